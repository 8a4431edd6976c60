// Multi-head softmax attention over independent sequences, f32. Queries are read from
// rows of `q` (row stride q_stride, head h at q_offset + h·d), keys and values from rows of
// `kv` (k_offset, v_offset), so packed qkv projections need no splitting. One thread per
// (sequence, head, query): two passes for the softmax, then the weighted sum of values.
// With `causal` set, query i sees keys j <= i.

@group(0) @binding(0) var<uniform> p: AttentionParams;
@group(0) @binding(1) var<storage, read> q: array<f32>;
@group(0) @binding(2) var<storage, read> kv: array<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let id = (group.x + group.y * groups.x) * 64u + lane;
    if id >= p.sequences * p.heads * p.queries {
        return;
    }
    let i = id % p.queries;
    let h = (id / p.queries) % p.heads;
    let s = id / (p.queries * p.heads);
    let d = p.channels / p.heads;
    let scale = inverseSqrt(f32(d));
    let q_row = (s * p.queries + i) * p.q_stride + p.q_offset + h * d;
    var keys = p.keys;
    if p.causal != 0u {
        keys = min(keys, i + 1u);
    }
    var best = -3.0e38;
    for (var j = 0u; j < keys; j++) {
        let k_row = (s * p.keys + j) * p.kv_stride + p.k_offset + h * d;
        var dot = 0.0;
        for (var e = 0u; e < d; e++) {
            dot += q[q_row + e] * kv[k_row + e];
        }
        best = max(best, dot * scale);
    }
    var total = 0.0;
    for (var j = 0u; j < keys; j++) {
        let k_row = (s * p.keys + j) * p.kv_stride + p.k_offset + h * d;
        var dot = 0.0;
        for (var e = 0u; e < d; e++) {
            dot += q[q_row + e] * kv[k_row + e];
        }
        total += exp(dot * scale - best);
    }
    let o_row = (s * p.queries + i) * p.channels + h * d;
    for (var e = 0u; e < d; e++) {
        out[o_row + e] = 0.0;
    }
    for (var j = 0u; j < keys; j++) {
        let k_row = (s * p.keys + j) * p.kv_stride + p.k_offset + h * d;
        let v_row = (s * p.keys + j) * p.kv_stride + p.v_offset + h * d;
        var dot = 0.0;
        for (var e = 0u; e < d; e++) {
            dot += q[q_row + e] * kv[k_row + e];
        }
        let weight = exp(dot * scale - best) / total;
        for (var e = 0u; e < d; e++) {
            out[o_row + e] += weight * kv[v_row + e];
        }
    }
}
