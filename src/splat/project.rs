//! Projecting 3D Gaussians to the screen (the EWA splatting of 3DGS), shared meaning for
//! the CPU reference renderer and the WGSL rasterizer (shaders/splat_project.wgsl mirrors
//! [`project`] line by line): camera-space mean, the Jacobian of the perspective at the
//! mean, Σ' = J W Σ Wᵀ Jᵀ + 0.3 I (a pixel-sized low-pass), its inverse (the conic),
//! a 3σ radius, and a sort key: the 16×16 tile in the high 16 bits, the depth quantised
//! to 16 bits over [0, depth_range) in the low ones.

use glam::{Mat3, Mat4, Vec2, Vec3};

use super::ply::Splat;

/// Tile size of the rasterizer, pixels.
pub const TILE: u32 = 16;

/// A pinhole camera in pixels.
#[derive(Clone, Copy, Debug)]
pub struct SplatCamera {
    pub view: Mat4,
    pub fx: f32,
    pub fy: f32,
    pub width: u32,
    pub height: u32,
    pub near: f32,
    /// Depths in [0, depth_range) sort exactly to 1/65536 of it; farther ones tie.
    pub depth_range: f32,
}

impl SplatCamera {
    pub fn tiles(&self) -> (u32, u32) {
        (self.width.div_ceil(TILE), self.height.div_ceil(TILE))
    }
}

/// A Gaussian on the screen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected {
    pub center: Vec2,
    /// The inverse 2D covariance (a, b, c): power = -½ (a dx² + 2 b dx dy + c dy²).
    pub conic: Vec3,
    pub depth: f32,
    pub radius: f32,
    pub color: Vec3,
    pub opacity: f32,
    /// Tiles covered: [x0, y0, x1, y1) in tile units.
    pub tiles: [u32; 4],
}

/// The splat's 3D covariance R S Sᵀ Rᵀ.
pub fn covariance(s: &Splat) -> Mat3 {
    let m = Mat3::from_quat(s.rotation) * Mat3::from_diagonal(s.scale);
    m * m.transpose()
}

/// `None` when the splat is behind the near plane, degenerate, or off screen.
pub fn project(s: &Splat, cam: &SplatCamera) -> Option<Projected> {
    let t = cam.view.transform_point3(s.position);
    let z = -t.z;
    if z < cam.near {
        return None;
    }
    let (cx, cy) = (0.5 * cam.width as f32, 0.5 * cam.height as f32);
    let center = Vec2::new(cx + cam.fx * t.x / z, cy - cam.fy * t.y / z);
    // Rows of J (d pixel / d camera-space point).
    let j0 = Vec3::new(cam.fx / z, 0.0, cam.fx * t.x / (z * z));
    let j1 = Vec3::new(0.0, -cam.fy / z, -cam.fy * t.y / (z * z));
    let w = Mat3::from_mat4(cam.view);
    let sigma = w * covariance(s) * w.transpose();
    let (sj0, sj1) = (sigma * j0, sigma * j1);
    let a = j0.dot(sj0) + 0.3;
    let b = j0.dot(sj1);
    let c = j1.dot(sj1) + 0.3;
    let det = a * c - b * b;
    if det <= 0.0 {
        return None;
    }
    let mid = 0.5 * (a + c);
    let largest = mid + (mid * mid - det).max(0.1).sqrt();
    let radius = (3.0 * largest.sqrt()).ceil();
    let (tx, ty) = cam.tiles();
    let tile = TILE as f32;
    let x0 = ((center.x - radius) / tile).floor().clamp(0.0, tx as f32) as u32;
    let x1 = ((center.x + radius) / tile).ceil().clamp(0.0, tx as f32) as u32;
    let y0 = ((center.y - radius) / tile).floor().clamp(0.0, ty as f32) as u32;
    let y1 = ((center.y + radius) / tile).ceil().clamp(0.0, ty as f32) as u32;
    if x0 >= x1 || y0 >= y1 {
        return None;
    }
    Some(Projected {
        center,
        conic: Vec3::new(c, -b, a) / det,
        depth: z,
        radius,
        color: s.color().max(Vec3::ZERO),
        opacity: s.opacity,
        tiles: [x0, y0, x1, y1],
    })
}

/// The 16-bit quantised depth of the sort key.
pub fn depth_key(depth: f32, cam: &SplatCamera) -> u32 {
    ((depth / cam.depth_range).clamp(0.0, 1.0) * 65535.0) as u32
}

/// The alpha one splat adds at pixel centre `pixel` (0 below 1/255, at most 0.99).
pub fn alpha(p: &Projected, pixel: Vec2) -> f32 {
    let d = p.center - pixel;
    let power = -0.5 * (p.conic.x * d.x * d.x + p.conic.z * d.y * d.y) - p.conic.y * d.x * d.y;
    if power > 0.0 {
        return 0.0;
    }
    let a = (p.opacity * power.exp()).min(0.99);
    if a < 1.0 / 255.0 { 0.0 } else { a }
}

/// Transmittance below which a pixel stops blending.
pub const DONE: f32 = 1e-4;

/// The CPU reference renderer: every pixel blends the splats whose tiles cover it, front
/// to back in sort-key order (the rasterizer's order), over `background`; linear RGBA.
/// Each tile's list holds its splats in that order, so a pixel visits only the splats
/// that can touch it: the same image as scanning every splat for every pixel, which
/// took about 20 s for the Witch's 306k level-1024 splats at 128².
pub fn render_reference(splats: &[Splat], cam: &SplatCamera, background: Vec3) -> Vec<[f32; 4]> {
    let mut projected: Vec<(u32, Projected)> = splats
        .iter()
        .filter_map(|s| project(s, cam))
        .map(|p| (depth_key(p.depth, cam), p))
        .collect();
    // A stable sort by key keeps input order among equal keys, as the radix sort does.
    projected.sort_by_key(|(key, _)| *key);
    let (tiles_x, tiles_y) = cam.tiles();
    let mut lists: Vec<Vec<&Projected>> = vec![Vec::new(); (tiles_x * tiles_y) as usize];
    for (_, p) in &projected {
        let [x0, y0, x1, y1] = p.tiles;
        for ty in y0..y1.min(tiles_y) {
            for tx in x0..x1.min(tiles_x) {
                lists[(ty * tiles_x + tx) as usize].push(p);
            }
        }
    }
    let mut image = Vec::with_capacity((cam.width * cam.height) as usize);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let list = &lists[((y / TILE) * tiles_x + x / TILE) as usize];
            let pixel = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let (mut color, mut transmittance) = (Vec3::ZERO, 1.0f32);
            for p in list {
                let a = alpha(p, pixel);
                if a == 0.0 {
                    continue;
                }
                let next = transmittance * (1.0 - a);
                if next < DONE {
                    break;
                }
                color += p.color * a * transmittance;
                transmittance = next;
            }
            color += background * transmittance;
            image.push([color.x, color.y, color.z, 1.0 - transmittance]);
        }
    }
    image
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    /// A camera 4 m out on +Z looking at the origin, 64 × 48 pixels, 0.8 rad high.
    fn camera() -> SplatCamera {
        let fy = 0.5 * 48.0 / (0.4f32).tan();
        SplatCamera {
            view: glam::camera::rh::view::look_at_mat4(
                Vec3::new(0.0, 0.0, 4.0),
                Vec3::ZERO,
                Vec3::Y,
            ),
            fx: fy,
            fy,
            width: 64,
            height: 48,
            near: 0.04,
            depth_range: 16.0,
        }
    }

    fn splat(position: Vec3, scale: Vec3, rotation: Quat) -> Splat {
        Splat {
            position,
            f_dc: Vec3::ZERO,
            opacity: 0.9,
            scale,
            rotation,
        }
    }

    #[test]
    fn a_round_splat_at_the_target_projects_to_the_centre_with_the_expected_size() {
        // At distance 4 a sphere of σ = 0.05 has a screen σ of fy · 0.05 / 4 pixels.
        let cam = camera();
        let p = project(&splat(Vec3::ZERO, Vec3::splat(0.05), Quat::IDENTITY), &cam).unwrap();
        assert!(
            p.center.distance(Vec2::new(32.0, 24.0)) < 1e-4,
            "{}",
            p.center
        );
        let sigma = cam.fy * 0.05 / 4.0;
        let var = sigma * sigma + 0.3;
        assert!(
            (p.conic.x - 1.0 / var).abs() < 1e-4 && p.conic.y.abs() < 1e-6,
            "{:?}",
            p.conic
        );
        // The larger eigenvalue is var; like 3DGS the radius pads it by √0.1.
        assert_eq!(p.radius, (3.0 * (var + 0.1f32.sqrt()).sqrt()).ceil());
        assert!((p.depth - 4.0).abs() < 1e-5);
    }

    #[test]
    fn up_is_up_and_right_is_right_on_screen() {
        // The default camera looks from +Z toward -Z: world +X is screen right, +Y up.
        let cam = camera();
        let s = |p| {
            project(&splat(p, Vec3::splat(0.02), Quat::IDENTITY), &cam)
                .unwrap()
                .center
        };
        assert!(s(Vec3::X * 0.5).x > 32.0 + 1.0);
        assert!(s(Vec3::Y * 0.5).y < 24.0 - 1.0);
        // A splat stretched along world X is wider than tall: a < c in the conic.
        let wide = project(
            &splat(Vec3::ZERO, Vec3::new(0.2, 0.02, 0.02), Quat::IDENTITY),
            &cam,
        )
        .unwrap();
        assert!(wide.conic.x < wide.conic.z);
        // Rotated 90° about Z it is taller than wide.
        let tall = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let tall = project(&splat(Vec3::ZERO, Vec3::new(0.2, 0.02, 0.02), tall), &cam).unwrap();
        assert!(tall.conic.x > tall.conic.z);
        assert!(
            project(
                &splat(Vec3::Z * 5.0, Vec3::splat(0.1), Quat::IDENTITY),
                &cam
            )
            .is_none(),
            "behind"
        );
    }

    #[test]
    fn the_reference_blends_front_to_back() {
        // A red splat in front of a green one, both opaque at their centres: the pixel at
        // the centre is red·0.9 + green·0.9·0.1 + background·0.01.
        let cam = camera();
        let mut front = splat(Vec3::Z * 0.5, Vec3::splat(0.3), Quat::IDENTITY);
        front.f_dc = (Vec3::X - Vec3::splat(0.5)) / super::super::ply::SH_C0;
        let mut back = splat(Vec3::ZERO, Vec3::splat(0.3), Quat::IDENTITY);
        back.f_dc = (Vec3::Y - Vec3::splat(0.5)) / super::super::ply::SH_C0;
        let image = render_reference(&[back, front], &cam, Vec3::Z);
        let centre = image[(24 * 64 + 32) as usize];
        // The pixel centre is 0.5 px off the splat centre: alpha ≈ 0.9 · exp(-tiny).
        assert!((centre[0] - 0.9).abs() < 0.01, "{centre:?}");
        assert!((centre[1] - 0.09).abs() < 0.01, "{centre:?}");
        assert!((centre[2] - 0.01).abs() < 0.01, "{centre:?}");
        let corner = image[0];
        assert_eq!(
            corner,
            [0.0, 0.0, 1.0, 0.0],
            "background where nothing covers"
        );
    }
}
