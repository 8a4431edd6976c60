// 3×3 convolution, stride 2, zero padding 1, for CPU drivers (NCHW, Elem storage, f32
// sums): register tiles of 4 neighbouring output pixels of a row × 8 output channels,
// the input and the packed weights (nn::ops::PackedConv) read as texels
// (src/gpu/texels.rs). Per (c_in, ky) the tile reads input columns 2·ox0 - 1 … 2·ox0 + 7
// (3 texels, picked by their offset) and 6 weight texels for 96 multiply-adds. Each
// output sums bias, then c_in, ky, kx in order; taps outside the input add an exact zero
// (as conv3x3.wgsl). Optional bias [c_out].

#import nn/conv/tile.wgsl
#import gpu/for_each.wgsl

#import nn/conv/pick.wgsl
#import nn/conv/conv_bias.wgsl
#import nn/conv/conv_store.wgsl

#bind p: uniform Conv2dParams
#bind x, weight: texture_2d<f32>
#bind bias: read array<Elem>
// Unread (the shared epilogue's addend and residual; `p` says there are none).
#bind extra, residual: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return tile_count(4u); }

fn each(i: u32) {
    let tile = tile_at(i, 4u);
    let start = bias_lanes(tile.block);
    let lo = start.lo;
    let hi = start.hi;
    // Input column 2·ox0 - 1 + m is inside for m < inside (and m > 0 or ox0 > 0).
    let inside = p.w_in + 1u - 2u * tile.ox0;
    let m0 = vec4<bool>(tile.ox0 > 0u, 1u < inside, 2u < inside, 3u < inside);
    let m1 = vec4<bool>(4u < inside, 5u < inside, 6u < inside, 7u < inside);
    let m8 = 8u < inside;
    var a0 = lo;
    var a1 = lo;
    var a2 = lo;
    var a3 = lo;
    var b0 = hi;
    var b1 = hi;
    var b2 = hi;
    var b3 = hi;
    let quads = 2u * channel_blocks();
    for (var ci = 0u; ci < p.c_in; ci++) {
        let plane = (tile.n * p.c_in + ci) * p.h_in * p.w_in;
        for (var ky = 0u; ky < 3u; ky++) {
            let iy = i32(2u * tile.oy + ky) - 1;
            if iy < 0 || iy >= i32(p.h_in) {
                continue;
            }
            // Flat index + 4 of column 2·ox0 - 1 (never negative).
            let start4 = plane + u32(iy) * p.w_in + 2u * tile.ox0 + 3u;
            let t = i32(start4 >> 2u) - 1;
            let s = start4 & 3u;
            let q0 = texel(x, u32(max(t, 0)));
            let q1 = texel(x, u32(t + 1));
            let q2 = texel(x, u32(t + 2));
            let u0 = select(vec4<f32>(0.0), pick(q0, q1, s), m0);
            let u1 = select(vec4<f32>(0.0), pick(q1, q2, s), m1);
            let u8 = select(0.0, pick(q2, q2, s).x, m8);
            var w = (ci * 3u + ky) * 3u * quads + 2u * tile.block;
            // kx = 0: columns 0, 2, 4, 6
            let wa0 = texel(weight, w);
            let wb0 = texel(weight, w + 1u);
            a0 += u0.x * wa0;
            a1 += u0.z * wa0;
            a2 += u1.x * wa0;
            a3 += u1.z * wa0;
            b0 += u0.x * wb0;
            b1 += u0.z * wb0;
            b2 += u1.x * wb0;
            b3 += u1.z * wb0;
            w += quads;
            // kx = 1: columns 1, 3, 5, 7
            let wa1 = texel(weight, w);
            let wb1 = texel(weight, w + 1u);
            a0 += u0.y * wa1;
            a1 += u0.w * wa1;
            a2 += u1.y * wa1;
            a3 += u1.w * wa1;
            b0 += u0.y * wb1;
            b1 += u0.w * wb1;
            b2 += u1.y * wb1;
            b3 += u1.w * wb1;
            w += quads;
            // kx = 2: columns 2, 4, 6, 8
            let wa2 = texel(weight, w);
            let wb2 = texel(weight, w + 1u);
            a0 += u0.z * wa2;
            a1 += u1.x * wa2;
            a2 += u1.z * wa2;
            a3 += u8 * wa2;
            b0 += u0.z * wb2;
            b1 += u1.x * wb2;
            b2 += u1.z * wb2;
            b3 += u8 * wb2;
        }
    }
    store(tile.n, tile.block, tile.oy, tile.ox0, a0, b0);
    store(tile.n, tile.block, tile.oy, tile.ox0 + 1u, a1, b1);
    store(tile.n, tile.block, tile.oy, tile.ox0 + 2u, a2, b2);
    store(tile.n, tile.block, tile.oy, tile.ox0 + 3u, a3, b3);
}
