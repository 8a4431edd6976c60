// Multi-head softmax attention for CPU drivers: attention.wgsl's contract (see there),
// for heads of at most 32 values with every row offset and stride a multiple of 4
// (host-checked). Each invocation serves two neighbouring queries of a run and fetches
// each key and value row once for both. q, the accumulators and each key and value row
// are held as up to 8 vec4 registers written out by name (a CPU driver keeps a
// dynamically indexed array in memory; the accumulators ride in structs of named
// fields), and the rows are read as texels (src/gpu/texels.rs: a vector gather on
// lavapipe, where a storage load is a loop over lanes). Dot products sum in vec4 chunks
// (snippets/online_softmax.wgsl). The first `prefix_keys` keys come from `prefix`, as
// in attention.wgsl.

#import gpu/for_each.wgsl

#import nn/attention/online_softmax.wgsl
#import nn/attention/query.wgsl

#bind p: uniform AttentionParams
#bind q_in, prefix, kv: texture_2d<f32>
#bind out: read_write array<vec4<Elem>>

// Two neighbouring queries of a (sequence, head) per invocation: each key and value
// row is fetched once for both (on lavapipe the fetches cost more than the sums: this
// kernel's 15 dispatches of a live frame took 66 ms with one query an invocation, 48
// with two; docs/performance.md, "Stores and fetches"). A
// query past the end of its run, or one that sees fewer keys (causal), skips the keys
// it does not see: its running softmax is kept as it was.
fn pairs() -> u32 { return (p.queries + 1u) / 2u; }

fn count() -> u32 { return p.sequences * p.heads * pairs(); }

// q of query `a`, scaled, in 8 chunks (zero past the head, so the padding chunks add
// exact zeros).
struct Q {
    q0: vec4<f32>,
    q1: vec4<f32>,
    q2: vec4<f32>,
    q3: vec4<f32>,
    q4: vec4<f32>,
    q5: vec4<f32>,
    q6: vec4<f32>,
    q7: vec4<f32>,
}

fn load_q(a: Query) -> Q {
    let chunks = a.d / 4u;
    let row = ((a.s * p.queries + a.i) * p.q_stride + p.q_offset + a.h * a.d) / 4u;
    var q = Q(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    if !a.live {
        return q;
    }
    if chunks > 0u { q.q0 = texel(q_in, row) * a.scale; }
    if chunks > 1u { q.q1 = texel(q_in, row + 1u) * a.scale; }
    if chunks > 2u { q.q2 = texel(q_in, row + 2u) * a.scale; }
    if chunks > 3u { q.q3 = texel(q_in, row + 3u) * a.scale; }
    if chunks > 4u { q.q4 = texel(q_in, row + 4u) * a.scale; }
    if chunks > 5u { q.q5 = texel(q_in, row + 5u) * a.scale; }
    if chunks > 6u { q.q6 = texel(q_in, row + 6u) * a.scale; }
    if chunks > 7u { q.q7 = texel(q_in, row + 7u) * a.scale; }
    return q;
}

// The dot products of q with the key row's chunks k0 … k7 (the last 4 only when
// `wide`), summed as score4 and score8 do.
fn dot_row(q: Q, k0: vec4<f32>, k1: vec4<f32>, k2: vec4<f32>, k3: vec4<f32>, k4: vec4<f32>, k5: vec4<f32>, k6: vec4<f32>, k7: vec4<f32>, wide: bool) -> f32 {
    var score = dot(q.q0, k0) + dot(q.q1, k1);
    score += dot(q.q2, k2) + dot(q.q3, k3);
    if wide {
        score += dot(q.q4, k4) + dot(q.q5, k5);
        score += dot(q.q6, k6) + dot(q.q7, k7);
    }
    return score;
}

// The pair's running softmaxes.
struct Pair {
    a: Online,
    b: Online,
}

// Key j of the pair (its row at texel k of `t`, its value row at texel v): each query
// that sees it takes it.
fn take_pair(o: Pair, qa: Q, qb: Q, t: texture_2d<f32>, k: u32, v: u32, wide: bool, see_a: bool, see_b: bool) -> Pair {
    let zero = vec4<f32>(0.0);
    let k0 = texel(t, k);
    let k1 = texel(t, k + 1u);
    let k2 = texel(t, k + 2u);
    let k3 = texel(t, k + 3u);
    var k4 = zero;
    var k5 = zero;
    var k6 = zero;
    var k7 = zero;
    let v0 = texel(t, v);
    let v1 = texel(t, v + 1u);
    let v2 = texel(t, v + 2u);
    let v3 = texel(t, v + 3u);
    var v4 = zero;
    var v5 = zero;
    var v6 = zero;
    var v7 = zero;
    if wide {
        k4 = texel(t, k + 4u);
        k5 = texel(t, k + 5u);
        k6 = texel(t, k + 6u);
        k7 = texel(t, k + 7u);
        v4 = texel(t, v + 4u);
        v5 = texel(t, v + 5u);
        v6 = texel(t, v + 6u);
        v7 = texel(t, v + 7u);
    }
    let sa = dot_row(qa, k0, k1, k2, k3, k4, k5, k6, k7, wide);
    let sb = dot_row(qb, k0, k1, k2, k3, k4, k5, k6, k7, wide);
    var n = o;
    let ta = take(o.a, sa, v0, v1, v2, v3, v4, v5, v6, v7, wide);
    let tb = take(o.b, sb, v0, v1, v2, v3, v4, v5, v6, v7, wide);
    if see_a {
        n.a = ta;
    }
    if see_b {
        n.b = tb;
    }
    return n;
}

fn each(id: u32) {
    let pair = id % pairs();
    let rest = id / pairs();
    let first = rest * p.queries + 2u * pair;
    let a = attention_query(first);
    var b = attention_query(first + 1u);
    // The second of an odd run's last pair is no query.
    b.live = b.live && 2u * pair + 1u < p.queries;
    if !b.live {
        b.keys = 0u;
    }
    let chunks = a.d / 4u;
    let qa = load_q(a);
    let qb = load_q(b);
    let keys = max(a.keys, b.keys);
    var o = Pair(online_start(), online_start());
    // The cached keys (prefix) then the fresh ones (kv), each in a loop of its own, and
    // heads of up to 16 values apart from wider ones: a CPU driver runs both sides of a
    // branch under a lane mask, so a branch per key would fetch from both textures and
    // all 8 chunks for every key.
    let cached = min(keys, p.prefix_keys);
    let wide = chunks > 4u;
    if wide {
        for (var j = 0u; j < cached; j++) {
            let row = key_row(a, j);
            o = take_pair(o, qa, qb, prefix, (row + p.k_offset) / 4u, (row + p.v_offset) / 4u, true, j < a.keys, j < b.keys);
        }
        for (var j = cached; j < keys; j++) {
            let row = key_row(a, j);
            o = take_pair(o, qa, qb, kv, (row + p.k_offset) / 4u, (row + p.v_offset) / 4u, true, j < a.keys, j < b.keys);
        }
    } else {
        for (var j = 0u; j < cached; j++) {
            let row = key_row(a, j);
            o = take_pair(o, qa, qb, prefix, (row + p.k_offset) / 4u, (row + p.v_offset) / 4u, false, j < a.keys, j < b.keys);
        }
        for (var j = cached; j < keys; j++) {
            let row = key_row(a, j);
            o = take_pair(o, qa, qb, kv, (row + p.k_offset) / 4u, (row + p.v_offset) / 4u, false, j < a.keys, j < b.keys);
        }
    }
    if a.live {
        store_online(o.a, ((a.s * p.queries + a.i) * p.channels + a.h * a.d) / 4u, chunks);
    }
    if b.live {
        store_online(o.b, ((b.s * p.queries + b.i) * p.channels + b.h * b.d) / 4u, chunks);
    }
}
