// The drawn splats: base splats plus, with `residuals` set, the refiner's residuals (14
// per splat: mean offset tanh-bounded by `bound`, colour, log-scale, rotation, opacity
// logit), as base.rs's refine; then the in-surface scales times `widen` (base.rs's
// widen_splats); written where the rasterizer reads them.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind base: read array<GpuSplat>
#bind residuals: read array<f32>
#bind splats: read_write array<GpuSplat>

fn bounded(x: f32) -> f32 {
    // tanh of a clamped argument: exact to f32 (tanh(±15) rounds to ±1), never NaN.
    return tanh(clamp(x, -15.0, 15.0));
}

fn count() -> u32 { return p.points; }

fn each(i: u32) {
    var s = base[i];
    if p.residuals != 0u {
        let o = 14u * i;
        let offset = vec3<f32>(bounded(residuals[o]), bounded(residuals[o + 1u]), bounded(residuals[o + 2u])) * p.bound;
        let color = vec3<f32>(0.5) + SH_C0 * s.f_dc.xyz
            + vec3<f32>(residuals[o + 3u], residuals[o + 4u], residuals[o + 5u]);
        let scale = s.scale.xyz * exp(vec3<f32>(residuals[o + 6u], residuals[o + 7u], residuals[o + 8u]));
        let q = s.rotation + vec4<f32>(residuals[o + 9u], residuals[o + 10u], residuals[o + 11u], residuals[o + 12u]);
        let l = sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
        let logit = log(OPACITY / (1.0 - OPACITY));
        s.position_opacity = vec4<f32>(s.position_opacity.xyz + offset, 1.0 / (1.0 + exp(-(logit + residuals[o + 13u]))));
        s.f_dc = vec4<f32>((color - vec3<f32>(0.5)) / SH_C0, 0.0);
        s.scale = vec4<f32>(scale, 0.0);
        s.rotation = q * (1.0 / l);
    }
    s.scale = vec4<f32>(s.scale.xy * p.widen, s.scale.z, 0.0);
    splats[i] = s;
}
