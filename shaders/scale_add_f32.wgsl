// Example element-wise kernel, f32 path: y = scale * x + bias.
// Dispatched on a 2-D grid (see gpu::kernel::Grid) so any length fits the workgroup limit.

@group(0) @binding(0) var<uniform> params: ElementwiseParams;
@group(0) @binding(1) var<storage, read> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> y: array<f32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let i = (group.x + group.y * groups.x) * 64u + lane;
    if i >= params.len {
        return;
    }
    y[i] = params.scale * x[i] + params.bias;
}
