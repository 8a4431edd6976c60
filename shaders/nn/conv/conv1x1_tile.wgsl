// The 1×1 convolution's tile, shared by its storage-buffer form (conv1x1.wgsl) and its
// texel form (conv1x1_cpu.wgsl), which define how four values of x and of the packed
// weights are read (`x_quad`, `weight_quad`) and bind `p: Conv2dParams`, `bias` and
// `y: array<vec4<Elem>>`: tiles of 8 neighbouring pixels of a plane × 8 output channels;
// each output sums the same terms in the same order (bias, then c_in) as conv2d.wgsl.

#import gpu/for_each.wgsl
#import nn/conv/tile.wgsl

// Output channel `co` at the 4 pixels starting at vec4 `quad` of the plane, when both
// exist.
fn store(n: u32, co: u32, quad: u32, v: vec4<f32>) {
    let quads = p.h_out * p.w_out / 4u;
    if co < p.c_out && quad < quads {
        y[(n * p.c_out + co) * quads + quad] = vec4<Elem>(v);
    }
}

// Tiles of 8 pixels (2 vec4 quads) in a plane.
fn plane_tiles() -> u32 {
    return (p.h_in * p.w_in / 4u + 1u) / 2u;
}

fn count() -> u32 { return p.batch * channel_blocks() * plane_tiles(); }

fn each(i: u32) {
    let blocks = channel_blocks();
    let quads = p.h_in * p.w_in / 4u;
    let tiles = plane_tiles();
    let q0 = (i % tiles) * 2u;
    let q1 = min(q0 + 1u, quads - 1u);
    let block = (i / tiles) % blocks;
    let n = i / (tiles * blocks);
    let start = bias_lanes(block);
    let lo = start.lo;
    let hi = start.hi;
    // Channel k's first four pixels in ak, its next four in bk.
    var a0 = vec4<f32>(lo[0]);
    var a1 = vec4<f32>(lo[1]);
    var a2 = vec4<f32>(lo[2]);
    var a3 = vec4<f32>(lo[3]);
    var a4 = vec4<f32>(hi[0]);
    var a5 = vec4<f32>(hi[1]);
    var a6 = vec4<f32>(hi[2]);
    var a7 = vec4<f32>(hi[3]);
    var b0 = vec4<f32>(lo[0]);
    var b1 = vec4<f32>(lo[1]);
    var b2 = vec4<f32>(lo[2]);
    var b3 = vec4<f32>(lo[3]);
    var b4 = vec4<f32>(hi[0]);
    var b5 = vec4<f32>(hi[1]);
    var b6 = vec4<f32>(hi[2]);
    var b7 = vec4<f32>(hi[3]);
    let lanes = 2u * blocks;
    for (var ci = 0u; ci < p.c_in; ci++) {
        let plane = (n * p.c_in + ci) * quads;
        let x0 = x_quad(plane + q0);
        let x1 = x_quad(plane + q1);
        let wl = weight_quad(ci * lanes + 2u * block);
        let wh = weight_quad(ci * lanes + 2u * block + 1u);
        a0 += x0 * wl[0];
        a1 += x0 * wl[1];
        a2 += x0 * wl[2];
        a3 += x0 * wl[3];
        a4 += x0 * wh[0];
        a5 += x0 * wh[1];
        a6 += x0 * wh[2];
        a7 += x0 * wh[3];
        b0 += x1 * wl[0];
        b1 += x1 * wl[1];
        b2 += x1 * wl[2];
        b3 += x1 * wl[3];
        b4 += x1 * wh[0];
        b5 += x1 * wh[1];
        b6 += x1 * wh[2];
        b7 += x1 * wh[3];
    }
    store(n, 8u * block + 0u, q0, a0);
    store(n, 8u * block + 1u, q0, a1);
    store(n, 8u * block + 2u, q0, a2);
    store(n, 8u * block + 3u, q0, a3);
    store(n, 8u * block + 4u, q0, a4);
    store(n, 8u * block + 5u, q0, a5);
    store(n, 8u * block + 6u, q0, a6);
    store(n, 8u * block + 7u, q0, a7);
    if q0 + 1u < quads {
        store(n, 8u * block + 0u, q0 + 1u, b0);
        store(n, 8u * block + 1u, q0 + 1u, b1);
        store(n, 8u * block + 2u, q0 + 1u, b2);
        store(n, 8u * block + 3u, q0 + 1u, b3);
        store(n, 8u * block + 4u, q0 + 1u, b4);
        store(n, 8u * block + 5u, q0 + 1u, b5);
        store(n, 8u * block + 6u, q0 + 1u, b6);
        store(n, 8u * block + 7u, q0 + 1u, b7);
    }
}
