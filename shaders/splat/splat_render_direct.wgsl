// Front-to-back blending as splat_render.wgsl computes it, for CPU drivers: one
// workgroup per 16×16 tile and one invocation per pixel, but each pixel reads its tile's
// splats (sorted by depth) straight from `projected` and stops at its own
// transmittance cut. No shared memory and no barriers: a CPU driver runs each barrier
// as a switch between the workgroup's invocations (docs/performance.md: on lavapipe
// this blend takes a third of the shared-memory one's time).

#bind f: uniform RasterView
#bind projected: read array<ProjectedSplat>
#bind values: read array<u32>
#bind ranges: read array<vec2<u32>>
#bind image: read_write array<vec4<f32>>

@compute @workgroup_size(16, 16)
fn main(invocation: Invocation) {
    let tile = group_index(invocation);
    let lane = invocation.lane;
    if tile >= f.tiles_x * f.tiles_y {
        return;
    }
    let x = (tile % f.tiles_x) * TILE + lane % TILE;
    let y = (tile / f.tiles_x) * TILE + lane / TILE;
    if x >= f.width || y >= f.height {
        return;
    }
    let pixel = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
    let range = ranges[tile];
    var color = vec3<f32>(0.0);
    var transmittance = 1.0;
    for (var k = range.x; k < range.y; k++) {
        let p = projected[values[k]];
        let d = p.center_depth.xy - pixel;
        let power = -0.5 * (p.conic_opacity.x * d.x * d.x + p.conic_opacity.z * d.y * d.y) - p.conic_opacity.y * d.x * d.y;
        if power > 0.0 {
            continue;
        }
        let alpha = min(p.conic_opacity.w * exp(power), 0.99);
        if alpha < 1.0 / 255.0 {
            continue;
        }
        let next = transmittance * (1.0 - alpha);
        if next < 1e-4 {
            break;
        }
        color += p.color.xyz * alpha * transmittance;
        transmittance = next;
    }
    image[y * f.width + x] = vec4<f32>(color + f.background.xyz * transmittance, 1.0 - transmittance);
}
