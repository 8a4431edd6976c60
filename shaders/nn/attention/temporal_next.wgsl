// A temporal attention layer's projection and attention for one new frame, for CPU
// drivers: each sequence (a pixel) has one query row, so its fresh key and value are
// read by its own query only, and one invocation per (sequence, head) projects the
// head's q, k and v from the token row itself (no qkv tensor, no second dispatch), then
// attends over the cached rows of the earlier frames (`prefix`, rows of q | k | v as the
// context pass kept them) and its own key. The projection sums each output as
// linear_cpu.wgsl does (bias, then the inputs in order, four at a time) and rounds it to
// Elem as the stored qkv would be; the attention is attention_cpu.wgsl's, key by key in
// the same order. Heads of at most 32 values, channels a multiple of 4 (host-checked);
// the parameters are the separate attention's (queries = 1, prefix_keys cached keys).
// Inputs, weights and the cache are read as texels (src/gpu/texels.rs).

#import gpu/for_each.wgsl

#import nn/attention/online_softmax.wgsl

#bind p: uniform AttentionParams
// [sequences, channels] token rows.
#bind x: texture_2d<f32>
// The qkv projection's weight [3 · channels, channels] and bias.
#bind weight: texture_2d<f32>
#bind bias: read array<Elem>
// [sequences, prefix_keys, 3 · channels]: the cached rows.
#bind prefix: texture_2d<f32>
#bind out: read_write array<vec4<Elem>>

// Four outputs' weights at texel rows `rows` + k, as columns (input 4k + j of the four
// outputs in column j), as linear_cpu.wgsl's transposed().
fn columns(rows: vec4<u32>, k: u32) -> mat4x4<f32> {
    let w0 = texel(weight, rows.x + k);
    let w1 = texel(weight, rows.y + k);
    let w2 = texel(weight, rows.z + k);
    let w3 = texel(weight, rows.w + k);
    return mat4x4<f32>(
        vec4<f32>(w0.x, w1.x, w2.x, w3.x),
        vec4<f32>(w0.y, w1.y, w2.y, w3.y),
        vec4<f32>(w0.z, w1.z, w2.z, w3.z),
        vec4<f32>(w0.w, w1.w, w2.w, w3.w),
    );
}

// The bias of outputs o … o + 3.
fn bias4(o: u32) -> vec4<f32> {
    let last = 3u * p.channels - 1u;
    let outputs = min(vec4<u32>(o) + vec4<u32>(0u, 1u, 2u, 3u), vec4<u32>(last));
    return vec4<f32>(f32(bias[outputs.x]), f32(bias[outputs.y]), f32(bias[outputs.z]), f32(bias[outputs.w]));
}

// One chunk (4 values) of the head's q, k and v.
struct Chunk {
    q: vec4<f32>,
    k: vec4<f32>,
    v: vec4<f32>,
}

// Chunk `j` of the head's q, k and v (outputs q0 + 4j …, and the same C and 2C on) from
// the token row at texel `row` (`quads` texels), each output summed as linear_cpu.wgsl
// sums it and rounded to Elem; a zero trip count gives zeros (chunks past the head).
fn project(q0: u32, j: u32, row: u32, quads: u32) -> Chunk {
    var out = Chunk(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    if quads == 0u {
        return out;
    }
    let oq = q0 + 4u * j;
    let ok = oq + p.channels;
    let ov = ok + p.channels;
    var aq = bias4(oq);
    var ak = bias4(ok);
    var av = bias4(ov);
    let four = vec4<u32>(0u, 1u, 2u, 3u);
    let rq = (vec4<u32>(oq) + four) * quads;
    let rk = (vec4<u32>(ok) + four) * quads;
    let rv = (vec4<u32>(ov) + four) * quads;
    for (var k = 0u; k < quads; k++) {
        let x4 = texel(x, row + k);
        let tq = columns(rq, k);
        let tk = columns(rk, k);
        let tv = columns(rv, k);
        aq = aq + x4.x * tq[0] + x4.y * tq[1] + x4.z * tq[2] + x4.w * tq[3];
        ak = ak + x4.x * tk[0] + x4.y * tk[1] + x4.z * tk[2] + x4.w * tk[3];
        av = av + x4.x * tv[0] + x4.y * tv[1] + x4.z * tv[2] + x4.w * tv[3];
    }
    out.q = vec4<f32>(vec4<Elem>(aq));
    out.k = vec4<f32>(vec4<Elem>(ak));
    out.v = vec4<f32>(vec4<Elem>(av));
    return out;
}

fn count() -> u32 { return p.sequences * p.heads; }

fn each(id: u32) {
    let h = id % p.heads;
    let s = id / p.heads;
    let c = p.channels;
    let d = c / p.heads;
    let chunks = d / 4u;
    let quads = c / 4u;
    let row = s * quads;
    // Chunk j of the head's q, k and v (zero past the head).
    let n0 = select(0u, quads, chunks > 0u);
    let n1 = select(0u, quads, chunks > 1u);
    let n2 = select(0u, quads, chunks > 2u);
    let n3 = select(0u, quads, chunks > 3u);
    let n4 = select(0u, quads, chunks > 4u);
    let n5 = select(0u, quads, chunks > 5u);
    let n6 = select(0u, quads, chunks > 6u);
    let n7 = select(0u, quads, chunks > 7u);
    let scale = inverseSqrt(f32(d));
    let q = h * d;
    let c0 = project(q, 0u, row, n0);
    let c1 = project(q, 1u, row, n1);
    let c2 = project(q, 2u, row, n2);
    let c3 = project(q, 3u, row, n3);
    let c4 = project(q, 4u, row, n4);
    let c5 = project(q, 5u, row, n5);
    let c6 = project(q, 6u, row, n6);
    let c7 = project(q, 7u, row, n7);
    let q0 = c0.q * scale;
    let q1 = c1.q * scale;
    let q2 = c2.q * scale;
    let q3 = c3.q * scale;
    let q4 = c4.q * scale;
    let q5 = c5.q * scale;
    let q6 = c6.q * scale;
    let q7 = c7.q * scale;
    let k0 = c0.k;
    let k1 = c1.k;
    let k2 = c2.k;
    let k3 = c3.k;
    let k4 = c4.k;
    let k5 = c5.k;
    let k6 = c6.k;
    let k7 = c7.k;
    let v0 = c0.v;
    let v1 = c1.v;
    let v2 = c2.v;
    let v3 = c3.v;
    let v4 = c4.v;
    let v5 = c5.v;
    let v6 = c6.v;
    let v7 = c7.v;
    var o = online_start();
    // The cached keys, then the sequence's own: heads of up to 16 values apart from wider
    // ones, each in a loop of its own (see attention_cpu.wgsl).
    let wide = chunks > 4u;
    let stride = p.kv_stride / 4u;
    if wide {
        for (var j = 0u; j < p.prefix_keys; j++) {
            let r = (s * p.prefix_keys + j) * stride + h * d / 4u;
            let kr = r + p.k_offset / 4u;
            let vr = r + p.v_offset / 4u;
            let score = score8(prefix, kr, q0, q1, q2, q3, q4, q5, q6, q7);
            o = take_row(o, score, prefix, vr, true);
        }
        var score = dot(q0, k0) + dot(q1, k1);
        score += dot(q2, k2) + dot(q3, k3);
        score += dot(q4, k4) + dot(q5, k5);
        score += dot(q6, k6) + dot(q7, k7);
        o = take(o, score, v0, v1, v2, v3, v4, v5, v6, v7, true);
    } else {
        for (var j = 0u; j < p.prefix_keys; j++) {
            let r = (s * p.prefix_keys + j) * stride + h * d / 4u;
            let kr = r + p.k_offset / 4u;
            let vr = r + p.v_offset / 4u;
            o = take_row(o, score4(prefix, kr, q0, q1, q2, q3), prefix, vr, false);
        }
        var score = dot(q0, k0) + dot(q1, k1);
        score += dot(q2, k2) + dot(q3, k3);
        o = take(o, score, v0, v1, v2, v3, v4, v5, v6, v7, false);
    }
    store_online(o, (s * c + h * d) / 4u, chunks);
}
