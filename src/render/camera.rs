//! The orbit camera: yaw/pitch/distance around a target point, with pan, zoom, framing.
//! Pure math (glam); the app maps mouse input onto it, headless renders set it directly.

use glam::{Mat4, Vec3};

use crate::splat::project::SplatCamera;

/// Vertical field of view in radians.
pub const FOV_Y: f32 = 0.8;
const MIN_DISTANCE: f32 = 0.2;
const MAX_DISTANCE: f32 = 100.0;
const PITCH_LIMIT: f32 = 1.5;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct OrbitCamera {
    pub target: Vec3,
    /// Rotation about +Y in radians; 0 looks from +Z toward -Z.
    pub yaw: f32,
    /// Elevation in radians, positive looks down from above.
    pub pitch: f32,
    pub distance: f32,
}

impl Default for OrbitCamera {
    fn default() -> Self {
        Self {
            target: Vec3::new(0.0, 1.0, 0.0),
            yaw: 0.5,
            pitch: 0.25,
            distance: 4.0,
        }
    }
}

impl OrbitCamera {
    /// World-space eye position.
    pub fn eye(&self) -> Vec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        self.target + self.distance * Vec3::new(sy * cp, sp, cy * cp)
    }

    pub fn view(&self) -> Mat4 {
        glam::camera::rh::view::look_at_mat4(self.eye(), self.target, Vec3::Y)
    }

    /// The splat rasterizer's pinhole camera for this view at `width` × `height` pixels.
    pub fn splat_camera(&self, width: u32, height: u32) -> SplatCamera {
        let projection = self.projection(width as f32 / height as f32);
        SplatCamera {
            view: self.view(),
            fx: 0.5 * width as f32 * projection.x_axis.x,
            fy: 0.5 * height as f32 * projection.y_axis.y,
            width,
            height,
            near: (self.distance * 0.01).max(0.01),
            depth_range: 4.0 * self.distance,
        }
    }

    /// Projection with depth in [0, 1] and y up (the WebGPU convention).
    pub fn projection(&self, aspect: f32) -> Mat4 {
        let near = (self.distance * 0.01).max(0.01);
        glam::camera::rh::proj::directx::perspective(
            FOV_Y,
            aspect.max(1e-3),
            near,
            self.distance * 20.0 + 50.0,
        )
    }

    pub fn view_projection(&self, aspect: f32) -> Mat4 {
        self.projection(aspect) * self.view()
    }

    /// Orbits by angles in radians; pitch stays short of the poles.
    pub fn orbit(&mut self, d_yaw: f32, d_pitch: f32) {
        self.yaw = (self.yaw + d_yaw).rem_euclid(std::f32::consts::TAU);
        self.pitch = (self.pitch + d_pitch).clamp(-PITCH_LIMIT, PITCH_LIMIT);
    }

    /// Moves the target in the view plane; `dx`, `dy` are fractions of the view height,
    /// so a drag across the whole view moves the target by what the view shows.
    pub fn pan(&mut self, dx: f32, dy: f32) {
        let forward = (self.target - self.eye()).normalize();
        let right = forward.cross(Vec3::Y).normalize();
        let up = right.cross(forward);
        let view_height = 2.0 * self.distance * (FOV_Y * 0.5).tan();
        self.target += (-dx * right + dy * up) * view_height;
    }

    /// Zooms by a factor (> 1 moves closer).
    pub fn zoom(&mut self, factor: f32) {
        self.distance = (self.distance / factor.max(1e-3)).clamp(MIN_DISTANCE, MAX_DISTANCE);
    }

    /// Centres the target on the box and backs off until its bounding sphere fits the view.
    pub fn frame(&mut self, min: Vec3, max: Vec3) {
        self.target = (min + max) * 0.5;
        let radius = ((max - min).length() * 0.5).max(0.05);
        self.distance = (radius / (FOV_Y * 0.5).sin()).clamp(MIN_DISTANCE, MAX_DISTANCE);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_eye_looks_at_the_target_from_the_given_distance() {
        let cam = OrbitCamera::default();
        assert!((cam.eye().distance(cam.target) - cam.distance).abs() < 1e-5);
        // The target projects to the centre of the screen.
        let clip = cam.view_projection(1.5) * cam.target.extend(1.0);
        assert!((clip.x / clip.w).abs() < 1e-5 && (clip.y / clip.w).abs() < 1e-5);
    }

    #[test]
    fn yaw_zero_pitch_zero_looks_down_negative_z() {
        let cam = OrbitCamera {
            target: Vec3::ZERO,
            yaw: 0.0,
            pitch: 0.0,
            distance: 2.0,
        };
        assert!(cam.eye().abs_diff_eq(Vec3::new(0.0, 0.0, 2.0), 1e-6));
    }

    #[test]
    fn orbit_keeps_the_distance_and_clamps_pitch() {
        let mut cam = OrbitCamera::default();
        cam.orbit(1.0, 10.0);
        assert_eq!(cam.pitch, PITCH_LIMIT);
        assert!((cam.eye().distance(cam.target) - cam.distance).abs() < 1e-5);
        cam.orbit(-20.0, 0.0);
        assert!((0.0..std::f32::consts::TAU).contains(&cam.yaw));
    }

    #[test]
    fn pan_moves_target_and_eye_together() {
        let mut cam = OrbitCamera::default();
        let offset = cam.eye() - cam.target;
        cam.pan(0.25, -0.1);
        assert!(!cam.target.abs_diff_eq(OrbitCamera::default().target, 1e-3));
        assert!((cam.eye() - cam.target).abs_diff_eq(offset, 1e-5));
    }

    #[test]
    fn zoom_is_clamped() {
        let mut cam = OrbitCamera::default();
        cam.zoom(2.0);
        assert!((cam.distance - 2.0).abs() < 1e-6);
        cam.zoom(1e6);
        assert_eq!(cam.distance, MIN_DISTANCE);
        cam.zoom(1e-6);
        assert_eq!(cam.distance, MAX_DISTANCE);
    }

    #[test]
    fn framing_fits_the_bounding_sphere() {
        let mut cam = OrbitCamera::default();
        cam.frame(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 2.0, 0.5));
        assert!(cam.target.abs_diff_eq(Vec3::new(0.0, 1.0, 0.0), 1e-6));
        // Every corner of the box lands inside the view (|ndc| <= 1) at aspect 1.
        let vp = cam.view_projection(1.0);
        for corner in 0..8 {
            let p = Vec3::new(
                if corner & 1 == 0 { -0.5 } else { 0.5 },
                if corner & 2 == 0 { 0.0 } else { 2.0 },
                if corner & 4 == 0 { -0.5 } else { 0.5 },
            );
            let clip = vp * p.extend(1.0);
            assert!(
                (clip.x / clip.w).abs() <= 1.0 && (clip.y / clip.w).abs() <= 1.0,
                "{p}"
            );
        }
    }
}
