// The alpha splat `p` adds at a pixel `d` = centre − pixel away, as project.rs's `alpha`
// computes it: min(0.99, opacity · e^power), 0 where power > 0 or below the 1/255 cut.
// Shared by the blends (splat_render.wgsl, splat_render_rows.wgsl).
fn splat_alpha(p: ProjectedSplat, d: vec2<f32>) -> f32 {
    let power = -0.5 * (p.conic_opacity.x * d.x * d.x + p.conic_opacity.z * d.y * d.y) - p.conic_opacity.y * d.x * d.y;
    if power > 0.0 {
        return 0.0;
    }
    let alpha = min(p.conic_opacity.w * exp(power), 0.99);
    if alpha < 1.0 / 255.0 {
        return 0.0;
    }
    return alpha;
}
