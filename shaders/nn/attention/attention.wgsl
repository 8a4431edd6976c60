// Multi-head softmax attention over independent sequences (Elem storage, f32 arithmetic).
// Queries are read from rows of `q` (row stride q_stride, head h at q_offset + h·d), keys
// and values from rows of `kv` (k_offset, v_offset), so packed qkv projections need no
// splitting; `kv_share` consecutive sequences read the same keys (one action token for
// every frame of a group). One thread per (sequence, head, query), an online softmax in
// one pass over the keys. With `causal` set, query i sees keys j <= i + keys - queries
// (the queries are the last ones of the sequence). Head size at most MAX_HEAD_SIZE (host-checked).
// The first `prefix_keys` keys of a sequence are rows of `prefix` (a cache), the rest rows
// of `kv`: the same keys in the same order as one concatenated buffer. With `rows` set,
// self-attention runs over consecutive runs of rows cut at row `rows` (a shorter last run).

@group(0) @binding(0) var<uniform> p: AttentionParams;
@group(0) @binding(1) var<storage, read> q: array<Elem>;
@group(0) @binding(2) var<storage, read> prefix: array<Elem>;
@group(0) @binding(3) var<storage, read> kv: array<Elem>;
@group(0) @binding(4) var<storage, read_write> out: array<Elem>;

// Value `at` of key j's rows: from the prefix for the first prefix_keys keys.
fn key_value(cached: bool, at: u32) -> f32 {
    if cached {
        return f32(prefix[at]);
    }
    return f32(kv[at]);
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
    let scale = inverseSqrt(f32(d));
    let q_row = (s * p.queries + i) * p.q_stride + p.q_offset + h * d;
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
    var acc: array<f32, MAX_HEAD_SIZE>;
    var best = -3.0e38;
    var total = 0.0;
    let fresh = p.keys - p.prefix_keys;
    for (var j = 0u; j < keys; j++) {
        let cached = j < p.prefix_keys;
        var row = (kv_sequence * fresh + j - p.prefix_keys) * p.kv_stride + h * d;
        if cached {
            row = (kv_sequence * p.prefix_keys + j) * p.kv_stride + h * d;
        }
        var dot = 0.0;
        for (var e = 0u; e < d; e++) {
            dot += f32(q[q_row + e]) * key_value(cached, row + p.k_offset + e);
        }
        let score = dot * scale;
        let new_best = max(best, score);
        let rescale = exp(best - new_best);
        let weight = exp(score - new_best);
        total = total * rescale + weight;
        for (var e = 0u; e < d; e++) {
            acc[e] = acc[e] * rescale + weight * key_value(cached, row + p.v_offset + e);
        }
        best = new_best;
    }
    let o_row = (s * p.queries + i) * p.channels + h * d;
    for (var e = 0u; e < d; e++) {
        out[o_row + e] = Elem(acc[e] / total);
    }
}
