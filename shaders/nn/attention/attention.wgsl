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

#import gpu/for_each.wgsl
#import nn/attention/query.wgsl

#bind p: uniform AttentionParams
#bind q, prefix, kv: read array<Elem>
#bind out: read_write array<Elem>

// Value `at` of key j's rows: from the prefix for the first prefix_keys keys.
fn key_value(cached: bool, at: u32) -> f32 {
    if cached {
        return f32(prefix[at]);
    }
    return f32(kv[at]);
}

fn count() -> u32 { return p.sequences * p.heads * p.queries; }

fn each(id: u32) {
    let a = attention_query(id);
    if !a.live {
        return;
    }
    let d = a.d;
    let q_row = (a.s * p.queries + a.i) * p.q_stride + p.q_offset + a.h * d;
    var acc: array<f32, MAX_HEAD_SIZE>;
    var best = -3.0e38;
    var total = 0.0;
    for (var j = 0u; j < a.keys; j++) {
        let cached = j < p.prefix_keys;
        let row = key_row(a, j);
        var dot = 0.0;
        for (var e = 0u; e < d; e++) {
            dot += f32(q[q_row + e]) * key_value(cached, row + p.k_offset + e);
        }
        let score = dot * a.scale;
        let new_best = max(best, score);
        let rescale = exp(best - new_best);
        let weight = exp(score - new_best);
        total = total * rescale + weight;
        for (var e = 0u; e < d; e++) {
            acc[e] = acc[e] * rescale + weight * key_value(cached, row + p.v_offset + e);
        }
        best = new_best;
    }
    let o_row = (a.s * p.queries + a.i) * p.channels + a.h * d;
    for (var e = 0u; e < d; e++) {
        out[o_row + e] = Elem(acc[e] / total);
    }
}
