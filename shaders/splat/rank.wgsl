// One serialisation order from curve `curve`'s codes, by counting: a point's rank is the
// number of points with a smaller code plus those with the same code and a smaller index
// (a stable sort). sort[rank] = i, unsort[i] = rank, and with `groups` set, each point's
// pooled group rank / stride.

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> codes: array<u32>;
@group(0) @binding(2) var<storage, read_write> sort: array<u32>;
@group(0) @binding(3) var<storage, read_write> unsort: array<u32>;
@group(0) @binding(4) var<storage, read_write> groups_out: array<u32>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    if i >= p.points {
        return;
    }
    let base = p.curve * p.points;
    let c = codes[base + i];
    var rank = 0u;
    for (var j = 0u; j < p.points; j++) {
        let d = codes[base + j];
        rank += select(0u, 1u, d < c || (d == c && j < i));
    }
    sort[rank] = i;
    unsort[i] = rank;
    if p.features != 0u {
        groups_out[i] = rank / p.stride;
    }
}
