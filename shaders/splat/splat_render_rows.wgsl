// Front-to-back blending as splat_render.wgsl computes it, for CPU drivers: one
// workgroup per 16×16 tile and one invocation per pixel row of it. Each row walks its
// tile's splats (sorted by depth) and blends each only over the pixels of the row where
// its alpha can reach the 1/255 cut: there opacity · e^power ≥ 1/255, a quadratic in x
// solved per row and widened by a pixel against rounding; every other pixel would skip
// it. Each pixel blends its splats in the same order and arithmetic as the per-pixel
// kernels and stops at the same transmittance cut; the row stops when all of its pixels
// have. No shared memory and no barriers: a CPU driver runs each barrier as a switch
// between the workgroup's invocations, and a splat a few pixels wide reaches a few of
// the tile's 256 pixels (docs/performance.md).

#bind f: uniform RasterView
#bind projected: read array<ProjectedSplat>
#bind values: read array<u32>
#bind ranges: read array<vec2<u32>>
#bind image: read_write array<vec4<f32>>

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
    let py = f32(y) + 0.5;
    var color: array<vec3<f32>, TILE>;
    var transmittance: array<f32, TILE>;
    for (var i = 0u; i < TILE; i++) {
        color[i] = vec3<f32>(0.0);
        transmittance[i] = 1.0;
    }
    var left = width;
    let range = ranges[tile];
    for (var k = range.x; k < range.y && left > 0u; k++) {
        let p = projected[values[k]];
        let opacity = p.conic_opacity.w;
        if !(opacity * 255.0 >= 1.0) {
            continue;
        }
        // power(dx) = -½ (a dx² + c dy²) - b dx dy with d = centre - pixel; alpha can
        // reach 1/255 where power ≥ -ln(255 · opacity).
        let a = p.conic_opacity.x;
        let b = p.conic_opacity.y;
        let c = p.conic_opacity.z;
        let dy = p.center_depth.y - py;
        let cut = log(255.0 * opacity);
        var first = 0u;
        var last = width;
        if a > 0.0 {
            let disc = b * b * dy * dy - a * (c * dy * dy - 2.0 * cut);
            if disc < 0.0 {
                continue;
            }
            let root = sqrt(disc);
            // dx = (-b dy ± root) / a, and the pixel centre x + 0.5 = centre.x - dx.
            let lo = p.center_depth.x - (-b * dy + root) / a - 0.5 - f32(x0) - 1.0;
            let hi = p.center_depth.x - (-b * dy - root) / a - 0.5 - f32(x0) + 1.0;
            if hi < 0.0 || lo >= f32(width) {
                continue;
            }
            first = u32(max(ceil(lo), 0.0));
            last = u32(min(floor(hi) + 1.0, f32(width)));
        }
        for (var i = first; i < last; i++) {
            let t = transmittance[i];
            if t == 0.0 {
                continue;
            }
            let d = p.center_depth.xy - vec2<f32>(f32(x0 + i) + 0.5, py);
            let power = -0.5 * (a * d.x * d.x + c * d.y * d.y) - b * d.x * d.y;
            if power > 0.0 {
                continue;
            }
            let alpha = min(opacity * exp(power), 0.99);
            if alpha < 1.0 / 255.0 {
                continue;
            }
            let next = t * (1.0 - alpha);
            if next < 1e-4 {
                // Done: the pixel keeps its colour and transmittance, marked by 0.
                image[y * f.width + x0 + i] = vec4<f32>(color[i] + f.background.xyz * t, 1.0 - t);
                transmittance[i] = 0.0;
                left -= 1u;
                continue;
            }
            color[i] += p.color.xyz * alpha * t;
            transmittance[i] = next;
        }
    }
    for (var i = 0u; i < width; i++) {
        let t = transmittance[i];
        if t > 0.0 {
            image[y * f.width + x0 + i] = vec4<f32>(color[i] + f.background.xyz * t, 1.0 - t);
        }
    }
}
