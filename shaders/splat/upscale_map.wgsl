// Foreground-aware upscaling of a position (or colour) map by an integer factor: at each
// output pixel, bilinear weights (half-pixel centres, edges clamped) of the mask-weighted
// values divided by the interpolated mask; pixels whose interpolated mask is at most 0.25
// are background (values and mask 0). One thread per output pixel.

#import gpu/for_each.wgsl

#bind p: uniform UpscaleParams
#bind map, mask: read array<f32>
#bind out_map, out_mask: read_write array<f32>

fn count() -> u32 { return (p.width * p.factor) * (p.height * p.factor); }

fn each(i: u32) {
    let w_out = p.width * p.factor;
    let h_out = p.height * p.factor;
    let ox = i % w_out;
    let oy = i / w_out;
    let sx = clamp((f32(ox) + 0.5) / f32(p.factor) - 0.5, 0.0, f32(p.width - 1u));
    let sy = clamp((f32(oy) + 0.5) / f32(p.factor) - 0.5, 0.0, f32(p.height - 1u));
    let x0 = u32(floor(sx));
    let y0 = u32(floor(sy));
    let x1 = min(x0 + 1u, p.width - 1u);
    let y1 = min(y0 + 1u, p.height - 1u);
    let fx = sx - f32(x0);
    let fy = sy - f32(y0);
    let corners = array<u32, 4>(y0 * p.width + x0, y0 * p.width + x1, y1 * p.width + x0, y1 * p.width + x1);
    let weights = array<f32, 4>((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
    var m = 0.0;
    var v = vec3<f32>(0.0);
    let plane = p.width * p.height;
    for (var k = 0u; k < 4u; k++) {
        let wm = weights[k] * mask[corners[k]];
        m += wm;
        v += wm * vec3<f32>(map[corners[k]], map[plane + corners[k]], map[2u * plane + corners[k]]);
    }
    let out_plane = w_out * h_out;
    if m > 0.25 {
        v /= m;
        out_mask[i] = 1.0;
    } else {
        v = vec3<f32>(0.0);
        out_mask[i] = 0.0;
    }
    out_map[i] = v.x;
    out_map[out_plane + i] = v.y;
    out_map[2u * out_plane + i] = v.z;
}
