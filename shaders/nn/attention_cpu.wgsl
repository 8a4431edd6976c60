// Multi-head softmax attention for CPU drivers: attention.wgsl's contract (see there),
// for heads of at most 32 values with every row offset and stride a multiple of 4
// (host-checked). q, the accumulator and each key and value row are held as up to 8
// vec4 registers written out by name (a CPU driver keeps a dynamically indexed array in
// memory), and the rows are read as texels (src/gpu/texels.rs: a vector gather on
// lavapipe, where a storage load is a loop over lanes). Dot products sum in vec4 chunks.
// The first `prefix_keys` keys come from `prefix`, as in attention.wgsl.

@group(0) @binding(0) var<uniform> p: AttentionParams;
@group(0) @binding(1) var q: texture_2d<f32>;
@group(0) @binding(2) var prefix: texture_2d<f32>;
@group(0) @binding(3) var kv: texture_2d<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<Elem>>;

// Chunk `c` (4 values) of the row starting at vec4 `row` of the prefix (`cached`) or kv,
// zero past the head.
fn kv_chunk(cached: bool, row: u32, c: u32, chunks: u32) -> vec4<f32> {
    if c >= chunks {
        return vec4<f32>(0.0);
    }
    if cached {
        return texel(prefix, row + c);
    }
    return texel(kv, row + c);
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

    var q0 = vec4<f32>(0.0);
    var q1 = vec4<f32>(0.0);
    var q2 = vec4<f32>(0.0);
    var q3 = vec4<f32>(0.0);
    var q4 = vec4<f32>(0.0);
    var q5 = vec4<f32>(0.0);
    var q6 = vec4<f32>(0.0);
    var q7 = vec4<f32>(0.0);
    if chunks > 0u { q0 = texel(q, q_row) * scale; }
    if chunks > 1u { q1 = texel(q, q_row + 1u) * scale; }
    if chunks > 2u { q2 = texel(q, q_row + 2u) * scale; }
    if chunks > 3u { q3 = texel(q, q_row + 3u) * scale; }
    if chunks > 4u { q4 = texel(q, q_row + 4u) * scale; }
    if chunks > 5u { q5 = texel(q, q_row + 5u) * scale; }
    if chunks > 6u { q6 = texel(q, q_row + 6u) * scale; }
    if chunks > 7u { q7 = texel(q, q_row + 7u) * scale; }
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    var acc4 = vec4<f32>(0.0);
    var acc5 = vec4<f32>(0.0);
    var acc6 = vec4<f32>(0.0);
    var acc7 = vec4<f32>(0.0);
    var best = -3.0e38;
    var total = 0.0;
    let fresh = p.keys - p.prefix_keys;
    for (var j = 0u; j < keys; j++) {
        let cached = j < p.prefix_keys;
        var row = (kv_sequence * fresh + j - p.prefix_keys) * p.kv_stride + h * d;
        if cached {
            row = (kv_sequence * p.prefix_keys + j) * p.kv_stride + h * d;
        }
        let k_row = (row + p.k_offset) / 4u;
        let v_row = (row + p.v_offset) / 4u;
        var score = dot(q0, kv_chunk(cached, k_row, 0u, chunks)) + dot(q1, kv_chunk(cached, k_row, 1u, chunks));
        score += dot(q2, kv_chunk(cached, k_row, 2u, chunks)) + dot(q3, kv_chunk(cached, k_row, 3u, chunks));
        if chunks > 4u {
            score += dot(q4, kv_chunk(cached, k_row, 4u, chunks)) + dot(q5, kv_chunk(cached, k_row, 5u, chunks));
            score += dot(q6, kv_chunk(cached, k_row, 6u, chunks)) + dot(q7, kv_chunk(cached, k_row, 7u, chunks));
        }
        let new_best = max(best, score);
        let rescale = exp(best - new_best);
        let weight = exp(score - new_best);
        total = total * rescale + weight;
        acc0 = acc0 * rescale + weight * kv_chunk(cached, v_row, 0u, chunks);
        acc1 = acc1 * rescale + weight * kv_chunk(cached, v_row, 1u, chunks);
        acc2 = acc2 * rescale + weight * kv_chunk(cached, v_row, 2u, chunks);
        acc3 = acc3 * rescale + weight * kv_chunk(cached, v_row, 3u, chunks);
        if chunks > 4u {
            acc4 = acc4 * rescale + weight * kv_chunk(cached, v_row, 4u, chunks);
            acc5 = acc5 * rescale + weight * kv_chunk(cached, v_row, 5u, chunks);
            acc6 = acc6 * rescale + weight * kv_chunk(cached, v_row, 6u, chunks);
            acc7 = acc7 * rescale + weight * kv_chunk(cached, v_row, 7u, chunks);
        }
        best = new_best;
    }
    let o_row = ((s * p.queries + i) * p.channels + h * d) / 4u;
    let inv = 1.0 / total;
    if chunks > 0u { out[o_row + 0u] = vec4<Elem>(acc0 * inv); }
    if chunks > 1u { out[o_row + 1u] = vec4<Elem>(acc1 * inv); }
    if chunks > 2u { out[o_row + 2u] = vec4<Elem>(acc2 * inv); }
    if chunks > 3u { out[o_row + 3u] = vec4<Elem>(acc3 * inv); }
    if chunks > 4u { out[o_row + 4u] = vec4<Elem>(acc4 * inv); }
    if chunks > 5u { out[o_row + 5u] = vec4<Elem>(acc5 * inv); }
    if chunks > 6u { out[o_row + 6u] = vec4<Elem>(acc6 * inv); }
    if chunks > 7u { out[o_row + 7u] = vec4<Elem>(acc7 * inv); }
}
