// Group normalisation of NCHW (Elem storage, f32 statistics) with a per-channel affine and
// an optional fused SiLU, for CPU drivers: one invocation per (sample, group) makes the
// three passes (mean, variance, normalise) alone, with no workgroup barrier (a CPU
// driver runs each barrier as a switch between invocations, which costs far more than
// the arithmetic). Values go 4 at a time, summed in 4 running partial sums. Planes of a
// multiple of 4 values or rows of a multiple of 4 channels (hw = 1: a layer norm), and
// at most SERIAL_NORM_LIMIT values per group (host-checked): lavapipe stops any
// invocation's loops after 65,535 iterations in all.

@group(0) @binding(0) var<uniform> p: GroupNormParams;
@group(0) @binding(1) var<storage, read> x: array<vec4<Elem>>;
@group(0) @binding(2) var<storage, read> gamma: array<Elem>;
@group(0) @binding(3) var<storage, read> beta: array<Elem>;
@group(0) @binding(4) var<storage, read_write> y: array<vec4<Elem>>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let id = linear_index(invocation);
    if id >= p.batch * p.groups {
        return;
    }
    let per_group = p.channels / p.groups;
    let count = per_group * p.hw;
    let base = id * count / 4u; // (n, g) blocks are contiguous in NCHW
    let quads = count / 4u;
    var sum = vec4<f32>(0.0);
    for (var i = 0u; i < quads; i++) {
        sum += vec4<f32>(x[base + i]);
    }
    let mean = (sum.x + sum.y + sum.z + sum.w) / f32(count);
    var squares = vec4<f32>(0.0);
    for (var i = 0u; i < quads; i++) {
        let d = vec4<f32>(x[base + i]) - mean;
        squares += d * d;
    }
    let inv_std = inverseSqrt((squares.x + squares.y + squares.z + squares.w) / f32(count) + p.eps);
    let first_channel = (id % p.groups) * per_group;
    if p.hw == 1u {
        // Rows of a layer norm: 4 channels at a time.
        for (var i = 0u; i < quads; i++) {
            let c = first_channel + 4u * i;
            let g = vec4<f32>(f32(gamma[c]), f32(gamma[c + 1u]), f32(gamma[c + 2u]), f32(gamma[c + 3u]));
            let b = vec4<f32>(f32(beta[c]), f32(beta[c + 1u]), f32(beta[c + 2u]), f32(beta[c + 3u]));
            var v = (vec4<f32>(x[base + i]) - mean) * (inv_std * g) + b;
            if p.silu != 0u {
                v = v / (1.0 + exp(-v));
            }
            y[base + i] = vec4<Elem>(v);
        }
        return;
    }
    let plane_quads = p.hw / 4u;
    for (var k = 0u; k < per_group; k++) {
        let c = first_channel + k;
        let scale = inv_std * f32(gamma[c]);
        let shift = f32(beta[c]);
        let plane = base + k * plane_quads;
        for (var i = 0u; i < plane_quads; i++) {
            var v = (vec4<f32>(x[plane + i]) - mean) * scale + shift;
            if p.silu != 0u {
                v = v / (1.0 + exp(-v));
            }
            y[plane + i] = vec4<Elem>(v);
        }
    }
}
