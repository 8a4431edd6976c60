// Multi-head softmax attention for GPUs: attention.wgsl's inputs and result, with one
// workgroup per (sequence, head, query) whose WORKGROUP threads split the keys (thread t
// takes keys t, t + WORKGROUP, …), each an online softmax over its own, then merged
// through workgroup memory: the largest score of all, each thread's total and values
// rescaled to it. attention.wgsl's thread per query ran every key in turn: 270 µs a
// spatial attention on an H200 (docs/gpu). Queries are read from rows of `q` (row
// stride q_stride, head h at q_offset + h·d), keys and values from rows of `kv`
// (k_offset, v_offset); `kv_share` consecutive sequences read the same keys. With
// `causal` set, query i sees keys j <= i + keys - queries. The first `prefix_keys` keys
// of a sequence are rows of `prefix` (a cache), the rest rows of `kv`: each key goes to
// the same thread either way, so the two give the same bits. With `rows` set,
// self-attention runs over consecutive runs of rows cut at row `rows`. Head size at most
// MAX_HEAD_SIZE (host-checked).

#import nn/attention/query.wgsl

#bind p: uniform AttentionParams
#bind q, prefix, kv: read array<Elem>
#bind out: read_write array<Elem>

// Each thread's running maximum, total and weighted values (rows of MAX_HEAD_SIZE + 1,
// so the threads' writes fall in different banks).
const ROW: u32 = MAX_HEAD_SIZE + 1u;
var<workgroup> best_of: array<f32, WORKGROUP>;
var<workgroup> total_of: array<f32, WORKGROUP>;
var<workgroup> acc_of: array<f32, ROW * WORKGROUP>;

// Value `at` of key j's rows: from the prefix for the first prefix_keys keys.
fn key_value(cached: bool, at: u32) -> f32 {
    if cached {
        return f32(prefix[at]);
    }
    return f32(kv[at]);
}

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let id = group_index(invocation);
    let t = invocation.lane;
    let a = attention_query(id);
    let live = a.live;
    let d = a.d;
    let q_row = (a.s * p.queries + a.i) * p.q_stride + p.q_offset + a.h * d;
    var acc: array<f32, MAX_HEAD_SIZE>;
    var best = -3.0e38;
    var total = 0.0;
    for (var j = t; j < a.keys; j += WORKGROUP) {
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
    best_of[t] = best;
    total_of[t] = total;
    for (var e = 0u; e < d; e++) {
        acc_of[t * ROW + e] = acc[e];
    }
    workgroupBarrier();
    // Thread e < d merges value e over the threads, in thread order.
    if !live || t >= d {
        return;
    }
    var top = -3.0e38;
    for (var k = 0u; k < WORKGROUP; k++) {
        top = max(top, best_of[k]);
    }
    var sum = 0.0;
    var weights = 0.0;
    for (var k = 0u; k < WORKGROUP; k++) {
        let rescale = exp(best_of[k] - top);
        sum += acc_of[k * ROW + t] * rescale;
        weights += total_of[k] * rescale;
    }
    out[(a.s * p.queries + a.i) * p.channels + a.h * d + t] = Elem(sum / weights);
}
