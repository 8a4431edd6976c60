// Multi-head softmax attention for CPU drivers: attention.wgsl's contract (see there),
// for heads of at most 32 values with every row offset and stride a multiple of 4
// (host-checked). q, the accumulator and each key and value row are held as up to 8
// vec4 registers written out by name (a CPU driver keeps a dynamically indexed array in
// memory; the accumulator rides in a struct of named fields), and the rows are read as
// texels (src/gpu/texels.rs: a vector gather on lavapipe, where a storage load is a loop
// over lanes). Dot products sum in vec4 chunks (snippets/online_softmax.wgsl). The first
// `prefix_keys` keys come from `prefix`, as in attention.wgsl.

#import gpu/for_each.wgsl

#import nn/attention/online_softmax.wgsl
#import nn/attention/query.wgsl

#bind p: uniform AttentionParams
#bind q_in, prefix, kv: texture_2d<f32>
#bind out: read_write array<vec4<Elem>>

fn count() -> u32 { return p.sequences * p.heads * p.queries; }

fn each(id: u32) {
    let a = attention_query(id);
    if !a.live {
        return;
    }
    let chunks = a.d / 4u;
    let scale = a.scale;
    let keys = a.keys;
    let q_row = ((a.s * p.queries + a.i) * p.q_stride + p.q_offset + a.h * a.d) / 4u;

    // q in registers, zero past the head (so the padding chunks add exact zeros).
    var q0 = vec4<f32>(0.0);
    var q1 = vec4<f32>(0.0);
    var q2 = vec4<f32>(0.0);
    var q3 = vec4<f32>(0.0);
    var q4 = vec4<f32>(0.0);
    var q5 = vec4<f32>(0.0);
    var q6 = vec4<f32>(0.0);
    var q7 = vec4<f32>(0.0);
    if chunks > 0u { q0 = texel(q_in, q_row) * scale; }
    if chunks > 1u { q1 = texel(q_in, q_row + 1u) * scale; }
    if chunks > 2u { q2 = texel(q_in, q_row + 2u) * scale; }
    if chunks > 3u { q3 = texel(q_in, q_row + 3u) * scale; }
    if chunks > 4u { q4 = texel(q_in, q_row + 4u) * scale; }
    if chunks > 5u { q5 = texel(q_in, q_row + 5u) * scale; }
    if chunks > 6u { q6 = texel(q_in, q_row + 6u) * scale; }
    if chunks > 7u { q7 = texel(q_in, q_row + 7u) * scale; }
    var o = online_start();
    // The cached keys (prefix) then the fresh ones (kv), each in a loop of its own, and
    // heads of up to 16 values apart from wider ones: a CPU driver runs both sides of a
    // branch under a lane mask, so a branch per key would fetch from both textures and
    // all 8 chunks for every key.
    let cached = min(keys, p.prefix_keys);
    let wide = chunks > 4u;
    if wide {
        for (var j = 0u; j < cached; j++) {
            let row = key_row(a, j);
            o = take_row(o, score8(prefix, (row + p.k_offset) / 4u, q0, q1, q2, q3, q4, q5, q6, q7), prefix, (row + p.v_offset) / 4u, true);
        }
        for (var j = cached; j < keys; j++) {
            let row = key_row(a, j);
            o = take_row(o, score8(kv, (row + p.k_offset) / 4u, q0, q1, q2, q3, q4, q5, q6, q7), kv, (row + p.v_offset) / 4u, true);
        }
    } else {
        for (var j = 0u; j < cached; j++) {
            let row = key_row(a, j);
            o = take_row(o, score4(prefix, (row + p.k_offset) / 4u, q0, q1, q2, q3), prefix, (row + p.v_offset) / 4u, false);
        }
        for (var j = cached; j < keys; j++) {
            let row = key_row(a, j);
            o = take_row(o, score4(kv, (row + p.k_offset) / 4u, q0, q1, q2, q3), kv, (row + p.v_offset) / 4u, false);
        }
    }
    store_online(o, ((a.s * p.queries + a.i) * p.channels + a.h * a.d) / 4u, chunks);
}
