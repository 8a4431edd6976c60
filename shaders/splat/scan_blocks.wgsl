// Exclusive prefix sum, first pass: each workgroup scans its 256 values in place (in
// shared memory) and writes its total to `sums`; a second level scans the totals and
// scan_add.wgsl adds them back. No workgroup waits on another.

#bind p: uniform ScanParams
#bind data, sums: read_write array<u32>

var<workgroup> temp: array<u32, 256>;

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let lane = invocation.lane;
    let i = block * 256u + lane;
    var value = 0u;
    if i < p.len {
        value = data[i];
    }
    temp[lane] = value;
    workgroupBarrier();
    for (var offset = 1u; offset < 256u; offset *= 2u) {
        var add = 0u;
        if lane >= offset {
            add = temp[lane - offset];
        }
        workgroupBarrier();
        temp[lane] += add;
        workgroupBarrier();
    }
    if i < p.len {
        data[i] = temp[lane] - value;
    }
    if lane == 255u && block < p.blocks {
        sums[block] = temp[255];
    }
}
