// Base splats (docs/architecture.md, Appearance; as src/splat/base.rs): per point,
// tangents from central differences over its right/left and lower/upper neighbours within
// 3× the median spacing (frame[3]), the local frame (x along the column tangent, z the
// normal), σ from the footprints, the bundle's colour; with `features`, the refiner's 11
// inputs too.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind points: read array<f32>
#bind neighbours: read array<vec4<i32>>
#bind colors, frame, unit: read array<f32>
#bind splats: read_write array<GpuSplat>
#bind features: read_write array<Elem>

fn point(i: u32) -> vec3<f32> {
    return vec3<f32>(points[3u * i], points[3u * i + 1u], points[3u * i + 2u]);
}

fn len(v: vec3<f32>) -> f32 {
    return sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
}

fn perpendicular(t: vec3<f32>) -> vec3<f32> {
    let unit = t / max(len(t), 1e-30);
    var helper = vec3<f32>(0.0, 1.0, 0.0);
    if abs(unit.y) > 0.9 {
        helper = vec3<f32>(1.0, 0.0, 0.0);
    }
    let q = cross(helper, unit);
    return q / max(len(q), 1e-30);
}

// The mean of the differences to the forward and (negated) backward neighbours within
// `limit`; w is the count (0: none).
fn axis(c: vec3<f32>, forward: i32, backward: i32, limit: f32) -> vec4<f32> {
    var total = vec3<f32>(0.0);
    var count = 0.0;
    if forward >= 0 {
        let d = point(u32(forward)) - c;
        if len(d) <= limit {
            total += d;
            count += 1.0;
        }
    }
    if backward >= 0 {
        let d = point(u32(backward)) - c;
        if len(d) <= limit {
            total += -d;
            count += 1.0;
        }
    }
    if count > 0.0 {
        return vec4<f32>(total / count, count);
    }
    return vec4<f32>(0.0);
}

// Shepperd's method, as base.rs's quat_from_frame (w ≥ 0, then normalised).
fn quat_from_frame(x: vec3<f32>, y: vec3<f32>, z: vec3<f32>) -> vec4<f32> {
    let m00 = x.x;
    let m11 = y.y;
    let m22 = z.z;
    let a = y.z - z.y;
    let b = z.x - x.z;
    let c = x.y - y.x;
    let xy = y.x + x.y;
    let xz = z.x + x.z;
    let yz = z.y + y.z;
    let trace = m00 + m11 + m22;
    var q: vec4<f32>;
    if trace > 0.0 {
        let s = sqrt(max(trace + 1.0, 1e-12)) * 2.0;
        q = vec4<f32>(a / s, b / s, c / s, s / 4.0);
    } else if m00 > m11 && m00 > m22 {
        let s = sqrt(max(1.0 + m00 - m11 - m22, 1e-12)) * 2.0;
        q = vec4<f32>(s / 4.0, xy / s, xz / s, a / s);
    } else if m11 > m22 {
        let s = sqrt(max(1.0 + m11 - m00 - m22, 1e-12)) * 2.0;
        q = vec4<f32>(xy / s, s / 4.0, yz / s, b / s);
    } else {
        let s = sqrt(max(1.0 + m22 - m00 - m11, 1e-12)) * 2.0;
        q = vec4<f32>(xz / s, yz / s, s / 4.0, c / s);
    }
    if q.w < 0.0 {
        q = -q;
    }
    let l = sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
    return q * (1.0 / l);
}

fn count() -> u32 { return p.points; }

fn each(i: u32) {
    let median = frame[3];
    let limit = 3.0 * median;
    let c = point(i);
    let n = neighbours[i];
    let au = axis(c, n.x, n.y, limit);
    let av = axis(c, n.z, n.w, limit);
    var u = au.xyz;
    var v = av.xyz;
    if au.w > 0.0 && av.w == 0.0 {
        v = cross(perpendicular(u), u);
    } else if au.w == 0.0 && av.w > 0.0 {
        u = cross(perpendicular(v), v);
    } else if au.w == 0.0 && av.w == 0.0 {
        u = vec3<f32>(median, 0.0, 0.0);
        v = vec3<f32>(0.0, median, 0.0);
    }
    let e1 = u / max(len(u), 1e-30);
    var normal = cross(u, v);
    if len(normal) <= 1e-6 * len(u) * len(v) {
        normal = perpendicular(e1);
    }
    normal = normal / max(len(normal), 1e-30);
    let e2 = cross(normal, e1);
    let su = len(u);
    let sv = max(abs(dot(v, e2)), 0.25 * len(v));
    let color = vec3<f32>(colors[3u * i], colors[3u * i + 1u], colors[3u * i + 2u]);
    let f_dc = (color - vec3<f32>(0.5)) / SH_C0;
    let scale = vec3<f32>(SPREAD * su, SPREAD * sv, THICKNESS * min(su, sv));
    var s: GpuSplat;
    s.position_opacity = vec4<f32>(c, OPACITY);
    s.scale = vec4<f32>(scale, 0.0);
    s.rotation = quat_from_frame(e1, e2, normal);
    s.f_dc = vec4<f32>(f_dc, 0.0);
    splats[i] = s;
    if p.features != 0u {
        let q = vec3<f32>(unit[3u * i], unit[3u * i + 1u], unit[3u * i + 2u]) - vec3<f32>(0.5);
        let shown = vec3<f32>(0.5) + SH_C0 * f_dc;
        let o = 11u * i;
        features[o] = Elem(q.x);
        features[o + 1u] = Elem(q.y);
        features[o + 2u] = Elem(q.z);
        features[o + 3u] = Elem(shown.x);
        features[o + 4u] = Elem(shown.y);
        features[o + 5u] = Elem(shown.z);
        features[o + 6u] = Elem(normal.x);
        features[o + 7u] = Elem(normal.y);
        features[o + 8u] = Elem(normal.z);
        features[o + 9u] = Elem(log(max(scale.x / SPREAD / median, 1e-6)));
        features[o + 10u] = Elem(log(max(scale.y / SPREAD / median, 1e-6)));
    }
}
