// The PCA coefficients of a frame: c_k = Σ_d basis[k, d] · (unit[d] - shift[d % 3] -
// mean[d]), one thread per component (the frame centred on its own root, DESIGN §6).

@group(0) @binding(0) var<uniform> p: PostParams;
@group(0) @binding(1) var<storage, read> unit: array<f32>;
@group(0) @binding(2) var<storage, read> mean: array<f32>;
@group(0) @binding(3) var<storage, read> basis: array<f32>;
@group(0) @binding(4) var<storage, read> state: FrameState;
@group(0) @binding(5) var<storage, read_write> coefficients: array<f32>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let k = linear_index(invocation);
    if k >= p.components {
        return;
    }
    let d = 3u * p.points;
    let row = k * d;
    var c = 0.0;
    for (var i = 0u; i < d; i++) {
        c += basis[row + i] * (unit[i] - state.shift[i % 3u] - mean[i]);
    }
    coefficients[k] = c;
}
