//! Group normalisation: one scale for the avatar (0.7 / the reference's largest extent, or
//! less where the baked motion would otherwise reach past the unit cube's margin — a big
//! head above a low waist) and, per group of frames, the translation that puts one frame's root (the mean of its
//! waist pixels) at 0.5 — so differences between the frames of a group are true motion.

use glam::Vec3;

/// Share of the unit cube the reference's largest extent spans (the rest is margin for
/// the motion within a group).
pub const FILL: f32 = 0.7;

/// The least distance between the baked motion and the unit cube's faces.
pub const MARGIN: f32 = 0.05;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupNorm {
    pub scale: f32,
}

#[derive(Debug, PartialEq, thiserror::Error)]
#[error("frame {frame} of the group, point {point}: normalised value {value} leaves [0, 1]")]
pub struct NormError {
    pub frame: usize,
    pub point: usize,
    pub value: Vec3,
}

impl GroupNorm {
    /// The scale for a reference mesh whose largest bounding-box extent is `extent`.
    pub fn for_extent(extent: f32) -> Self {
        Self {
            scale: FILL / extent.max(1e-6),
        }
    }

    /// This scale, lowered where needed so that points up to `reach` (world units, any
    /// axis) from a group's root stay [`MARGIN`] inside the unit cube.
    pub fn fitted(self, reach: f32) -> Self {
        Self {
            scale: self.scale.min((0.5 - MARGIN) / reach.max(1e-6)),
        }
    }

    /// The farthest any point of a group's frames gets from the group's root along any
    /// axis, over every group of `group` consecutive frames with root frame `anchor`;
    /// `bounds` are each frame's point bounds (min, max), `roots` its roots.
    pub fn reach(bounds: &[(Vec3, Vec3)], roots: &[Vec3], group: usize, anchor: usize) -> f32 {
        let mut reach = 0.0f32;
        for start in 0..bounds.len().saturating_sub(group - 1) {
            let root = roots[start + anchor];
            for (lo, hi) in &bounds[start..start + group] {
                reach = reach.max((*hi - root).max_element().max((root - *lo).max_element()));
            }
        }
        reach
    }

    /// The root of a frame: the mean of its waist points.
    pub fn root(points: &[Vec3], waist: &[u32]) -> Vec3 {
        waist.iter().map(|&i| points[i as usize]).sum::<Vec3>() / waist.len().max(1) as f32
    }

    /// Normalises a group of frames so that frame `anchor`'s root sits at (0.5, 0.5, 0.5);
    /// returns the frames and that root (world). Every value must stay in [0, 1].
    pub fn normalise(
        &self,
        frames: &[Vec<Vec3>],
        waist: &[u32],
        anchor: usize,
    ) -> Result<(Vec<Vec<Vec3>>, Vec3), NormError> {
        let root = Self::root(&frames[anchor], waist);
        let normalised: Vec<Vec<Vec3>> = frames.iter().map(|f| self.to_unit(f, root)).collect();
        for (frame, points) in normalised.iter().enumerate() {
            if let Some(point) = points
                .iter()
                .position(|p| p.min_element() < 0.0 || p.max_element() > 1.0)
            {
                return Err(NormError {
                    frame,
                    point,
                    value: points[point],
                });
            }
        }
        Ok((normalised, root))
    }

    /// World points to the unit cube, with `root` at 0.5.
    pub fn to_unit(&self, points: &[Vec3], root: Vec3) -> Vec<Vec3> {
        points
            .iter()
            .map(|p| (*p - root) * self.scale + Vec3::splat(0.5))
            .collect()
    }

    /// The inverse of [`Self::to_unit`]: a normalised map back to a world point cloud.
    pub fn to_world(&self, points: &[Vec3], root: Vec3) -> Vec<Vec3> {
        points
            .iter()
            .map(|p| (*p - Vec3::splat(0.5)) / self.scale + root)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_anchor_root_lands_at_one_half_and_motion_is_kept() {
        let norm = GroupNorm::for_extent(2.0); // scale 0.35
        let frame = |dx: f32| {
            vec![
                Vec3::new(1.0 + dx, 1.0, 0.0),
                Vec3::new(1.0 + dx, 2.0, 0.0),
                Vec3::new(2.0 + dx, 1.0, 0.0),
            ]
        };
        let frames = vec![frame(0.0), frame(0.1), frame(0.2), frame(0.3)];
        let waist = [0, 1];
        let (unit, root) = norm.normalise(&frames, &waist, 2).unwrap();
        assert!(root.abs_diff_eq(Vec3::new(1.2, 1.5, 0.0), 1e-6));
        assert!(GroupNorm::root(&unit[2], &waist).abs_diff_eq(Vec3::splat(0.5), 1e-6));
        // Frame 3 moved 0.1 m further in x: 0.035 in normalised units.
        let shift = GroupNorm::root(&unit[3], &waist) - GroupNorm::root(&unit[2], &waist);
        assert!(shift.abs_diff_eq(Vec3::new(0.035, 0.0, 0.0), 1e-6));
        let back = norm.to_world(&unit[0], root);
        for (a, b) in back.iter().zip(&frames[0]) {
            assert!(a.abs_diff_eq(*b, 1e-5));
        }
    }

    #[test]
    fn leaving_the_unit_cube_is_an_error() {
        let norm = GroupNorm::for_extent(1.0);
        let frames = vec![vec![Vec3::ZERO, Vec3::new(0.9, 0.0, 0.0)]];
        let err = norm.normalise(&frames, &[0], 0).unwrap_err();
        assert_eq!((err.frame, err.point), (0, 1));
        assert!(err.to_string().contains("leaves [0, 1]"));
    }

    #[test]
    fn the_scale_shrinks_only_when_the_motion_reaches_too_far() {
        // Two frames of a group of 2 anchored on frame 1: the root moves 1 m in x and a
        // point 2 m above the root at frame 0 -> reach 2 (the head) and 1 (the move).
        let bounds = [
            (Vec3::new(-0.2, 0.0, -0.1), Vec3::new(0.2, 2.0, 0.1)),
            (Vec3::new(0.8, 0.0, -0.1), Vec3::new(1.2, 1.5, 0.1)),
        ];
        let roots = [Vec3::ZERO, Vec3::new(1.0, 0.0, 0.0)];
        let reach = GroupNorm::reach(&bounds, &roots, 2, 1);
        assert!((reach - 2.0).abs() < 1e-6, "{reach}");
        // 0.7 / 2 m = 0.35 would put the top at 0.5 + 0.7: lowered to 0.45 / 2.
        let fitted = GroupNorm::for_extent(2.0).fitted(reach);
        assert!((fitted.scale - 0.225).abs() < 1e-6, "{}", fitted.scale);
        // A small reach keeps the extent's scale.
        assert_eq!(GroupNorm::for_extent(2.0).fitted(0.5).scale, 0.35);
    }
}
