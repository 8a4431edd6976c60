// Multi-head softmax attention for CPU drivers: attention.wgsl's contract (see there),
// for heads of at most 32 values with every row offset and stride a multiple of 4
// (host-checked). q, the accumulator and each key and value row are held as up to 8
// vec4 registers written out by name (a CPU driver keeps a dynamically indexed array in
// memory; the accumulator rides in a struct of named fields), and the rows are read as texels (src/gpu/texels.rs: a vector gather on
// lavapipe, where a storage load is a loop over lanes). Dot products sum in vec4 chunks.
// The first `prefix_keys` keys come from `prefix`, as in attention.wgsl.

@group(0) @binding(0) var<uniform> p: AttentionParams;
@group(0) @binding(1) var q_in: texture_2d<f32>;
@group(0) @binding(2) var prefix: texture_2d<f32>;
@group(0) @binding(3) var kv: texture_2d<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<Elem>>;

// The running softmax of one query: the best score so far, the sum of exp(score - best)
// and the weighted sum of the value rows (up to 8 chunks of 4).
struct Online {
    best: f32,
    total: f32,
    a0: vec4<f32>,
    a1: vec4<f32>,
    a2: vec4<f32>,
    a3: vec4<f32>,
    a4: vec4<f32>,
    a5: vec4<f32>,
    a6: vec4<f32>,
    a7: vec4<f32>,
}

// One more key: its score and the first 4 chunks of its value row at texel `v` of `t`
// (the last 4 only when `wide`).
fn take(o: Online, score: f32, t: texture_2d<f32>, v: u32, wide: bool) -> Online {
    var n = o;
    let new_best = max(o.best, score);
    let rescale = exp(o.best - new_best);
    let weight = exp(score - new_best);
    n.total = o.total * rescale + weight;
    n.a0 = o.a0 * rescale + weight * texel(t, v);
    n.a1 = o.a1 * rescale + weight * texel(t, v + 1u);
    n.a2 = o.a2 * rescale + weight * texel(t, v + 2u);
    n.a3 = o.a3 * rescale + weight * texel(t, v + 3u);
    if wide {
        n.a4 = o.a4 * rescale + weight * texel(t, v + 4u);
        n.a5 = o.a5 * rescale + weight * texel(t, v + 5u);
        n.a6 = o.a6 * rescale + weight * texel(t, v + 6u);
        n.a7 = o.a7 * rescale + weight * texel(t, v + 7u);
    }
    n.best = new_best;
    return n;
}

// q (scaled) against the key row at texel `k` of `t`: the first 4 chunks.
fn score4(t: texture_2d<f32>, k: u32, q0: vec4<f32>, q1: vec4<f32>, q2: vec4<f32>, q3: vec4<f32>) -> f32 {
    var score = dot(q0, texel(t, k)) + dot(q1, texel(t, k + 1u));
    score += dot(q2, texel(t, k + 2u)) + dot(q3, texel(t, k + 3u));
    return score;
}

// The last 4 chunks (heads of 20 to 32 values), added in the same order.
fn score8(t: texture_2d<f32>, k: u32, q0: vec4<f32>, q1: vec4<f32>, q2: vec4<f32>, q3: vec4<f32>, q4: vec4<f32>, q5: vec4<f32>, q6: vec4<f32>, q7: vec4<f32>) -> f32 {
    var score = score4(t, k, q0, q1, q2, q3);
    score += dot(q4, texel(t, k + 4u)) + dot(q5, texel(t, k + 5u));
    score += dot(q6, texel(t, k + 6u)) + dot(q7, texel(t, k + 7u));
    return score;
}

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let id = linear_index(invocation);
    if id >= p.sequences * p.heads * p.queries {
        return;
    }
    let i = id % p.queries;
    let h = (id / p.queries) % p.heads;
    let s = id / (p.queries * p.heads);
    let d = p.channels / p.heads;
    let chunks = d / 4u;
    let scale = inverseSqrt(f32(d));
    let q_row = ((s * p.queries + i) * p.q_stride + p.q_offset + h * d) / 4u;
    let kv_sequence = s / p.kv_share;
    var keys = p.keys;
    if p.causal != 0u {
        keys = min(keys, i + 1u + p.keys - p.queries);
    }
    if p.rows != 0u {
        // Runs of `queries` rows that end at row p.rows: the last one is shorter.
        let first = s * p.queries;
        if first + i >= p.rows {
            return;
        }
        keys = min(keys, p.rows - first);
    }

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
    var o = Online(-3.0e38, 0.0, vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    // The cached keys (prefix) then the fresh ones (kv), each in a loop of its own, and
    // heads of up to 16 values apart from wider ones: a CPU driver runs both sides of a
    // branch under a lane mask, so a branch per key would fetch from both textures and
    // all 8 chunks for every key.
    let fresh = p.keys - p.prefix_keys;
    let cached = min(keys, p.prefix_keys);
    let wide = chunks > 4u;
    if wide {
        for (var j = 0u; j < cached; j++) {
            let row = (kv_sequence * p.prefix_keys + j) * p.kv_stride + h * d;
            o = take(o, score8(prefix, (row + p.k_offset) / 4u, q0, q1, q2, q3, q4, q5, q6, q7), prefix, (row + p.v_offset) / 4u, true);
        }
        for (var j = cached; j < keys; j++) {
            let row = (kv_sequence * fresh + j - p.prefix_keys) * p.kv_stride + h * d;
            o = take(o, score8(kv, (row + p.k_offset) / 4u, q0, q1, q2, q3, q4, q5, q6, q7), kv, (row + p.v_offset) / 4u, true);
        }
    } else {
        for (var j = 0u; j < cached; j++) {
            let row = (kv_sequence * p.prefix_keys + j) * p.kv_stride + h * d;
            o = take(o, score4(prefix, (row + p.k_offset) / 4u, q0, q1, q2, q3), prefix, (row + p.v_offset) / 4u, false);
        }
        for (var j = cached; j < keys; j++) {
            let row = (kv_sequence * fresh + j - p.prefix_keys) * p.kv_stride + h * d;
            o = take(o, score4(kv, (row + p.k_offset) / 4u, q0, q1, q2, q3), kv, (row + p.v_offset) / 4u, false);
        }
    }
    let o_row = ((s * p.queries + i) * p.channels + h * d) / 4u;
    let inv = 1.0 / o.total;
    if chunks > 0u { out[o_row + 0u] = vec4<Elem>(o.a0 * inv); }
    if chunks > 1u { out[o_row + 1u] = vec4<Elem>(o.a1 * inv); }
    if chunks > 2u { out[o_row + 2u] = vec4<Elem>(o.a2 * inv); }
    if chunks > 3u { out[o_row + 3u] = vec4<Elem>(o.a3 * inv); }
    if chunks > 4u { out[o_row + 4u] = vec4<Elem>(o.a4 * inv); }
    if chunks > 5u { out[o_row + 5u] = vec4<Elem>(o.a5 * inv); }
    if chunks > 6u { out[o_row + 6u] = vec4<Elem>(o.a6 * inv); }
    if chunks > 7u { out[o_row + 7u] = vec4<Elem>(o.a7 * inv); }
}
