// Front-to-back blending as splat_render.wgsl computes it, for CPU drivers: one
// workgroup per 16×16 tile and one invocation per pixel row of it. Each row walks its
// tile's splats (sorted by depth) and blends each only over the pixels of the row where
// its alpha can reach the 1/255 cut: there opacity · e^power ≥ 1/255, a quadratic in x
// solved per row and widened by a pixel against rounding; every other pixel would skip
// it. Each pixel blends its splats in the same order and arithmetic as the per-pixel
// kernel and stops at the same transmittance cut; the row stops when all of its pixels
// have. No shared memory and no barriers: a CPU driver runs each barrier as a switch
// between the workgroup's invocations, and a splat a few pixels wide reaches a few of
// the tile's 256 pixels (docs/performance.md).
//
// Lavapipe (llvmpipe) ends every loop of an invocation once all of its loops together
// have run 65,535 iterations (LP_MAX_TGSI_LOOP_ITERATIONS, one counter for every loop of
// a shader), silently. So the walk over the tile's splats, one iteration a sort entry,
// is only used for up to raster.rs's ROW_BLEND_MAX_SPLATS splats (a splat enters a tile
// once), and a loop over each splat's pixels only in tiles of up to LOOP_ENTRIES entries,
// where the limit cannot be reached (such a loop everywhere left whole rows unwritten on
// the Witch's level-1024 splats); fuller tiles write the row's 16 pixels out as 16
// calls. Lavapipe runs the calls whole for every lane, with masks, and a loop only while
// one of its lanes is still in it: the loop drew the Witch's level-256 window 20-25 %
// faster (docs/performance.md), with the same pixels.

#bind f: uniform RasterView
// The projected splats (4 texels each) and the sorted splat indices (4 a texel) as
// texels (src/gpu/texels.rs): a vector gather on lavapipe, where a storage load is a
// loop over the lanes for every value.
#bind projected: texture_2d<f32>
#bind values: texture_2d<u32>
#bind ranges: read array<vec2<u32>>
#bind image: read_write array<vec4<f32>>

#import splat/splat_alpha.wgsl

struct Row {
    color: array<vec3<f32>, TILE>,
    transmittance: array<f32, TILE>,
    // Bit i: pixel i has stopped (its transmittance would fall below 1e-4).
    stopped: u32,
}

// The projected splat of sort entry k.
fn entry(k: u32) -> ProjectedSplat {
    let s = texel_u32(values, k / 4u)[k % 4u];
    let t = 4u * s;
    return ProjectedSplat(
        texel(projected, t),
        texel(projected, t + 1u),
        texel(projected, t + 2u),
        bitcast<vec4<u32>>(texel(projected, t + 3u)),
    );
}

// Splat `p` over pixel `i` of the row at height `py`, if `i` lies in [first, last).
fn blend(row: ptr<function, Row>, i: u32, first: u32, last: u32, p: ProjectedSplat, px: f32, py: f32) {
    if i < first || i >= last || ((*row).stopped & (1u << i)) != 0u {
        return;
    }
    let alpha = splat_alpha(p, p.center_depth.xy - vec2<f32>(px + f32(i), py));
    if alpha == 0.0 {
        return;
    }
    let t = (*row).transmittance[i];
    let next = t * (1.0 - alpha);
    if next < 1e-4 {
        (*row).stopped |= 1u << i;
        return;
    }
    (*row).color[i] += p.color.xyz * alpha * t;
    (*row).transmittance[i] = next;
}

// The pixels [x, y) of the row at height `py` (starting at `px`, `width` wide) where
// splat `p`'s alpha can reach the 1/255 cut: opacity · e^power ≥ 1/255, with power(dx) =
// -½ (a dx² + c dy²) - b dx dy and d = centre - pixel, a quadratic in dx solved for the
// row and widened by a pixel against rounding. (0, 0) where it reaches none.
fn reach(p: ProjectedSplat, px: f32, py: f32, width: u32) -> vec2<u32> {
    let opacity = p.conic_opacity.w;
    if !(opacity * 255.0 >= 1.0) {
        return vec2<u32>(0u);
    }
    let a = p.conic_opacity.x;
    let b = p.conic_opacity.y;
    let c = p.conic_opacity.z;
    if !(a > 0.0) {
        return vec2<u32>(0u, width);
    }
    let dy = p.center_depth.y - py;
    let cut = log(255.0 * opacity);
    let disc = b * b * dy * dy - a * (c * dy * dy - 2.0 * cut);
    if disc < 0.0 {
        return vec2<u32>(0u);
    }
    let root = sqrt(disc);
    // dx = (-b dy ± root) / a, and the pixel centre x + 0.5 = centre.x - dx.
    let lo = p.center_depth.x - (-b * dy + root) / a - px - 1.0;
    let hi = p.center_depth.x - (-b * dy - root) / a - px + 1.0;
    if hi < 0.0 || lo >= f32(width) {
        return vec2<u32>(0u);
    }
    return vec2<u32>(u32(max(ceil(lo), 0.0)), u32(min(floor(hi) + 1.0, f32(width))));
}

// Tiles of up to this many sort entries take the loop over each splat's pixels: each
// entry costs lavapipe's loop limiter at most 1 + 17 iterations (the walk, then up to 16
// pixels and the exit), 3,600 × 18 + 32 < 65,535.
const LOOP_ENTRIES: u32 = 3600u;

@compute @workgroup_size(TILE)
fn main(invocation: Invocation) {
    let tile = group_index(invocation);
    if tile >= f.tiles_x * f.tiles_y {
        return;
    }
    let x0 = (tile % f.tiles_x) * TILE;
    let y = (tile / f.tiles_x) * TILE + invocation.lane;
    if y >= f.height {
        return;
    }
    let width = min(TILE, f.width - x0);
    let everyone = (1u << width) - 1u;
    let py = f32(y) + 0.5;
    let px = f32(x0) + 0.5;
    var row: Row;
    for (var i = 0u; i < TILE; i++) {
        row.color[i] = vec3<f32>(0.0);
        row.transmittance[i] = 1.0;
    }
    row.stopped = 0u;
    let range = ranges[tile];
    // The walk is written twice, not once with the choice inside it: lavapipe would run
    // both sides of that choice for every entry, the 16 calls too.
    if range.y - range.x <= LOOP_ENTRIES {
        // A loop over the pixels the splat reaches: lavapipe runs a loop only while one
        // of the vector's lanes is still in it, where it runs the 16 calls below whole.
        for (var k = range.x; k < range.y && row.stopped != everyone; k++) {
            let p = entry(k);
            let reached = reach(p, px, py, width);
            for (var i = reached.x; i < reached.y; i++) {
                blend(&row, i, reached.x, reached.y, p, px, py);
            }
        }
    } else {
        for (var k = range.x; k < range.y && row.stopped != everyone; k++) {
            let p = entry(k);
            let reached = reach(p, px, py, width);
            let first = reached.x;
            let last = reached.y;
            blend(&row, 0u, first, last, p, px, py);
            blend(&row, 1u, first, last, p, px, py);
            blend(&row, 2u, first, last, p, px, py);
            blend(&row, 3u, first, last, p, px, py);
            blend(&row, 4u, first, last, p, px, py);
            blend(&row, 5u, first, last, p, px, py);
            blend(&row, 6u, first, last, p, px, py);
            blend(&row, 7u, first, last, p, px, py);
            blend(&row, 8u, first, last, p, px, py);
            blend(&row, 9u, first, last, p, px, py);
            blend(&row, 10u, first, last, p, px, py);
            blend(&row, 11u, first, last, p, px, py);
            blend(&row, 12u, first, last, p, px, py);
            blend(&row, 13u, first, last, p, px, py);
            blend(&row, 14u, first, last, p, px, py);
            blend(&row, 15u, first, last, p, px, py);
        }
    }
    for (var i = 0u; i < width; i++) {
        let t = row.transmittance[i];
        image[y * f.width + x0 + i] = vec4<f32>(row.color[i] + f.background.xyz * t, 1.0 - t);
    }
}
