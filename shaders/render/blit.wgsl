// A render target's image shown over the current viewport of a render pass (the 3D
// viewport's rectangle in the window's egui pass): a triangle covering the viewport whose
// fragments interpolate `image` bilinearly, without blending. egui's image
// shader (bilinear sampling, dithering, blending) cost a CPU driver about 57 ms a window
// frame for a 990 × 775 viewport; the numbers are in docs/performance.md.

#bind image: texture_2d<f32>

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    // Image coordinates in [0, 1] over the viewport, y down.
    @location(0) uv: vec2<f32>,
}

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> VertexOut {
    let xy = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    var out: VertexOut;
    out.clip = vec4<f32>(xy * 2.0 - 1.0, 0.0, 1.0);
    out.uv = vec2<f32>(xy.x, 1.0 - xy.y);
    return out;
}

// Bilinear between the four nearest texel centres, clamped at the edges: what a linear
// sampler returns (the view decodes sRGB first), from four loads.
@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let last = textureDimensions(image) - 1u;
    let p = max(in.uv * vec2<f32>(last + 1u) - 0.5, vec2<f32>(0.0));
    let f = fract(p);
    let lo = min(vec2<u32>(p), last);
    let hi = min(lo + 1u, last);
    let top = mix(textureLoad(image, lo, 0), textureLoad(image, vec2<u32>(hi.x, lo.y), 0), f.x);
    let bottom = mix(textureLoad(image, vec2<u32>(lo.x, hi.y), 0), textureLoad(image, hi, 0), f.x);
    return mix(top, bottom, f.y);
}
