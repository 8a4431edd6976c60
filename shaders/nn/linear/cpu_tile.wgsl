// The register tiles of the CPU-driver linear layers (linear_cpu.wgsl, and
// linear_rows_cpu.wgsl for plain rows): 8 rows × 8 outputs of
// y[b, o] = sum_i act(x[b, i]) * weight[o, i] + bias[o] per tile, with x and the
// weights read as texels (src/gpu/texels.rs: a vector gather on lavapipe, where a
// storage load is a loop over lanes) along the contiguous input axis (inputs a multiple
// of 4, host-checked): 16 texels per 256 multiply-adds. Optionally the input rows come
// through an index (a gather) and are layer-normed first (see LinearParams). The four
// weight vectors are transposed in registers, so each sum still runs over i in order
// from the bias, as linear.wgsl's does. Rows and outputs past the end are clamped for
// the loads. The importing file declares the bindings (p, x, weight, bias, ids, gamma,
// beta) and `store(row, o0, v)`, which puts outputs o0 … o0 + 3 of a row (and skips
// rows past the end).

#import gpu/for_each.wgsl
#import nn/norm/texel_stats.wgsl

fn silu(f: vec4<f32>) -> vec4<f32> {
    return f / (1.0 + exp(-f));
}

// Four inputs (4k … 4k + 3) of the four outputs' weight rows at texels `rows`, as
// columns: column j holds input 4k + j of outputs o0 … o0 + 3.
fn transposed(rows: vec4<u32>) -> mat4x4<f32> {
    let w0 = texel(weight, rows.x);
    let w1 = texel(weight, rows.y);
    let w2 = texel(weight, rows.z);
    let w3 = texel(weight, rows.w);
    return mat4x4<f32>(
        vec4<f32>(w0.x, w1.x, w2.x, w3.x),
        vec4<f32>(w0.y, w1.y, w2.y, w3.y),
        vec4<f32>(w0.z, w1.z, w2.z, w3.z),
        vec4<f32>(w0.w, w1.w, w2.w, w3.w),
    );
}

// a + the four inputs x times their weights, summed input by input in order.
fn mac(a: vec4<f32>, x: vec4<f32>, t: mat4x4<f32>) -> vec4<f32> {
    return a + x.x * t[0] + x.y * t[1] + x.z * t[2] + x.w * t[3];
}

// Four normed inputs as the layer norm stores them (rounded to Elem).
fn normed(v: vec4<f32>, stats: vec2<f32>, g: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(vec4<Elem>((v - stats.x) * (stats.y * g) + b));
}

// With `p.norm_rows`, an invocation makes up to NORMED_TILES (src/nn/ops/linear.rs)
// output tiles of its 8 rows, so each row's statistics are computed once per chunk.

fn output_tiles() -> u32 {
    return (p.outputs + 7u) / 8u;
}

// Output tiles an invocation makes: 1, or a chunk of NORMED_TILES with `p.norm_rows`.
fn chunk_size() -> u32 {
    return select(1u, NORMED_TILES, p.norm_rows != 0u);
}

fn chunks() -> u32 {
    return (output_tiles() + chunk_size() - 1u) / chunk_size();
}

fn count() -> u32 { return chunks() * ((p.rows + 7u) / 8u); }

fn each(i: u32) {
    let r0 = (i / chunks()) * 8u;
    let first_tile = (i % chunks()) * chunk_size();
    let tiles = min(chunk_size(), output_tiles() - first_tile);
    let last_r = vec4<u32>(p.rows - 1u);
    let quads = p.inputs / 4u;
    let four = vec4<u32>(0u, 1u, 2u, 3u);
    // Texels of the 8 rows of x (clamped at the end).
    var rows = min(vec4<u32>(r0) + four, last_r);
    var rows2 = min(vec4<u32>(r0 + 4u) + four, last_r);
    if p.gather_rows != 0u {
        rows = vec4<u32>(ids[rows.x], ids[rows.y], ids[rows.z], ids[rows.w]);
        rows2 = vec4<u32>(ids[rows2.x], ids[rows2.y], ids[rows2.z], ids[rows2.w]);
    }
    let xr = rows * quads;
    let xr2 = rows2 * quads;
    // The rows' layer-norm statistics (a loop that runs no iteration without a norm).
    var s0 = vec2<f32>(0.0);
    var s1 = vec2<f32>(0.0);
    var s2 = vec2<f32>(0.0);
    var s3 = vec2<f32>(0.0);
    var s4 = vec2<f32>(0.0);
    var s5 = vec2<f32>(0.0);
    var s6 = vec2<f32>(0.0);
    var s7 = vec2<f32>(0.0);
    for (var once = 0u; once < p.norm_rows; once++) {
        s0 = texel_stats(x, xr.x, p.inputs, p.eps);
        s1 = texel_stats(x, xr.y, p.inputs, p.eps);
        s2 = texel_stats(x, xr.z, p.inputs, p.eps);
        s3 = texel_stats(x, xr.w, p.inputs, p.eps);
        s4 = texel_stats(x, xr2.x, p.inputs, p.eps);
        s5 = texel_stats(x, xr2.y, p.inputs, p.eps);
        s6 = texel_stats(x, xr2.z, p.inputs, p.eps);
        s7 = texel_stats(x, xr2.w, p.inputs, p.eps);
    }
    for (var t = 0u; t < tiles; t++) {
        tile(r0, (first_tile + t) * 8u, xr, xr2, array<vec2<f32>, 8>(s0, s1, s2, s3, s4, s5, s6, s7));
    }
}

// Outputs o0 … o0 + 7 of rows r0 … r0 + 7, whose input texels start at xr and xr2 (and
// whose norm statistics are `stats`, with `p.norm_rows`).
fn tile(r0: u32, o0: u32, xr: vec4<u32>, xr2: vec4<u32>, stats: array<vec2<f32>, 8>) {
    let last_o = vec4<u32>(p.outputs - 1u);
    let quads = p.inputs / 4u;
    let four = vec4<u32>(0u, 1u, 2u, 3u);
    // Texels of the 8 outputs' weight rows (clamped at the end).
    let wo = min(vec4<u32>(o0) + four, last_o) * quads;
    let wo2 = min(vec4<u32>(o0 + 4u) + four, last_o) * quads;
    let ob = min(vec4<u32>(o0) + four, last_o);
    let ob2 = min(vec4<u32>(o0 + 4u) + four, last_o);
    let b = vec4<f32>(f32(bias[ob.x]), f32(bias[ob.y]), f32(bias[ob.z]), f32(bias[ob.w]));
    let b2 = vec4<f32>(f32(bias[ob2.x]), f32(bias[ob2.y]), f32(bias[ob2.z]), f32(bias[ob2.w]));
    // Row j's outputs o0 … o0 + 3 in aj, o0 + 4 … o0 + 7 in cj.
    var a0 = b;
    var a1 = b;
    var a2 = b;
    var a3 = b;
    var a4 = b;
    var a5 = b;
    var a6 = b;
    var a7 = b;
    var c0 = b2;
    var c1 = b2;
    var c2 = b2;
    var c3 = b2;
    var c4 = b2;
    var c5 = b2;
    var c6 = b2;
    var c7 = b2;
    // Loops of their own rather than branches inside one: a CPU driver runs both sides
    // of a branch under a lane mask, so the SiLU's exp or the norm would cost every layer.
    if p.input_silu != 0u {
        for (var k = 0u; k < quads; k++) {
            let lo = transposed(wo + k);
            let hi = transposed(wo2 + k);
            let x0 = silu(texel(x, xr.x + k));
            let x1 = silu(texel(x, xr.y + k));
            let x2 = silu(texel(x, xr.z + k));
            let x3 = silu(texel(x, xr.w + k));
            let x4 = silu(texel(x, xr2.x + k));
            let x5 = silu(texel(x, xr2.y + k));
            let x6 = silu(texel(x, xr2.z + k));
            let x7 = silu(texel(x, xr2.w + k));
            a0 = mac(a0, x0, lo);
            c0 = mac(c0, x0, hi);
            a1 = mac(a1, x1, lo);
            c1 = mac(c1, x1, hi);
            a2 = mac(a2, x2, lo);
            c2 = mac(c2, x2, hi);
            a3 = mac(a3, x3, lo);
            c3 = mac(c3, x3, hi);
            a4 = mac(a4, x4, lo);
            c4 = mac(c4, x4, hi);
            a5 = mac(a5, x5, lo);
            c5 = mac(c5, x5, hi);
            a6 = mac(a6, x6, lo);
            c6 = mac(c6, x6, hi);
            a7 = mac(a7, x7, lo);
            c7 = mac(c7, x7, hi);
        }
    } else if p.norm_rows != 0u {
        let s0 = stats[0];
        let s1 = stats[1];
        let s2 = stats[2];
        let s3 = stats[3];
        let s4 = stats[4];
        let s5 = stats[5];
        let s6 = stats[6];
        let s7 = stats[7];
        for (var k = 0u; k < quads; k++) {
            let lo = transposed(wo + k);
            let hi = transposed(wo2 + k);
            let g = texel(gamma, k);
            let b = texel(beta, k);
            let x0 = normed(texel(x, xr.x + k), s0, g, b);
            let x1 = normed(texel(x, xr.y + k), s1, g, b);
            let x2 = normed(texel(x, xr.z + k), s2, g, b);
            let x3 = normed(texel(x, xr.w + k), s3, g, b);
            let x4 = normed(texel(x, xr2.x + k), s4, g, b);
            let x5 = normed(texel(x, xr2.y + k), s5, g, b);
            let x6 = normed(texel(x, xr2.z + k), s6, g, b);
            let x7 = normed(texel(x, xr2.w + k), s7, g, b);
            a0 = mac(a0, x0, lo);
            c0 = mac(c0, x0, hi);
            a1 = mac(a1, x1, lo);
            c1 = mac(c1, x1, hi);
            a2 = mac(a2, x2, lo);
            c2 = mac(c2, x2, hi);
            a3 = mac(a3, x3, lo);
            c3 = mac(c3, x3, hi);
            a4 = mac(a4, x4, lo);
            c4 = mac(c4, x4, hi);
            a5 = mac(a5, x5, lo);
            c5 = mac(c5, x5, hi);
            a6 = mac(a6, x6, lo);
            c6 = mac(c6, x6, hi);
            a7 = mac(a7, x7, lo);
            c7 = mac(c7, x7, hi);
        }
    } else {
        for (var k = 0u; k < quads; k++) {
            let lo = transposed(wo + k);
            let hi = transposed(wo2 + k);
            let x0 = texel(x, xr.x + k);
            let x1 = texel(x, xr.y + k);
            let x2 = texel(x, xr.z + k);
            let x3 = texel(x, xr.w + k);
            let x4 = texel(x, xr2.x + k);
            let x5 = texel(x, xr2.y + k);
            let x6 = texel(x, xr2.z + k);
            let x7 = texel(x, xr2.w + k);
            a0 = mac(a0, x0, lo);
            c0 = mac(c0, x0, hi);
            a1 = mac(a1, x1, lo);
            c1 = mac(c1, x1, hi);
            a2 = mac(a2, x2, lo);
            c2 = mac(c2, x2, hi);
            a3 = mac(a3, x3, lo);
            c3 = mac(c3, x3, hi);
            a4 = mac(a4, x4, lo);
            c4 = mac(c4, x4, hi);
            a5 = mac(a5, x5, lo);
            c5 = mac(c5, x5, hi);
            a6 = mac(a6, x6, lo);
            c6 = mac(c6, x6, hi);
            a7 = mac(a7, x7, lo);
            c7 = mac(c7, x7, hi);
        }
    }
    store(r0, o0, a0);
    store(r0 + 1u, o0, a1);
    store(r0 + 2u, o0, a2);
    store(r0 + 3u, o0, a3);
    store(r0 + 4u, o0, a4);
    store(r0 + 5u, o0, a5);
    store(r0 + 6u, o0, a6);
    store(r0 + 7u, o0, a7);
    store(r0, o0 + 4u, c0);
    store(r0 + 1u, o0 + 4u, c1);
    store(r0 + 2u, o0 + 4u, c2);
    store(r0 + 3u, o0 + 4u, c3);
    store(r0 + 4u, o0 + 4u, c4);
    store(r0 + 5u, o0 + 4u, c5);
    store(r0 + 6u, o0 + 4u, c6);
    store(r0 + 7u, o0 + 4u, c7);
}
