// Exclusive prefix sum, first pass: each workgroup scans a block of 256 · SCAN_PER_LANE
// values in place: each lane sums its SCAN_PER_LANE consecutive values in registers,
// the 256 lane totals are scanned in shared memory, and each lane writes its values'
// prefixes. The block's total goes to `sums`; a second level scans the totals and
// scan_add.wgsl adds them back. No workgroup waits on another. Lanes sum serially
// because shared-memory barriers are what a CPU driver pays for (docs/performance.md:
// one value a lane took 38 ms for a 288k-entry histogram on lavapipe).

#bind p: uniform ScanParams
#bind data, sums: read_write array<u32>

var<workgroup> temp: array<u32, 256>;

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let lane = invocation.lane;
    let first = (block * 256u + lane) * SCAN_PER_LANE;
    var before: array<u32, SCAN_PER_LANE>;
    var total = 0u;
    for (var k = 0u; k < SCAN_PER_LANE; k++) {
        before[k] = total;
        if first + k < p.len {
            total += data[first + k];
        }
    }
    temp[lane] = total;
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
    let lanes_before = temp[lane] - total;
    for (var k = 0u; k < SCAN_PER_LANE; k++) {
        if first + k < p.len {
            data[first + k] = lanes_before + before[k];
        }
    }
    if lane == 255u && block < p.blocks {
        sums[block] = temp[255];
    }
}
