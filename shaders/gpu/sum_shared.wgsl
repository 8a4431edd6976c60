// Example reduction, portable path: one workgroup sums the array through shared memory.
// Each of 256 threads strides over the input, then a tree reduction halves the partials.

#bind params: uniform ReduceParams
#bind x: read array<f32>
#bind total: read_write array<f32>

var<workgroup> partial: array<f32, 256>;

@compute @workgroup_size(256)
fn main(@builtin(local_invocation_index) lane: u32) {
    var acc = 0.0;
    for (var i = lane; i < params.len; i += 256u) {
        acc += x[i];
    }
    partial[lane] = acc;
    workgroupBarrier();
    for (var stride = 128u; stride > 0u; stride /= 2u) {
        if lane < stride {
            partial[lane] += partial[lane + stride];
        }
        workgroupBarrier();
    }
    if lane == 0u {
        total[0] = partial[0];
    }
}
