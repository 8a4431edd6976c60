// 3×3 convolution, stride 1, zero padding 1 (NCHW, Elem storage, f32 sums), for GPUs:
// one workgroup per register tile of 8 neighbouring output pixels of a row × 8 output
// channels, its WORKGROUP threads splitting the input channels (thread t takes c_in t,
// t + WORKGROUP, …) and summing their partial tiles through workgroup memory. A thread
// per tile, summing every input channel alone, left an H200 with a few hundred threads
// busy at the UNet's 16×16 latents: 257 µs a convolution (docs/gpu). The weights come
// repacked at load as f32 [c_in, 3, 3, c_out rounded up to 8] (nn::ops::PackedConv), so
// a tap's 8 channels are two vec4 loads, and the 10 input values a row of 8 outputs
// needs are loaded once per (c_in, ky) for all 3 taps. Taps outside the input add an
// exact zero. The bias is added to the summed tile, then an optional per-image addend,
// and an optional residual is added to the result rounded to Elem (so it equals a
// separate add.wgsl exactly). With `upsample`, the input is read upsampled ×2
// (upsample_nearest.wgsl fused into the loads).

#import nn/conv/tile.wgsl
#import nn/conv/conv_bias.wgsl
#import nn/conv/conv_store.wgsl

#bind p: uniform Conv2dParams
#bind x: read array<Elem>
#bind weight: read array<vec4<f32>>
#bind bias: read array<Elem>
// With `p.has_extra` set: [N, c_out] added to each image's channels after the sums.
#bind extra: read array<Elem>
// With `p.has_residual` set: [N, c_out, H, W] added last.
#bind residual: read array<Elem>
#bind y: read_write array<Elem>

// The image the taps see is w_out × h_out ("same" padding): x itself, or with
// `p.upsample` x upsampled ×2 (nearest), read from its source pixels.

// The seen image at column `ix` of the seen row whose x row starts at `row`; zero outside.
fn column(row: u32, ix: i32) -> f32 {
    let inside = ix >= 0 && ix < i32(p.w_out);
    let seen = u32(clamp(ix, 0, i32(p.w_out) - 1));
    return select(0.0, f32(x[row + (seen >> p.upsample)]), inside);
}

// Each thread's partial tile: 16 vec4 (pixel j's channels 0-3 at j, 4-7 at 8 + j).
var<workgroup> partial: array<vec4<f32>, 16u * WORKGROUP>;
// The summed tile, one value per thread: value 4q + c is channel c of partial slot q.
var<workgroup> total: array<f32, 64>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    // The tile: the workgroup's linear index (the few past the end compute and store
    // nothing, and take part in the barriers).
    let i = group_index(invocation);
    let t = invocation.lane;
    let live = i < tile_count(8u);
    let tile = tile_at(i, 8u);
    let lo = vec4<f32>(0.0);
    let hi = vec4<f32>(0.0);
    // Pixel j's first four channels in aj, its second four in bj: written out, not
    // arrays, so they stay in registers.
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
    let left = i32(tile.ox0) - 1;
    let c_end = select(0u, p.c_in, live);
    for (var ci = t; ci < c_end; ci += WORKGROUP) {
        let plane = (tile.n * p.c_in + ci) * p.h_in * p.w_in;
        for (var ky = 0u; ky < 3u; ky++) {
            let iy = i32(tile.oy + ky) - 1;
            if iy < 0 || iy >= i32(p.h_out) {
                continue;
            }
            let row = plane + (u32(iy) >> p.upsample) * p.w_in;
            let v0 = column(row, left + 0);
            let v1 = column(row, left + 1);
            let v2 = column(row, left + 2);
            let v3 = column(row, left + 3);
            let v4 = column(row, left + 4);
            let v5 = column(row, left + 5);
            let v6 = column(row, left + 6);
            let v7 = column(row, left + 7);
            let v8 = column(row, left + 8);
            let v9 = column(row, left + 9);
            var w = (ci * 3u + ky) * 3u * quads + 2u * tile.block;
            // kx = 0
            let wa0 = weight[w];
            let wb0 = weight[w + 1u];
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
            let wa1 = weight[w];
            let wb1 = weight[w + 1u];
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
            let wa2 = weight[w];
            let wb2 = weight[w + 1u];
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
    let slot = 16u * t;
    partial[slot + 0u] = a0;
    partial[slot + 1u] = a1;
    partial[slot + 2u] = a2;
    partial[slot + 3u] = a3;
    partial[slot + 4u] = a4;
    partial[slot + 5u] = a5;
    partial[slot + 6u] = a6;
    partial[slot + 7u] = a7;
    partial[slot + 8u] = b0;
    partial[slot + 9u] = b1;
    partial[slot + 10u] = b2;
    partial[slot + 11u] = b3;
    partial[slot + 12u] = b4;
    partial[slot + 13u] = b5;
    partial[slot + 14u] = b6;
    partial[slot + 15u] = b7;
    workgroupBarrier();
    // Thread t < 64 sums value t of the tile over the threads, in thread order.
    var sum = 0.0;
    let value = min(t, 63u);
    for (var k = 0u; k < WORKGROUP; k++) {
        sum += partial[16u * k + value / 4u][value % 4u];
    }
    if t < 64u {
        total[t] = sum;
    }
    workgroupBarrier();
    if live && t < 8u {
        let start = bias_lanes(tile.block);
        let a = vec4<f32>(total[4u * t], total[4u * t + 1u], total[4u * t + 2u], total[4u * t + 3u]);
        let q = 4u * (8u + t);
        let b = vec4<f32>(total[q], total[q + 1u], total[q + 2u], total[q + 3u]);
        store(tile.n, tile.block, tile.oy, tile.ox0 + t, start.lo + a, start.hi + b);
    }
}
