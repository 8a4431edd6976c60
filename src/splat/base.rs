//! Base splats (docs/architecture.md, Appearance): one flat Gaussian per foreground pixel
//! of a position map, in the local surface frame of its map neighbourhood, recomputed
//! every frame (so splats turn and stretch with the body instead of keeping the rest
//! pose's shape). x follows the column tangent, z the surface normal; σ = 0.6 × the
//! footprint along the surface and 0.1 × the smaller footprint across it. The same
//! arithmetic as train/unica_train/splats.py, pinned by a parity fixture; the refiner's
//! residuals are applied here too.

use glam::{Quat, Vec3};

use super::ply::{SH_C0, Splat};
use crate::posmap::table::VIEWS;

pub const SPREAD: f32 = 0.6;
pub const THICKNESS: f32 = 0.1;
pub const OPACITY: f32 = 0.95;
/// Above level 256 (the level the refiner is trained at), the drawn splats are this much
/// wider along the surface: there a splat is under half a pixel across at the
/// evaluation's 512² framing and the rasteriser's 0.3 px² blur sets its size, so at 1.0
/// the silhouettes lose a rim of pixels. Chosen on a script seed the evaluation does not
/// score (docs/experiments/appearance.md): the teacher's geometry at level 1024 scored
/// 16.8, 17.1, 17.3, 17.5 and 15.5 dB on white at 1.0, 1.25, 1.5, 2.0 and 3.0.
pub const FINE_WIDEN: f32 = 2.0;

/// How much wider than [`SPREAD`] the drawn splats of map size `level` are.
pub fn widen(level: usize) -> f32 {
    if level > 256 { FINE_WIDEN } else { 1.0 }
}

/// Multiplies each splat's two in-surface scales by `factor`.
pub fn widen_splats(splats: &mut [Splat], factor: f32) {
    for s in splats {
        s.scale.x *= factor;
        s.scale.y *= factor;
    }
}

/// Raw refiner outputs per splat: mean 3, colour 3, log-scale 3, rotation 4, opacity 1.
pub const RESIDUALS: usize = 14;

/// For each foreground pixel of a `size`² map (the 128 layout scaled by size / 128), its
/// right, left, lower and upper neighbour in the same view.
pub fn neighbours(pixels: &[u32], size: usize) -> Vec<[Option<u32>; 4]> {
    let mut index = vec![u32::MAX; size * size];
    for (i, &p) in pixels.iter().enumerate() {
        index[p as usize] = i as u32;
    }
    let factor = size / 128;
    let view = |row: usize, col: usize| {
        let (r, c) = (row / factor, col / factor);
        VIEWS.iter().position(|v| {
            (v.row..v.row + v.rows).contains(&r) && (v.col..v.col + v.cols).contains(&c)
        })
    };
    pixels
        .iter()
        .map(|&p| {
            let (row, col) = (p as usize / size, p as usize % size);
            [(0, 1), (0, -1), (1, 0), (-1, 0)].map(|(dr, dc): (isize, isize)| {
                let (r, c) = (row as isize + dr, col as isize + dc);
                if r < 0 || c < 0 || r >= size as isize || c >= size as isize {
                    return None;
                }
                let (r, c) = (r as usize, c as usize);
                let n = index[r * size + c];
                (n != u32::MAX && view(r, c) == view(row, col)).then_some(n)
            })
        })
        .collect()
}

/// The median distance to the right and lower neighbours (the sorted list's [len / 2]).
pub fn median_spacing(points: &[Vec3], neighbours: &[[Option<u32>; 4]]) -> f32 {
    let mut d: Vec<f32> = [0, 2]
        .iter()
        .flat_map(|&k| {
            neighbours
                .iter()
                .zip(points)
                .filter_map(move |(n, p)| n[k].map(|n| points[n as usize].distance(*p)))
        })
        .collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// A unit vector perpendicular to `t` (Y as the helper unless `t` is near Y, then X).
fn perpendicular(t: Vec3) -> Vec3 {
    let unit = t / t.length().max(1e-30);
    let helper = if unit.y.abs() > 0.9 { Vec3::X } else { Vec3::Y };
    let p = helper.cross(unit);
    p / p.length().max(1e-30)
}

/// One frame's local geometry: per point the tangents along map columns (u) and rows (v)
/// per pixel step, and the median spacing.
pub struct Tangents {
    pub u: Vec<Vec3>,
    pub v: Vec<Vec3>,
    pub median: f32,
}

/// Central differences over the neighbours within 3× the median spacing (one-sided at
/// edges); a missing tangent becomes a perpendicular of the other's length, both missing
/// the median along X and Y.
pub fn tangents(points: &[Vec3], neighbours: &[[Option<u32>; 4]]) -> Tangents {
    let median = median_spacing(points, neighbours);
    let limit = 3.0 * median;
    let axis = |p: Vec3, n: &[Option<u32>; 4], forward: usize, backward: usize| {
        let (mut total, mut count) = (Vec3::ZERO, 0u32);
        for (k, sign) in [(forward, 1.0), (backward, -1.0)] {
            if let Some(q) = n[k] {
                let d = points[q as usize] - p;
                if d.length() <= limit {
                    total += sign * d;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| total / count as f32)
    };
    let (mut us, mut vs) = (
        Vec::with_capacity(points.len()),
        Vec::with_capacity(points.len()),
    );
    for (&p, n) in points.iter().zip(neighbours) {
        let (u, v) = match (axis(p, n, 0, 1), axis(p, n, 2, 3)) {
            (Some(u), Some(v)) => (u, v),
            (Some(u), None) => (u, perpendicular(u).cross(u)),
            (None, Some(v)) => (perpendicular(v).cross(v), v),
            (None, None) => (Vec3::X * median, Vec3::Y * median),
        };
        us.push(u);
        vs.push(v);
    }
    Tangents {
        u: us,
        v: vs,
        median,
    }
}

/// The base splats of one frame (linear RGB `colors`) and their normals.
pub fn base_splats(points: &[Vec3], colors: &[Vec3], t: &Tangents) -> (Vec<Splat>, Vec<Vec3>) {
    points
        .iter()
        .zip(colors)
        .zip(t.u.iter().zip(&t.v))
        .map(|((&position, &color), (&u, &v))| {
            let e1 = u / u.length().max(1e-30);
            let mut n = u.cross(v);
            if n.length() <= 1e-6 * u.length() * v.length() {
                n = perpendicular(e1);
            }
            let n = n / n.length().max(1e-30);
            let e2 = n.cross(e1);
            let (su, sv) = (u.length(), v.dot(e2).abs().max(0.25 * v.length()));
            let splat = Splat {
                position,
                f_dc: (color - Vec3::splat(0.5)) / SH_C0,
                opacity: OPACITY,
                scale: Vec3::new(SPREAD * su, SPREAD * sv, THICKNESS * su.min(sv)),
                rotation: quat_from_frame(e1, e2, n),
            };
            (splat, n)
        })
        .unzip()
}

/// The rotation whose columns are `x`, `y`, `z` (orthonormal, right-handed), computed
/// as the trainer does (Shepperd's method: the largest of w, x, y, z from the diagonal,
/// the rest from the off-diagonal terms; w ≥ 0), so refiner residuals add to the same
/// quaternion on both sides.
pub fn quat_from_frame(x: Vec3, y: Vec3, z: Vec3) -> Quat {
    let (m00, m11, m22) = (x.x, y.y, z.z);
    let (a, b, c) = (y.z - z.y, z.x - x.z, x.y - y.x);
    let (xy, xz, yz) = (y.x + x.y, z.x + x.z, z.y + y.z);
    let root = |v: f32| v.max(1e-12).sqrt() * 2.0;
    let trace = m00 + m11 + m22;
    let q = if trace > 0.0 {
        let s = root(trace + 1.0);
        Quat::from_xyzw(a / s, b / s, c / s, s / 4.0)
    } else if m00 > m11 && m00 > m22 {
        let s = root(1.0 + m00 - m11 - m22);
        Quat::from_xyzw(s / 4.0, xy / s, xz / s, a / s)
    } else if m11 > m22 {
        let s = root(1.0 + m11 - m00 - m22);
        Quat::from_xyzw(xy / s, s / 4.0, yz / s, b / s)
    } else {
        let s = root(1.0 + m22 - m00 - m11);
        Quat::from_xyzw(xz / s, yz / s, s / 4.0, c / s)
    };
    let q = if q.w < 0.0 { -q } else { q };
    q.normalize()
}

/// The refiner's inputs [N, 11]: position about the root (unit − 0.5), linear colour,
/// normal, and the log of the two footprints over the median spacing.
pub fn features(unit: &[Vec3], splats: &[Splat], normals: &[Vec3], median: f32) -> Vec<f32> {
    unit.iter()
        .zip(splats)
        .zip(normals)
        .flat_map(|((&p, s), &n)| {
            let footprint = |k: usize| (s.scale[k] / SPREAD / median).max(1e-6).ln();
            let p = p - Vec3::splat(0.5);
            let c = s.color();
            [
                p.x,
                p.y,
                p.z,
                c.x,
                c.y,
                c.z,
                n.x,
                n.y,
                n.z,
                footprint(0),
                footprint(1),
            ]
        })
        .collect()
}

/// Base splats plus the refiner's raw residuals (14 per splat); `mean_bound` in world
/// units bounds the mean offsets.
pub fn refine(splats: &mut [Splat], residuals: &[f32], mean_bound: f32) {
    let logit = (OPACITY / (1.0 - OPACITY)).ln();
    for (s, r) in splats.iter_mut().zip(residuals.chunks_exact(RESIDUALS)) {
        let offset = Vec3::new(r[0].tanh(), r[1].tanh(), r[2].tanh()) * mean_bound;
        let color = s.color() + Vec3::new(r[3], r[4], r[5]);
        let rotation = Quat::from_xyzw(
            s.rotation.x + r[9],
            s.rotation.y + r[10],
            s.rotation.z + r[11],
            s.rotation.w + r[12],
        );
        s.position += offset;
        s.f_dc = (color - Vec3::splat(0.5)) / SH_C0;
        s.scale *= Vec3::new(r[6].exp(), r[7].exp(), r[8].exp());
        s.rotation = rotation.normalize();
        s.opacity = 1.0 / (1.0 + (-(logit + r[13])).exp());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat 4×3 patch of the front view, spacing 0.01, in the XY plane.
    fn patch() -> (Vec<u32>, Vec<Vec3>) {
        let mut pixels = Vec::new();
        let mut points = Vec::new();
        for row in 10..13 {
            for col in 60..64 {
                pixels.push((row * 128 + col) as u32);
                points.push(Vec3::new(col as f32 * 0.01, -(row as f32) * 0.01, 0.2));
            }
        }
        (pixels, points)
    }

    #[test]
    fn splats_above_level_256_are_widened_along_the_surface_only() {
        assert_eq!((widen(128), widen(256)), (1.0, 1.0));
        assert_eq!((widen(512), widen(1024)), (FINE_WIDEN, FINE_WIDEN));
        let mut splats = vec![Splat {
            position: Vec3::ZERO,
            f_dc: Vec3::ZERO,
            opacity: 0.5,
            scale: Vec3::new(1.0, 2.0, 0.25),
            rotation: Quat::IDENTITY,
        }];
        widen_splats(&mut splats, 1.5);
        assert_eq!(splats[0].scale, Vec3::new(1.5, 3.0, 0.25));
    }

    #[test]
    fn frames_become_the_quaternions_that_rotate_into_them() {
        for q in [
            Quat::IDENTITY,
            Quat::from_rotation_y(0.7),
            Quat::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 2.5),
            Quat::from_rotation_x(-1.2),
        ] {
            let got = quat_from_frame(q * Vec3::X, q * Vec3::Y, q * Vec3::Z);
            assert!(got.w >= 0.0);
            assert!(got.dot(q).abs() > 1.0 - 1e-6, "{got} vs {q}");
        }
    }

    #[test]
    fn neighbours_stay_inside_the_view() {
        // Column 47 is the back view's last, column 48 the front view's first.
        let pixels = [5 * 128 + 47, 5 * 128 + 48, 5 * 128 + 49];
        let n = neighbours(&pixels, 128);
        assert_eq!(n[0], [None; 4]);
        assert_eq!(n[1], [Some(2), None, None, None]);
        assert_eq!(n[2], [None, Some(1), None, None]);
        // At 1024 the same layout is 8× finer: pixel (40, 383) is the back view's edge.
        let fine = [40 * 1024 + 383, 40 * 1024 + 384];
        assert_eq!(neighbours(&fine, 1024), [[None; 4]; 2]);
    }

    #[test]
    fn a_flat_grid_gives_discs_in_its_plane_sized_by_the_spacing() {
        let (pixels, points) = patch();
        let n = neighbours(&pixels, 128);
        let t = tangents(&points, &n);
        assert!((t.median - 0.01).abs() < 1e-6);
        let colors = vec![Vec3::new(0.2, 0.4, 0.6); points.len()];
        let (splats, normals) = base_splats(&points, &colors, &t);
        for (s, n) in splats.iter().zip(&normals) {
            // u = +X per column, v = -Y per row: the normal is ±Z, x along X.
            assert!(n.abs().distance(Vec3::Z) < 1e-5, "{n}");
            assert!((s.rotation * Vec3::X).distance(Vec3::X) < 1e-5);
            assert!(
                s.scale.distance(Vec3::new(0.006, 0.006, 0.001)) < 1e-6,
                "{}",
                s.scale
            );
            assert!(s.color().distance(Vec3::new(0.2, 0.4, 0.6)) < 1e-6);
        }
    }

    #[test]
    fn a_stretched_turned_grid_gives_splats_that_follow_it() {
        // Rotate the patch by 90° about Y and stretch the columns ×2: splats follow.
        let (pixels, points) = patch();
        let turn = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        let moved: Vec<Vec3> = points
            .iter()
            .map(|p| turn * Vec3::new(p.x * 2.0, p.y, p.z))
            .collect();
        let n = neighbours(&pixels, 128);
        let (splats, _) = base_splats(&moved, &[Vec3::ONE; 12], &tangents(&moved, &n));
        for s in &splats {
            assert!((s.rotation * Vec3::X).distance(turn * Vec3::X) < 1e-5);
            assert!((s.scale.x - 0.012).abs() < 1e-6 && (s.scale.y - 0.006).abs() < 1e-6);
        }
    }

    #[test]
    fn a_depth_jump_is_not_a_neighbour() {
        let (pixels, mut points) = patch();
        points[3].z += 1.0; // the last column of the first row jumps away
        let n = neighbours(&pixels, 128);
        let t = tangents(&points, &n);
        // Its left neighbour is too far: u is one-sided from... nothing on the left.
        assert!((t.u[2] - Vec3::X * 0.01).length() < 1e-6, "{}", t.u[2]);
    }

    #[test]
    fn zero_residuals_leave_the_splats_unchanged() {
        let (pixels, points) = patch();
        let n = neighbours(&pixels, 128);
        let (splats, _) = base_splats(&points, &[Vec3::ONE * 0.3; 12], &tangents(&points, &n));
        let mut refined = splats.clone();
        refine(&mut refined, &vec![0.0; 12 * RESIDUALS], 0.01);
        for (a, b) in splats.iter().zip(&refined) {
            assert!(a.position.distance(b.position) < 1e-7);
            assert!((a.opacity - b.opacity).abs() < 1e-6);
            assert!(a.scale.distance(b.scale) < 1e-7);
            assert!(a.rotation.dot(b.rotation).abs() > 1.0 - 1e-6);
            assert!(a.f_dc.distance(b.f_dc) < 1e-5);
        }
        // Mean offsets stay within the bound however large the raw output.
        let mut pushed = splats.clone();
        let mut big = vec![0.0; 12 * RESIDUALS];
        big[0] = 1e6;
        refine(&mut pushed, &big, 0.01);
        assert!((pushed[0].position.x - splats[0].position.x - 0.01).abs() < 1e-6);
    }
}
