// Exclusive prefix sum, last pass: adds each block's scanned total to its values.

@group(0) @binding(0) var<uniform> p: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let lane = invocation.lane;
    let i = block * 256u + lane;
    if i < p.len {
        data[i] += sums[block];
    }
}
