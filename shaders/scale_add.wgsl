// Example element-wise kernel: y = scale * x + bias, stored as Elem (f32 or f16) and
// computed in f32. Dispatched on a 2-D grid (see gpu::kernel::Grid) so any length fits
// the workgroup limit.

@group(0) @binding(0) var<uniform> params: ElementwiseParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read_write> y: array<Elem>;

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
    y[i] = Elem(params.scale * f32(x[i]) + params.bias);
}
