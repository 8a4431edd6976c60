// Exclusive prefix sum, last pass: adds each block's scanned total to its values.

#bind p: uniform ScanParams
#bind data, sums: read_write array<u32>

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let lane = invocation.lane;
    let i = block * 256u + lane;
    if i < p.len {
        data[i] += sums[block];
    }
}
