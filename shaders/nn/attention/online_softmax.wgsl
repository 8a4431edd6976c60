// The running softmax of one query over its keys, key by key, and the scores and value
// rows read as texels (the CPU-driver attention kernels): the best score so far, the sum of exp(score - best) and the weighted sum of
// the value rows, in up to 8 named chunks of 4 (a CPU driver keeps a dynamically
// indexed array in memory).
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

fn online_start() -> Online {
    let zero = vec4<f32>(0.0);
    return Online(-3.0e38, 0.0, zero, zero, zero, zero, zero, zero, zero, zero);
}

// One more key: its score and its value row's chunks (the last 4 only when `wide`).
fn take(o: Online, score: f32, v0: vec4<f32>, v1: vec4<f32>, v2: vec4<f32>, v3: vec4<f32>, v4: vec4<f32>, v5: vec4<f32>, v6: vec4<f32>, v7: vec4<f32>, wide: bool) -> Online {
    var n = o;
    let new_best = max(o.best, score);
    let rescale = exp(o.best - new_best);
    let weight = exp(score - new_best);
    n.total = o.total * rescale + weight;
    n.a0 = o.a0 * rescale + weight * v0;
    n.a1 = o.a1 * rescale + weight * v1;
    n.a2 = o.a2 * rescale + weight * v2;
    n.a3 = o.a3 * rescale + weight * v3;
    if wide {
        n.a4 = o.a4 * rescale + weight * v4;
        n.a5 = o.a5 * rescale + weight * v5;
        n.a6 = o.a6 * rescale + weight * v6;
        n.a7 = o.a7 * rescale + weight * v7;
    }
    n.best = new_best;
    return n;
}

// The query's output chunks (those of the head) stored at vec4 `row` of `out`.
fn store_online(o: Online, row: u32, chunks: u32) {
    let inv = 1.0 / o.total;
    if chunks > 0u { out[row + 0u] = vec4<Elem>(o.a0 * inv); }
    if chunks > 1u { out[row + 1u] = vec4<Elem>(o.a1 * inv); }
    if chunks > 2u { out[row + 2u] = vec4<Elem>(o.a2 * inv); }
    if chunks > 3u { out[row + 3u] = vec4<Elem>(o.a3 * inv); }
    if chunks > 4u { out[row + 4u] = vec4<Elem>(o.a4 * inv); }
    if chunks > 5u { out[row + 5u] = vec4<Elem>(o.a5 * inv); }
    if chunks > 6u { out[row + 6u] = vec4<Elem>(o.a6 * inv); }
    if chunks > 7u { out[row + 7u] = vec4<Elem>(o.a7 * inv); }
}

// One more key with its value row at texel `v` of
// `t`: 4 chunks, or 8 when `wide`.
fn take_row(o: Online, score: f32, t: texture_2d<f32>, v: u32, wide: bool) -> Online {
    if wide {
        return take(o, score, texel(t, v), texel(t, v + 1u), texel(t, v + 2u), texel(t, v + 3u), texel(t, v + 4u), texel(t, v + 5u), texel(t, v + 6u), texel(t, v + 7u), true);
    }
    let zero = vec4<f32>(0.0);
    return take(o, score, texel(t, v), texel(t, v + 1u), texel(t, v + 2u), texel(t, v + 3u), zero, zero, zero, zero, false);
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
