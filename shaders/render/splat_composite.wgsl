// Lays the rasterized splats (premultiplied linear RGB + coverage, drawn over black) over
// the rendered scene: a full-screen triangle whose fragments read the splat image; the
// pipeline blends with (One, OneMinusSrcAlpha). The image may be smaller than the target
// by `divisor` (a quick raster while the camera moves).

#bind c: uniform CompositeParams
#bind image: read array<vec4<f32>>

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(xy * 2.0 - 1.0, 0.0, 1.0);
}

@fragment
fn fs_main(@builtin(position) position: vec4<f32>) -> @location(0) vec4<f32> {
    let x = min(u32(position.x) / c.divisor, c.width - 1u);
    let y = min(u32(position.y) / c.divisor, c.height - 1u);
    return image[y * c.width + x];
}
