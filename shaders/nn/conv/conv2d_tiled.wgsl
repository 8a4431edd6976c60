// 2-D convolution in register tiles (NCHW, Elem storage, f32 sums): each invocation
// computes 4 neighbouring output pixels of a row × 8 output channels, so every weight
// loaded serves 4 pixels and every input value 8 channels. Taps outside the input add
// an exact zero, so each output sums the same terms in the same order (bias, then
// c_in, ky, kx) as conv2d.wgsl. Weights [c_out, c_in, k, k], optional bias [c_out].

#import nn/conv/tile.wgsl
#import nn/conv/conv_bias.wgsl
#import gpu/for_each.wgsl

#bind p: uniform Conv2dParams
#bind x, weight, bias: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return tile_count(4u); }

fn each(i: u32) {
    let tile = tile_at(i, 4u);
    let last = p.c_out - 1u;
    let co = min(vec4<u32>(8u * tile.block) + vec4<u32>(0u, 1u, 2u, 3u), vec4<u32>(last));
    let co2 = min(co + vec4<u32>(4u), vec4<u32>(last));
    let start = bias_lanes(tile.block);
    let b = start.lo;
    let b2 = start.hi;
    // Accumulators: pixel j's first and second four channels.
    var a = array<vec4<f32>, 4>(b, b, b, b);
    var a2 = array<vec4<f32>, 4>(b2, b2, b2, b2);
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
            let row = x_base + u32(iy) * p.w_in;
            for (var kx = 0u; kx < p.kernel; kx++) {
                let tap = vec4<u32>(ky * p.kernel + kx);
                let w = w_ci + tap;
                let w2 = w_ci2 + tap;
                let wv = vec4<f32>(f32(weight[w.x]), f32(weight[w.y]), f32(weight[w.z]), f32(weight[w.w]));
                let wv2 = vec4<f32>(f32(weight[w2.x]), f32(weight[w2.y]), f32(weight[w2.z]), f32(weight[w2.w]));
                for (var j = 0u; j < 4u; j++) {
                    let ix = i32((tile.ox0 + j) * p.stride + kx) - i32(p.pad);
                    if ix < 0 || ix >= i32(p.w_in) {
                        continue;
                    }
                    let v = f32(x[row + u32(ix)]);
                    a[j] += v * wv;
                    a2[j] += v * wv2;
                }
            }
        }
    }
    let plane = p.h_out * p.w_out;
    for (var j = 0u; j < 4u; j++) {
        let ox = tile.ox0 + j;
        if ox >= p.w_out {
            break;
        }
        let out = (tile.n * p.c_out + 8u * tile.block) * plane + tile.oy * p.w_out + ox;
        for (var c = 0u; c < 4u; c++) {
            if 8u * tile.block + c < p.c_out {
                y[out + c * plane] = Elem(a[j][c]);
            }
            if 8u * tile.block + 4u + c < p.c_out {
                y[out + (4u + c) * plane] = Elem(a2[j][c]);
            }
        }
    }
}
