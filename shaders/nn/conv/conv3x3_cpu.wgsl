// 3×3 convolution for CPU drivers: conv3x3.wgsl's register tiles (8 neighbouring output
// pixels of a row × 8 output channels; the same terms summed in the same order: bias,
// then c_in, ky, kx) with the input and the packed weights read as texels
// (src/gpu/texels.rs), which lavapipe fetches as vector gathers where a storage load is a
// loop over lanes. Per (c_in, ky): 4 input texels (3 when upsampling) and 6 weight texels
// for 192 multiply-adds. The 10 input values a row of 8 outputs needs start anywhere in
// a texel, so they are picked from four texels by their offset. Optional bias, addend
// and residual as in conv3x3.wgsl; `upsample` reads the input upsampled ×2 (nearest).
// Output rows are whole vec4s (host-checked): each channel's 8 pixels are stored (and
// their residual read) as two vec4s.
// Built with NORMED set (CONV3X3_NORMED_CPU, with `p.norm_groups` = G > 0), the input
// is group-normalised as it is loaded: each workgroup first computes the (mean, 1/std)
// of every (sample, group) with group_norm_serial.wgsl's `texel_stats` (one barrier),
// then each value read is normalised, SiLU'd and rounded to Elem, as that kernel's
// stores would have been.

#import nn/conv/tile.wgsl
#import nn/conv/pick.wgsl
#import nn/conv/conv_bias.wgsl
#import nn/norm/texel_stats.wgsl

#bind p: uniform Conv2dParams
#bind x, weight: texture_2d<f32>
#bind bias: read array<Elem>
// With `p.has_extra` set: [N, c_out] added to each image's channels after the sums.
#bind extra: read array<Elem>
// With `p.has_residual` set: [N, c_out, H, W] added last.
#bind residual: read array<vec4<Elem>>
#bind y: read_write array<vec4<Elem>>
// With `p.norm_groups` set: the norm's per-channel affine, [c_in] each.
#bind norm_gamma, norm_beta: read array<Elem>

// (mean, 1/std) of (sample n, group g) at n·G + g, with `p.norm_groups` set.
var<workgroup> norm_stats: array<vec2<f32>, NORM_STATS>;

// Input values normalised: (v - mean) · scale + shift, SiLU, rounded to Elem (the norm's
// SiLU is always on here: Recorder::can_fold_norm).
fn normed(v: vec4<f32>, mean: f32, scale: f32, shift: f32) -> vec4<f32> {
    let out = (v - mean) * scale + shift;
    return vec4<f32>(vec4<Elem>(out / (1.0 + exp(-out))));
}

// Four output pixels of channel `co` at vec4 `at` (image n): the sums plus the addend
// when there is one, rounded to Elem, plus the residual when there is one (as
// conv_store.wgsl's `finish`, four at a time).
fn finish4(at: u32, n: u32, co: u32, v: vec4<f32>) -> vec4<Elem> {
    var out = v;
    if p.has_extra != 0u {
        out += f32(extra[n * p.c_out + co]);
    }
    if p.has_residual != 0u {
        return vec4<Elem>(vec4<f32>(residual[at]) + vec4<f32>(vec4<Elem>(out)));
    }
    return vec4<Elem>(out);
}

// Channel `co` of the tile's 8 pixels (`first` the first four, `last` the next four),
// stored as two vec4s: w_out is a multiple of 4 (host-checked), so each four is whole
// or past the row's end. On lavapipe a storage store moves one value per loop over
// the lanes, so 16 vec4 stores cost far less than 64 one-value stores.
fn put(tile: Tile, co: u32, first: vec4<f32>, last: vec4<f32>) {
    if co >= p.c_out {
        return;
    }
    let at = (((tile.n * p.c_out + co) * p.h_out + tile.oy) * p.w_out + tile.ox0) / 4u;
    y[at] = finish4(at, tile.n, co, first);
    if tile.ox0 + 4u < p.w_out {
        y[at + 1u] = finish4(at + 1u, tile.n, co, last);
    }
}

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    if NORMED != 0u {
        // Each (sample, group) block of x is contiguous in NCHW.
        let count = p.c_in / p.norm_groups * p.h_in * p.w_in;
        for (var k = invocation.lane; k < p.batch * p.norm_groups; k += WORKGROUP) {
            norm_stats[k] = texel_stats(x, k * count / 4u, count, p.norm_eps);
        }
        workgroupBarrier();
    }
    let i = linear_index(invocation);
    if i >= tile_count(8u) {
        return;
    }
    let tile = tile_at(i, 8u);
    let start = bias_lanes(tile.block);
    let lo = start.lo;
    let hi = start.hi;
    // Seen column ox0 - 1 + j is inside the image for j < inside (and j > 0 or ox0 > 0).
    let inside = p.w_out + 1u - tile.ox0;
    let m0 = vec4<bool>(tile.ox0 > 0u, 1u < inside, 2u < inside, 3u < inside);
    let m1 = vec4<bool>(4u < inside, 5u < inside, 6u < inside, 7u < inside);
    let m2 = vec4<bool>(8u < inside, 9u < inside, false, false);
    // The first source column the tile reads, relative to its row (+1: never negative).
    let first = select(tile.ox0, tile.ox0 >> 1u, p.upsample != 0u);
    var a0 = lo;
    var a1 = lo;
    var a2 = lo;
    var a3 = lo;
    var a4 = lo;
    var a5 = lo;
    var a6 = lo;
    var a7 = lo;
    var b0 = hi;
    var b1 = hi;
    var b2 = hi;
    var b3 = hi;
    var b4 = hi;
    var b5 = hi;
    var b6 = hi;
    var b7 = hi;
    let quads = 2u * channel_blocks();
    for (var ci = 0u; ci < p.c_in; ci++) {
        let plane = (tile.n * p.c_in + ci) * p.h_in * p.w_in;
        var mean = 0.0;
        var scale = 1.0;
        var shift = 0.0;
        if NORMED != 0u {
            let stats = norm_stats[tile.n * p.norm_groups + ci / (p.c_in / p.norm_groups)];
            mean = stats.x;
            scale = stats.y * f32(norm_gamma[ci]);
            shift = f32(norm_beta[ci]);
        }
        for (var ky = 0u; ky < 3u; ky++) {
            let iy = i32(tile.oy + ky) - 1;
            if iy < 0 || iy >= i32(p.h_out) {
                continue;
            }
            // Flat index + 4 of the tile's first source value (one before the first
            // column: -1 at the very start of the array).
            let start4 = plane + (u32(iy) >> p.upsample) * p.w_in + first + 3u;
            let t = i32(start4 >> 2u) - 1;
            let s = start4 & 3u;
            let q0 = texel(x, u32(max(t, 0)));
            let q1 = texel(x, u32(t + 1));
            let q2 = texel(x, u32(t + 2));
            var u0 = pick(q0, q1, s);
            var u1 = pick(q1, q2, s);
            var u2 = vec4<f32>(0.0);
            if p.upsample != 0u {
                // Seen columns ox0 - 1 … ox0 + 8 are source values 0, 1, 1, 2, 2, 3, 3,
                // 4, 4, 5 from the first (ox0 is even).
                let w0 = u0;
                let w1 = u1;
                u0 = vec4<f32>(w0.x, w0.y, w0.y, w0.z);
                u1 = vec4<f32>(w0.z, w0.w, w0.w, w1.x);
                u2 = vec4<f32>(w1.x, w1.y, 0.0, 0.0);
            } else {
                u2 = pick(q2, texel(x, u32(t + 3)), s);
            }
            if NORMED != 0u {
                // Before the padding masks: the padding is zero after the norm.
                u0 = normed(u0, mean, scale, shift);
                u1 = normed(u1, mean, scale, shift);
                u2 = normed(u2, mean, scale, shift);
            }
            u0 = select(vec4<f32>(0.0), u0, m0);
            u1 = select(vec4<f32>(0.0), u1, m1);
            u2 = select(vec4<f32>(0.0), u2, m2);
            let v0 = u0.x;
            let v1 = u0.y;
            let v2 = u0.z;
            let v3 = u0.w;
            let v4 = u1.x;
            let v5 = u1.y;
            let v6 = u1.z;
            let v7 = u1.w;
            let v8 = u2.x;
            let v9 = u2.y;
            var w = (ci * 3u + ky) * 3u * quads + 2u * tile.block;
            // kx = 0
            let wa0 = texel(weight, w);
            let wb0 = texel(weight, w + 1u);
            a0 += v0 * wa0;
            a1 += v1 * wa0;
            a2 += v2 * wa0;
            a3 += v3 * wa0;
            a4 += v4 * wa0;
            a5 += v5 * wa0;
            a6 += v6 * wa0;
            a7 += v7 * wa0;
            b0 += v0 * wb0;
            b1 += v1 * wb0;
            b2 += v2 * wb0;
            b3 += v3 * wb0;
            b4 += v4 * wb0;
            b5 += v5 * wb0;
            b6 += v6 * wb0;
            b7 += v7 * wb0;
            w += quads;
            // kx = 1
            let wa1 = texel(weight, w);
            let wb1 = texel(weight, w + 1u);
            a0 += v1 * wa1;
            a1 += v2 * wa1;
            a2 += v3 * wa1;
            a3 += v4 * wa1;
            a4 += v5 * wa1;
            a5 += v6 * wa1;
            a6 += v7 * wa1;
            a7 += v8 * wa1;
            b0 += v1 * wb1;
            b1 += v2 * wb1;
            b2 += v3 * wb1;
            b3 += v4 * wb1;
            b4 += v5 * wb1;
            b5 += v6 * wb1;
            b6 += v7 * wb1;
            b7 += v8 * wb1;
            w += quads;
            // kx = 2
            let wa2 = texel(weight, w);
            let wb2 = texel(weight, w + 1u);
            a0 += v2 * wa2;
            a1 += v3 * wa2;
            a2 += v4 * wa2;
            a3 += v5 * wa2;
            a4 += v6 * wa2;
            a5 += v7 * wa2;
            a6 += v8 * wa2;
            a7 += v9 * wa2;
            b0 += v2 * wb2;
            b1 += v3 * wb2;
            b2 += v4 * wb2;
            b3 += v5 * wb2;
            b4 += v6 * wb2;
            b5 += v7 * wb2;
            b6 += v8 * wb2;
            b7 += v9 * wb2;
        }
    }
    let co = 8u * tile.block;
    put(tile, co, vec4<f32>(a0.x, a1.x, a2.x, a3.x), vec4<f32>(a4.x, a5.x, a6.x, a7.x));
    put(tile, co + 1u, vec4<f32>(a0.y, a1.y, a2.y, a3.y), vec4<f32>(a4.y, a5.y, a6.y, a7.y));
    put(tile, co + 2u, vec4<f32>(a0.z, a1.z, a2.z, a3.z), vec4<f32>(a4.z, a5.z, a6.z, a7.z));
    put(tile, co + 3u, vec4<f32>(a0.w, a1.w, a2.w, a3.w), vec4<f32>(a4.w, a5.w, a6.w, a7.w));
    put(tile, co + 4u, vec4<f32>(b0.x, b1.x, b2.x, b3.x), vec4<f32>(b4.x, b5.x, b6.x, b7.x));
    put(tile, co + 5u, vec4<f32>(b0.y, b1.y, b2.y, b3.y), vec4<f32>(b4.y, b5.y, b6.y, b7.y));
    put(tile, co + 6u, vec4<f32>(b0.z, b1.z, b2.z, b3.z), vec4<f32>(b4.z, b5.z, b6.z, b7.z));
    put(tile, co + 7u, vec4<f32>(b0.w, b1.w, b2.w, b3.w), vec4<f32>(b4.w, b5.w, b6.w, b7.w));
}
