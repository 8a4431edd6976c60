// One serialisation order from curve `curve`'s codes, by counting: a point's rank is the
// number of points with a smaller code plus those with the same code and a smaller index
// (a stable sort). sort[rank] = i, unsort[i] = rank, and with `groups` set, each point's
// pooled group rank / stride. The codes are read as texels (src/gpu/texels.rs): every
// invocation reads them all, and lavapipe fetches a texel as one vector gather where a
// storage load is a loop over lanes.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind codes: texture_2d<u32>
#bind sort, unsort, groups_out: read_write array<u32>

fn count() -> u32 { return p.points; }

fn each(i: u32) {
    // The curve's codes as vec4s (codes.wgsl pads each curve to a multiple of 4 with the
    // largest u32, which no code reaches, so padding never counts).
    let quads = (p.points + 3u) / 4u;
    let base = p.curve * quads;
    let c = texel_u32(codes, base + i / 4u)[i % 4u];
    let cv = vec4<u32>(c);
    let iv = vec4<u32>(i);
    var counts = vec4<u32>(0u);
    for (var q = 0u; q < quads; q++) {
        let d = texel_u32(codes, base + q);
        let j = vec4<u32>(4u * q) + vec4<u32>(0u, 1u, 2u, 3u);
        let before = (d < cv) | ((d == cv) & (j < iv));
        counts += select(vec4<u32>(0u), vec4<u32>(1u), before);
    }
    let rank = counts.x + counts.y + counts.z + counts.w;
    sort[rank] = i;
    unsort[i] = rank;
    if p.features != 0u {
        groups_out[i] = rank / p.stride;
    }
}
