// A frame's drawn points in world space: the PCA reconstruction mean + Σ_k c_k basis_k
// with the root shift put back (or the clamped points when there are no components),
// then (v - 0.5) / scale + the world root. One thread per value (3 per point).

@group(0) @binding(0) var<uniform> p: PostParams;
@group(0) @binding(1) var<storage, read> unit: array<f32>;
@group(0) @binding(2) var<storage, read> mean: array<f32>;
@group(0) @binding(3) var<storage, read> basis: array<f32>;
@group(0) @binding(4) var<storage, read> state: FrameState;
@group(0) @binding(5) var<storage, read> coefficients: array<f32>;
@group(0) @binding(6) var<storage, read_write> points: array<f32>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    let d = 3u * p.points;
    if i >= d {
        return;
    }
    let axis = i % 3u;
    var v = unit[i];
    if p.components > 0u {
        var o = mean[i];
        for (var k = 0u; k < p.components; k++) {
            o += coefficients[k] * basis[k * d + i];
        }
        v = o + state.shift[axis];
    }
    points[i] = (v - 0.5) / p.scale + state.root[axis];
}
