// Sums: y[i] = a[i] + b[(i / per_value) % b_len] — elementwise when b is as long as a,
// per-channel (b[n, c] over each H×W plane) with per_value = H×W, and a trailing
// broadcast (b repeated over the leading axes) with per_value = 1.

@group(0) @binding(0) var<uniform> p: AddParams;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> y: array<f32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let i = (group.x + group.y * groups.x) * 64u + lane;
    if i >= p.len {
        return;
    }
    y[i] = a[i] + b[(i / p.per_value) % p.b_len];
}
