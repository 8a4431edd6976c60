// 2-D convolution, NCHW, stored as Elem (f32 or f16), summed in f32. Weights [c_out, c_in,
// k, k], optional bias [c_out], zero padding. One thread per output pixel and block of 8
// output channels: each input value is loaded once for eight accumulators.

#import nn/conv/tile.wgsl
#import nn/conv/conv_bias.wgsl
#import gpu/for_each.wgsl

#bind p: uniform Conv2dParams
#bind x, weight, bias: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return tile_count(1u); }

fn each(i: u32) {
    let tile = tile_at(i, 1u);
    // Channels past c_out (the last block) read the last channel and are not written.
    let last = p.c_out - 1u;
    let co = min(vec4<u32>(8u * tile.block) + vec4<u32>(0u, 1u, 2u, 3u), vec4<u32>(last));
    let co2 = min(co + vec4<u32>(4u), vec4<u32>(last));
    let start = bias_lanes(tile.block);
    var acc = start.lo;
    var acc2 = start.hi;
    let taps = p.kernel * p.kernel;
    let w_base = co * (p.c_in * taps);
    let w_base2 = co2 * (p.c_in * taps);
    for (var ci = 0u; ci < p.c_in; ci++) {
        let x_base = (tile.n * p.c_in + ci) * p.h_in * p.w_in;
        let w_ci = w_base + vec4<u32>(ci * taps);
        let w_ci2 = w_base2 + vec4<u32>(ci * taps);
        for (var ky = 0u; ky < p.kernel; ky++) {
            let iy = i32(tile.oy * p.stride + ky) - i32(p.pad);
            if iy < 0 || iy >= i32(p.h_in) {
                continue;
            }
            for (var kx = 0u; kx < p.kernel; kx++) {
                let ix = i32(tile.ox0 * p.stride + kx) - i32(p.pad);
                if ix < 0 || ix >= i32(p.w_in) {
                    continue;
                }
                let v = f32(x[x_base + u32(iy) * p.w_in + u32(ix)]);
                let tap = vec4<u32>(ky * p.kernel + kx);
                let w = w_ci + tap;
                let w2 = w_ci2 + tap;
                acc += v * vec4<f32>(f32(weight[w.x]), f32(weight[w.y]), f32(weight[w.z]), f32(weight[w.w]));
                acc2 += v * vec4<f32>(f32(weight[w2.x]), f32(weight[w2.y]), f32(weight[w2.z]), f32(weight[w2.w]));
            }
        }
    }
    let plane = p.h_out * p.w_out;
    let out = (tile.n * p.c_out + 8u * tile.block) * plane + tile.oy * p.w_out + tile.ox0;
    for (var j = 0u; j < 4u; j++) {
        if 8u * tile.block + j < p.c_out {
            y[out + j * plane] = Elem(acc[j]);
        }
        if 8u * tile.block + 4u + j < p.c_out {
            y[out + (4u + j) * plane] = Elem(acc2[j]);
        }
    }
}
