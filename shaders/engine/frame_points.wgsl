// A frame's drawn points in world space: the PCA reconstruction mean + Σ_k c_k basis_k
// (summed over k in order) with the root shift put back (or the clamped points when
// there are no components), then (v - 0.5) / scale + the world root. One thread per
// four values, read as texels (src/gpu/texels.rs; basis rows padded to whole texels).

#import gpu/for_each.wgsl

#bind p: uniform PostParams
#bind unit, mean, basis: texture_2d<f32>
#bind state: read FrameState
#bind coefficients: texture_2d<f32>
#bind points: read_write array<f32>

fn count() -> u32 { return (3u * p.points + 3u) / 4u; }

fn each(q: u32) {
    let d = 3u * p.points;
    let quads = (d + 3u) / 4u;
    // Value 4q + c is on axis (q + c) % 3 (4 ≡ 1 mod 3).
    let axes = (vec4<u32>(q) + vec4<u32>(0u, 1u, 2u, 3u)) % 3u;
    let shift = vec4<f32>(state.shift[axes.x], state.shift[axes.y], state.shift[axes.z], state.shift[axes.w]);
    let root = vec4<f32>(state.root[axes.x], state.root[axes.y], state.root[axes.z], state.root[axes.w]);
    let motion = vec4<f32>(state.motion[axes.x], state.motion[axes.y], state.motion[axes.z], state.motion[axes.w]);
    var v = texel(unit, q) - shift;
    if p.components > 0u {
        var o = texel(mean, q);
        let whole = p.components / 4u;
        for (var kq = 0u; kq < whole; kq++) {
            let c = texel(coefficients, kq);
            let k = 4u * kq;
            o += c.x * texel(basis, k * quads + q);
            o += c.y * texel(basis, (k + 1u) * quads + q);
            o += c.z * texel(basis, (k + 2u) * quads + q);
            o += c.w * texel(basis, (k + 3u) * quads + q);
        }
        for (var k = 4u * whole; k < p.components; k++) {
            o += texel(coefficients, k / 4u)[k % 4u] * texel(basis, k * quads + q);
        }
        v = o;
    }
    let out = (v + motion - 0.5) / p.scale + root;
    for (var c = 0u; c < 4u; c++) {
        if 4u * q + c < d {
            points[4u * q + c] = out[c];
        }
    }
}
