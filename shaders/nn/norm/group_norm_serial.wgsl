// Group normalisation of NCHW (Elem storage, f32 statistics) with a per-channel affine and
// an optional fused SiLU, for CPU drivers: one invocation per (sample, group) makes the
// three passes (mean, variance, normalise) alone, with no workgroup barrier (a CPU
// driver runs each barrier as a switch between invocations, which costs far more than
// the arithmetic). Values go 4 at a time, summed in 4 running partial sums. Planes of a
// multiple of 4 values or rows of a multiple of 4 channels (hw = 1: a layer norm), and
// at most SERIAL_NORM_LIMIT values per group (host-checked): lavapipe stops any
// invocation's loops after 65,535 iterations in all. With `p.tokens` (F > 0) the values
// are stored as token rows [N, HW, F, C] instead, plus optional frame positions: the
// attention layers' permute, done by the stores (see GroupNormParams). x is read as
// texels (src/gpu/texels.rs: a vector gather on lavapipe, where a storage load is a
// loop over lanes).

#import gpu/for_each.wgsl

#import nn/norm/texel_stats.wgsl

#bind p: uniform GroupNormParams
#bind x: texture_2d<f32>
#bind gamma, beta: read array<Elem>
// With `p.has_rows`: frame positions added to the token rows.
#bind rows: read array<Elem>
#bind y: read_write array<Elem>

fn silu(v: vec4<f32>) -> vec4<f32> {
    return v / (1.0 + exp(-v));
}

// Four values at y[at], y[at + 1], … (NCHW and layer-norm rows).
fn store4(at: u32, v: vec4<f32>) {
    y[at] = Elem(v.x);
    y[at + 1u] = Elem(v.y);
    y[at + 2u] = Elem(v.z);
    y[at + 3u] = Elem(v.w);
}

fn count() -> u32 { return p.batch * p.groups; }

fn each(id: u32) {
    let per_group = p.channels / p.groups;
    let count = per_group * p.hw;
    let base = id * count / 4u; // (n, g) blocks are contiguous in NCHW
    let quads = count / 4u;
    let stats = texel_stats(x, base, count, p.eps);
    let mean = stats.x;
    let inv_std = stats.y;
    let first_channel = (id % p.groups) * per_group;
    if p.hw == 1u {
        // Rows of a layer norm: 4 channels at a time.
        for (var i = 0u; i < quads; i++) {
            let c = first_channel + 4u * i;
            let g = vec4<f32>(f32(gamma[c]), f32(gamma[c + 1u]), f32(gamma[c + 2u]), f32(gamma[c + 3u]));
            let b = vec4<f32>(f32(beta[c]), f32(beta[c + 1u]), f32(beta[c + 2u]), f32(beta[c + 3u]));
            var v = (texel(x, base + i) - mean) * (inv_std * g) + b;
            if p.silu != 0u {
                v = silu(v);
            }
            store4(4u * (base + i), v);
        }
        return;
    }
    let plane_quads = p.hw / 4u;
    if p.tokens != 0u {
        // Image n·F + f's pixel q is token row (n·HW + q)·F + f.
        let image = id / p.groups;
        let f = image % p.tokens;
        let stride = p.tokens * p.channels; // between pixels
        let first_row = ((image / p.tokens) * p.hw * p.tokens + f) * p.channels;
        for (var k = 0u; k < per_group; k++) {
            let c = first_channel + k;
            let scale = inv_std * f32(gamma[c]);
            let shift = f32(beta[c]);
            let plane = base + k * plane_quads;
            var position = 0.0;
            if p.has_rows != 0u {
                position = f32(rows[p.rows_offset + f * p.channels + c]);
            }
            for (var i = 0u; i < plane_quads; i++) {
                let v = (texel(x, plane + i) - mean) * scale + shift;
                // Rounded to Elem, then the position added and rounded again: the
                // norm's store and the permute's add.
                let rounded = vec4<f32>(vec4<Elem>(v));
                let out = select(rounded, rounded + position, p.has_rows != 0u);
                let at = first_row + 4u * i * stride + c;
                y[at] = Elem(out.x);
                y[at + stride] = Elem(out.y);
                y[at + 2u * stride] = Elem(out.z);
                y[at + 3u * stride] = Elem(out.w);
            }
        }
        return;
    }
    for (var k = 0u; k < per_group; k++) {
        let c = first_channel + k;
        let scale = inv_std * f32(gamma[c]);
        let shift = f32(beta[c]);
        let plane = base + k * plane_quads;
        for (var i = 0u; i < plane_quads; i++) {
            var v = (texel(x, plane + i) - mean) * scale + shift;
            if p.silu != 0u {
                v = silu(v);
            }
            store4(4u * (plane + i), v);
        }
    }
}
