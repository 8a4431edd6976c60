// The PCA coefficients of a frame for GPUs: pca_coefficients.wgsl's c_k = Σ_d basis[k, d]
// · (unit[d] - shift[d % 3] - mean[d]), with one workgroup per component whose WORKGROUP
// threads split the texels (thread t takes texels t, t + WORKGROUP, …), their partial
// sums then added in thread order by the first. A thread per component walking its
// 3,311 texels alone took 1.3 ms on an NVIDIA H200 (docs/gpu). Texel layout, shifts and
// padding as pca_coefficients.wgsl.

@group(0) @binding(0) var<uniform> p: PostParams;
@group(0) @binding(1) var unit: texture_2d<f32>;
@group(0) @binding(2) var mean: texture_2d<f32>;
@group(0) @binding(3) var basis: texture_2d<f32>;
@group(0) @binding(4) var<storage, read> state: FrameState;
@group(0) @binding(5) var<storage, read_write> coefficients: array<f32>;

var<workgroup> partial: array<f32, WORKGROUP>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let k = invocation.group.x + invocation.group.y * invocation.groups.x;
    let t = invocation.lane;
    let quads = (3u * p.points + 3u) / 4u;
    let row = k * quads;
    // Value 4j + c is on axis (j + c) % 3 (4 ≡ 1 mod 3): the shifts of texel j by j % 3.
    let s = state.shift;
    let s0 = vec4<f32>(s[0], s[1], s[2], s[0]);
    let s1 = vec4<f32>(s[1], s[2], s[0], s[1]);
    let s2 = vec4<f32>(s[2], s[0], s[1], s[2]);
    var c = 0.0;
    let end = select(0u, quads, k < p.components);
    for (var j = t; j < end; j += WORKGROUP) {
        let phase = j % 3u;
        let shift = select(select(s0, s1, phase == 1u), s2, phase == 2u);
        let b = texel(basis, row + j);
        let v = texel(unit, j) - shift - texel(mean, j);
        c += b.x * v.x;
        c += b.y * v.y;
        c += b.z * v.z;
        c += b.w * v.w;
    }
    partial[t] = c;
    workgroupBarrier();
    if t == 0u && k < p.components {
        var sum = 0.0;
        for (var i = 0u; i < WORKGROUP; i++) {
            sum += partial[i];
        }
        coefficients[k] = sum;
    }
}
