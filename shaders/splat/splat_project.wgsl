// Splat projection (mirrors src/splat/project.rs): per Gaussian the camera-space mean,
// Σ' = J W Σ Wᵀ Jᵀ + 0.3 I, the conic, a 3σ radius padded like 3DGS, the covered tiles,
// and how many tiles it touches (0 when culled).

#import gpu/for_each.wgsl

#bind f: uniform RasterView
#bind splats: read array<GpuSplat>
#bind projected: read_write array<ProjectedSplat>
#bind touched: read_write array<u32>

fn rotation(q: vec4<f32>) -> mat3x3<f32> {
    let n = normalize(q);
    let x = n.x; let y = n.y; let z = n.z; let w = n.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn count() -> u32 { return f.splats; }

fn each(i: u32) {
    touched[i] = 0u;
    let s = splats[i];
    let t = (f.view * vec4<f32>(s.position_opacity.xyz, 1.0)).xyz;
    let z = -t.z;
    if z < f.near {
        return;
    }
    let center = vec2<f32>(0.5 * f32(f.width) + f.fx * t.x / z, 0.5 * f32(f.height) - f.fy * t.y / z);
    let j0 = vec3<f32>(f.fx / z, 0.0, f.fx * t.x / (z * z));
    let j1 = vec3<f32>(0.0, -f.fy / z, -f.fy * t.y / (z * z));
    let w = mat3x3<f32>(f.view[0].xyz, f.view[1].xyz, f.view[2].xyz);
    let m = rotation(s.rotation) * mat3x3<f32>(
        vec3<f32>(s.scale.x, 0.0, 0.0), vec3<f32>(0.0, s.scale.y, 0.0), vec3<f32>(0.0, 0.0, s.scale.z));
    let sigma = w * (m * transpose(m)) * transpose(w);
    let sj0 = sigma * j0;
    let sj1 = sigma * j1;
    let a = dot(j0, sj0) + 0.3;
    let b = dot(j0, sj1);
    let c = dot(j1, sj1) + 0.3;
    let det = a * c - b * b;
    if det <= 0.0 {
        return;
    }
    let mid = 0.5 * (a + c);
    let largest = mid + sqrt(max(mid * mid - det, 0.1));
    let radius = ceil(3.0 * sqrt(largest));
    let tile = 16.0;
    let x0 = u32(clamp(floor((center.x - radius) / tile), 0.0, f32(f.tiles_x)));
    let x1 = u32(clamp(ceil((center.x + radius) / tile), 0.0, f32(f.tiles_x)));
    let y0 = u32(clamp(floor((center.y - radius) / tile), 0.0, f32(f.tiles_y)));
    let y1 = u32(clamp(ceil((center.y + radius) / tile), 0.0, f32(f.tiles_y)));
    if x0 >= x1 || y0 >= y1 {
        return;
    }
    let color = max(vec3<f32>(0.5) + 0.2820948 * s.f_dc.xyz, vec3<f32>(0.0));
    projected[i] = ProjectedSplat(
        vec4<f32>(center, z, radius),
        vec4<f32>(vec3<f32>(c, -b, a) / det, s.position_opacity.w),
        vec4<f32>(color, 0.0),
        vec4<u32>(x0, y0, x1, y1),
    );
    touched[i] = (x1 - x0) * (y1 - y0);
}
