// Example element-wise kernel, f16 storage and arithmetic: y = scale * x + bias.
// Same grid as the f32 path; used only where the device has SHADER_F16.

@group(0) @binding(0) var<uniform> params: ElementwiseParams;
@group(0) @binding(1) var<storage, read> x: array<f16>;
@group(0) @binding(2) var<storage, read_write> y: array<f16>;

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
    y[i] = f16(params.scale) * x[i] + f16(params.bias);
}
