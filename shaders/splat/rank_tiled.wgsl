// The serialisation ranks for GPUs: a point's rank is the number of points with a smaller
// code plus those with the same code and a smaller index (a stable sort); sort[rank] = i,
// unsort[i] = rank, and with `groups` set each point's pooled group rank / stride. The
// codes are read from their storage buffer a tile at a time into workgroup memory (each
// thread loads one vec4 of the tile, then every thread counts against the whole tile):
// every thread fetching every code as a texel took 168 µs a curve on an H200 (docs/gpu).

#bind p: uniform SplatParams
#bind codes: read array<vec4<u32>>
#bind sort, unsort, groups_out: read_write array<u32>

var<workgroup> tile: array<vec4<u32>, WORKGROUP>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    let t = invocation.lane;
    // Threads past the end load their share of the tiles and store nothing.
    let live = i < p.points;
    // The curve's codes as vec4s (codes.wgsl pads each curve to a multiple of 4 with the
    // largest u32, which no code reaches, so padding never counts).
    let quads = (p.points + 3u) / 4u;
    let base = p.curve * quads;
    let own = min(i, p.points - 1u);
    let cv = vec4<u32>(codes[base + own / 4u][own % 4u]);
    let iv = vec4<u32>(own);
    var counts = vec4<u32>(0u);
    for (var first = 0u; first < quads; first += WORKGROUP) {
        let q = first + t;
        tile[t] = select(vec4<u32>(0xffffffffu), codes[base + min(q, quads - 1u)], q < quads);
        workgroupBarrier();
        let n = min(WORKGROUP, quads - first);
        for (var k = 0u; k < n; k++) {
            let d = tile[k];
            let j = vec4<u32>(4u * (first + k)) + vec4<u32>(0u, 1u, 2u, 3u);
            let before = (d < cv) | ((d == cv) & (j < iv));
            counts += select(vec4<u32>(0u), vec4<u32>(1u), before);
        }
        workgroupBarrier();
    }
    if !live {
        return;
    }
    let rank = counts.x + counts.y + counts.z + counts.w;
    sort[rank] = i;
    unsort[i] = rank;
    if p.features != 0u {
        groups_out[i] = rank / p.stride;
    }
}
