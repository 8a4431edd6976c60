// One query of the attention kernels (attention.wgsl's contract): which sequence, head
// and query an invocation or workgroup `id` serves, and how many keys it sees. Reads
// `p: AttentionParams`.
struct Query {
    // Its index in its sequence, its head and its sequence.
    i: u32,
    h: u32,
    s: u32,
    // The head size and 1/√d.
    d: u32,
    scale: f32,
    // The sequence whose keys it reads (`kv_share` sequences read the same).
    kv_sequence: u32,
    // The keys it sees: all, the first i + 1 + keys - queries when causal, those of its
    // run of rows when `rows` is set; 0 when it is not a query.
    keys: u32,
    // Whether `id` is a query: inside the grid and, with `rows`, before row p.rows.
    live: bool,
}

fn attention_query(id: u32) -> Query {
    let i = id % p.queries;
    let h = (id / p.queries) % p.heads;
    let s = id / (p.queries * p.heads);
    let d = p.channels / p.heads;
    var live = id < p.sequences * p.heads * p.queries;
    var keys = p.keys;
    if p.causal != 0u {
        keys = min(keys, i + 1u + p.keys - p.queries);
    }
    if p.rows != 0u {
        // Runs of `queries` rows that end at row p.rows: the last one is shorter.
        let first = s * p.queries;
        live = live && first + i < p.rows;
        keys = min(keys, p.rows - min(first, p.rows));
    }
    if !live {
        keys = 0u;
    }
    return Query(i, h, s, d, inverseSqrt(f32(d)), s / p.kv_share, keys, live);
}

// The first value of key j's row for query `a`, in `prefix` for the first prefix_keys
// keys and in `kv` after them.
fn key_row(a: Query, j: u32) -> u32 {
    if j < p.prefix_keys {
        return (a.kv_sequence * p.prefix_keys + j) * p.kv_stride + a.h * a.d;
    }
    let fresh = p.keys - p.prefix_keys;
    return (a.kv_sequence * fresh + j - p.prefix_keys) * p.kv_stride + a.h * a.d;
}
