// A temporal attention layer's projection and attention for one new frame, for GPUs:
// what linear_split.wgsl then attention_split.wgsl give (the separate ops the other
// variants record), bit for bit, in one dispatch. One workgroup per (sequence, head):
// its threads project the head's q, k and v from the sequence's token row, each output
// summed as linear_split.wgsl sums it (WORKGROUP partial sums over the inputs t, t +
// WORKGROUP, …, added in order, then the bias) and rounded to Elem as the stored qkv
// would be; then thread e < d attends for value e over the cached rows of the earlier
// frames (`prefix`, rows of q | k | v as the context pass kept them) and the sequence's
// own key, merging the keys as attention_split.wgsl merges its threads' (each key alone
// on one thread there). The parameters are the separate attention's (queries = 1,
// prefix_keys cached keys, at most WORKGROUP keys; host-checked).

#bind p: uniform AttentionParams
// [sequences, channels] token rows.
#bind x: read array<Elem>
// The qkv projection's weight [3 · channels, channels] and bias.
#bind weight, bias: read array<Elem>
// [sequences, prefix_keys, 3 · channels]: the cached rows.
#bind prefix: read array<Elem>
#bind out: read_write array<Elem>

// The head's projected q, k and v (value e of each at e, d + e, 2d + e), as stored.
var<workgroup> qkv: array<f32, 3u * MAX_HEAD_SIZE>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let id = group_index(invocation);
    let t = invocation.lane;
    let live = id < p.sequences * p.heads;
    let h = id % p.heads;
    let s = id / p.heads;
    let c = p.channels;
    let d = c / p.heads;
    // The projection: output j of the head is row (j / d) · c + h · d + j % d.
    let outputs = select(0u, 3u * d, live);
    for (var j = t; j < outputs; j += WORKGROUP) {
        let o = (j / d) * c + h * d + j % d;
        var sum = 0.0;
        for (var k = 0u; k < WORKGROUP; k++) {
            var part = 0.0;
            for (var i = k; i < c; i += WORKGROUP) {
                part += f32(x[s * c + i]) * f32(weight[o * c + i]);
            }
            sum += part;
        }
        qkv[j] = f32(Elem(f32(bias[o]) + sum));
    }
    workgroupBarrier();
    if !live || t >= d {
        return;
    }
    let e = t;
    let scale = inverseSqrt(f32(d));
    let keys = p.prefix_keys + 1u;
    // Key j's score: q · k_j in order, times the scale.
    var top = -3.0e38;
    for (var j = 0u; j < keys; j++) {
        top = max(top, score(s, h, d, j) * scale);
    }
    var sum = 0.0;
    var weights = 0.0;
    for (var j = 0u; j < keys; j++) {
        let rescale = exp(score(s, h, d, j) * scale - top);
        var v = qkv[2u * d + e];
        if j < p.prefix_keys {
            v = f32(prefix[(s * p.prefix_keys + j) * p.kv_stride + h * d + p.v_offset + e]);
        }
        sum += v * rescale;
        weights += rescale;
    }
    out[s * c + h * d + e] = Elem(sum / weights);
}

// q · k_j of sequence s, head h: from the cache for j < prefix_keys, else the fresh key.
fn score(s: u32, h: u32, d: u32, j: u32) -> f32 {
    var dot = 0.0;
    for (var e = 0u; e < d; e++) {
        var k = qkv[d + e];
        if j < p.prefix_keys {
            k = f32(prefix[(s * p.prefix_keys + j) * p.kv_stride + h * d + p.k_offset + e]);
        }
        dot += qkv[e] * k;
    }
    return dot;
}
