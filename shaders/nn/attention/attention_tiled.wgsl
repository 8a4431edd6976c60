// Multi-head softmax attention for GPUs over long sequences: attention.wgsl's inputs and
// result, with one workgroup per (sequence, head, block of WORKGROUP queries), a thread
// per query. The workgroup walks the keys in chunks of CHUNK: its threads load the
// chunk's keys and values into workgroup memory once, then every thread scores its query
// against all of them, rescales its running values once to the chunk's largest score
// and adds the chunk's weighted values. attention_split.wgsl's workgroup per query
// loaded every key once per query: 134 µs a refiner attention on an H200 (docs/gpu).
// Heads of at most TILE_HEAD values (a multiple of 4; the host checks), held as vec4s
// padded with zeros, so the loops over a head have constant bounds and stay in
// registers. Row layout, `kv_share`, `causal`, `prefix_keys` and `rows` as
// attention_split.wgsl.

#bind p: uniform AttentionParams
#bind q, prefix, kv: read array<Elem>
#bind out: read_write array<Elem>

const QUADS: u32 = TILE_HEAD / 4u;
const CHUNK: u32 = 32u;
// The chunk's keys and values, QUADS vec4s a key (zeros past the head size).
var<workgroup> keys_of: array<vec4<f32>, CHUNK * QUADS>;
var<workgroup> values_of: array<vec4<f32>, CHUNK * QUADS>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let t = invocation.lane;
    let blocks = (p.queries + WORKGROUP - 1u) / WORKGROUP;
    let id = group_index(invocation);
    // The few workgroups past the end load and store nothing.
    if id >= p.sequences * p.heads * blocks {
        return;
    }
    let block = id % blocks;
    let h = (id / blocks) % p.heads;
    let s = id / (blocks * p.heads);
    let i = block * WORKGROUP + t;
    let d = p.channels / p.heads;
    let scale = inverseSqrt(f32(d));
    let kv_sequence = s / p.kv_share;
    var keys = p.keys;
    var live = i < p.queries;
    if p.rows != 0u {
        // Runs of `queries` rows that end at row p.rows: the last one is shorter.
        let first = s * p.queries;
        live = live && first + i < p.rows;
        keys = min(keys, p.rows - min(first, p.rows));
    }
    // The keys this query sees.
    var seen = keys;
    if p.causal != 0u {
        seen = min(keys, i + 1u + p.keys - p.queries);
    }
    if !live {
        seen = 0u;
    }
    let q_row = (s * p.queries + min(i, p.queries - 1u)) * p.q_stride + p.q_offset + h * d;
    var query: array<vec4<f32>, QUADS>;
    for (var k = 0u; k < QUADS; k++) {
        var v = vec4<f32>(0.0);
        for (var c = 0u; c < 4u; c++) {
            let e = 4u * k + c;
            if live && e < d {
                v[c] = f32(q[q_row + e]) * scale;
            }
        }
        query[k] = v;
    }
    var acc: array<vec4<f32>, QUADS>;
    var best = -3.0e38;
    var total = 0.0;
    let fresh = p.keys - p.prefix_keys;
    for (var first = 0u; first < keys; first += CHUNK) {
        // Load the chunk: value slot u of CHUNK × QUADS × 4, as key, quad, lane.
        for (var u = t; u < CHUNK * TILE_HEAD; u += WORKGROUP) {
            let j = first + u / TILE_HEAD;
            let e = u % TILE_HEAD;
            var k_value = 0.0;
            var v_value = 0.0;
            if j < keys && e < d {
                if j < p.prefix_keys {
                    let row = (kv_sequence * p.prefix_keys + j) * p.kv_stride + h * d + e;
                    k_value = f32(prefix[row + p.k_offset]);
                    v_value = f32(prefix[row + p.v_offset]);
                } else {
                    let row = (kv_sequence * fresh + j - p.prefix_keys) * p.kv_stride + h * d + e;
                    k_value = f32(kv[row + p.k_offset]);
                    v_value = f32(kv[row + p.v_offset]);
                }
            }
            keys_of[u / 4u][u % 4u] = k_value;
            values_of[u / 4u][u % 4u] = v_value;
        }
        workgroupBarrier();
        let count = min(CHUNK, keys - first);
        let visible = min(count, seen - min(seen, first));
        var score: array<f32, CHUNK>;
        var top = best;
        for (var j = 0u; j < CHUNK; j++) {
            var dot_sum = 0.0;
            for (var k = 0u; k < QUADS; k++) {
                dot_sum += dot(query[k], keys_of[j * QUADS + k]);
            }
            score[j] = dot_sum;
            if j < visible {
                top = max(top, dot_sum);
            }
        }
        let rescale = exp(best - top);
        total *= rescale;
        for (var k = 0u; k < QUADS; k++) {
            acc[k] *= rescale;
        }
        for (var j = 0u; j < CHUNK; j++) {
            let weight = select(0.0, exp(score[j] - top), j < visible);
            total += weight;
            for (var k = 0u; k < QUADS; k++) {
                acc[k] += weight * values_of[j * QUADS + k];
            }
        }
        best = top;
        workgroupBarrier();
    }
    if !live {
        return;
    }
    let o = (s * p.queries + i) * p.channels + h * d;
    for (var k = 0u; k < QUADS; k++) {
        for (var c = 0u; c < 4u; c++) {
            let e = 4u * k + c;
            if e < d {
                out[o + e] = Elem(acc[k][c] / total);
            }
        }
    }
}
