// Exclusive prefix sum, last pass: adds each block's scanned total to its
// 256 · SCAN_PER_LANE values.

#bind p: uniform ScanParams
#bind data, sums: read_write array<u32>

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let first = (block * 256u + invocation.lane) * SCAN_PER_LANE;
    let add = sums[block];
    for (var k = 0u; k < SCAN_PER_LANE; k++) {
        if first + k < p.len {
            data[first + k] += add;
        }
    }
}
