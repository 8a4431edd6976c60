// 2-D convolution for GPUs (NCHW, Elem storage, f32 sums; any square kernel, stride and
// padding): conv2d.wgsl's result, with one workgroup per tile of 4 neighbouring output
// pixels of a row × 8 output channels, its WORKGROUP threads splitting the terms
// (thread t takes term t, t + WORKGROUP, … of the c_in × k × k, in (c_in, ky, kx)
// order) and summing their partial tiles through workgroup memory. conv2d_tiled.wgsl's
// thread per tile left an H200 with a few hundred threads busy on the VAE encoder's
// stride-2 convolutions: 305 µs a convolution (docs/gpu). Taps outside the input add
// nothing. Weights [c_out, c_in, k, k], optional bias [c_out] added to the summed tile.

#import nn/conv/tile.wgsl

#bind p: uniform Conv2dParams
#bind x, weight, bias: read array<Elem>
#bind y: read_write array<Elem>

// Each thread's partial tile: pixel j's channels 0-3 at 8t + j, 4-7 at 8t + 4 + j.
var<workgroup> partial: array<vec4<f32>, 8u * WORKGROUP>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    // The tile: the workgroup's linear index (the few past the end compute and store
    // nothing, and take part in the barrier).
    let i = group_index(invocation);
    let t = invocation.lane;
    let live = i < tile_count(4u);
    let tile = tile_at(i, 4u);
    let last = p.c_out - 1u;
    let co = min(vec4<u32>(8u * tile.block) + vec4<u32>(0u, 1u, 2u, 3u), vec4<u32>(last));
    let co2 = min(co + vec4<u32>(4u), vec4<u32>(last));
    let taps = p.kernel * p.kernel;
    let terms = select(0u, p.c_in * taps, live);
    // Pixel j's first four channels in aj, its second four in bj.
    var a0 = vec4<f32>(0.0);
    var a1 = vec4<f32>(0.0);
    var a2 = vec4<f32>(0.0);
    var a3 = vec4<f32>(0.0);
    var b0 = vec4<f32>(0.0);
    var b1 = vec4<f32>(0.0);
    var b2 = vec4<f32>(0.0);
    var b3 = vec4<f32>(0.0);
    let left = i32(tile.ox0 * p.stride) - i32(p.pad);
    let step = i32(p.stride);
    for (var r = t; r < terms; r += WORKGROUP) {
        let ci = r / taps;
        let tap = r % taps;
        let ky = tap / p.kernel;
        let kx = tap % p.kernel;
        let iy = i32(tile.oy * p.stride + ky) - i32(p.pad);
        if iy < 0 || iy >= i32(p.h_in) {
            continue;
        }
        let w = co * (p.c_in * taps) + vec4<u32>(r);
        let w2 = co2 * (p.c_in * taps) + vec4<u32>(r);
        let wa = vec4<f32>(f32(weight[w.x]), f32(weight[w.y]), f32(weight[w.z]), f32(weight[w.w]));
        let wb = vec4<f32>(f32(weight[w2.x]), f32(weight[w2.y]), f32(weight[w2.z]), f32(weight[w2.w]));
        let row = ((tile.n * p.c_in + ci) * p.h_in + u32(iy)) * p.w_in;
        let ix = vec4<i32>(left + i32(kx)) + step * vec4<i32>(0, 1, 2, 3);
        let inside = ix >= vec4<i32>(0) & ix < vec4<i32>(i32(p.w_in));
        let at = vec4<u32>(clamp(ix, vec4<i32>(0), vec4<i32>(i32(p.w_in) - 1))) + vec4<u32>(row);
        let v = select(vec4<f32>(0.0), vec4<f32>(f32(x[at.x]), f32(x[at.y]), f32(x[at.z]), f32(x[at.w])), inside);
        a0 += v.x * wa;
        a1 += v.y * wa;
        a2 += v.z * wa;
        a3 += v.w * wa;
        b0 += v.x * wb;
        b1 += v.y * wb;
        b2 += v.z * wb;
        b3 += v.w * wb;
    }
    let slot = 8u * t;
    partial[slot + 0u] = a0;
    partial[slot + 1u] = a1;
    partial[slot + 2u] = a2;
    partial[slot + 3u] = a3;
    partial[slot + 4u] = b0;
    partial[slot + 5u] = b1;
    partial[slot + 6u] = b2;
    partial[slot + 7u] = b3;
    workgroupBarrier();
    // Thread t < 32 sums value t of the tile (pixel j = t % 4, channel c = t / 4) over the
    // threads, in thread order, then adds the bias and stores it.
    if !live || t >= 32u {
        return;
    }
    let j = t % 4u;
    let c = t / 4u;
    let q = select(j, 4u + j, c >= 4u);
    var sum = 0.0;
    for (var k = 0u; k < WORKGROUP; k++) {
        sum += partial[8u * k + q][c % 4u];
    }
    let channel = 8u * tile.block + c;
    let ox = tile.ox0 + j;
    if channel >= p.c_out || ox >= p.w_out {
        return;
    }
    if p.has_bias != 0u {
        sum = f32(bias[channel]) + sum;
    }
    y[((tile.n * p.c_out + channel) * p.h_out + tile.oy) * p.w_out + ox] = Elem(sum);
}
