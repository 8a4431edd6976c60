//! The auto-rigger's metrics as in UniRig and RigNet, in the unit cube of the ground
//! truth's mesh: J2J (Chamfer distance between joint sets), J2B (joints to the other
//! skeleton's bone segments, both ways), B2B (between points sampled along the bones),
//! skin L1 (per vertex, summed over bones) and motion L2 (vertex distance after posing
//! with the same motion under predicted and true weights), and tearing: the largest edge
//! stretch of a posed mesh against its rest pose.

use glam::{Mat4, Quat, Vec3};

use super::skeleton::Skeleton;
use super::voxel::segment_distance;
use crate::random::Rng;

/// The largest edge stretch, posed length / rest length, over the edges of `indices`
/// (triangles) whose rest length is at least `shortest`.
pub fn edge_stretch(rest: &[Vec3], posed: &[Vec3], indices: &[u32], shortest: f32) -> f32 {
    let mut worst: f32 = 1.0;
    for t in indices.chunks_exact(3) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            let (a, b) = (a as usize, b as usize);
            let length = rest[a].distance(rest[b]);
            if length >= shortest {
                worst = worst.max(posed[a].distance(posed[b]) / length);
            }
        }
    }
    worst
}

/// Mean distance from each point of `a` to its nearest in `b`.
fn one_way(a: &[Vec3], b: &[Vec3]) -> f32 {
    a.iter()
        .map(|&p| {
            b.iter()
                .map(|&q| p.distance(q))
                .fold(f32::INFINITY, f32::min)
        })
        .sum::<f32>()
        / a.len().max(1) as f32
}

/// Symmetric Chamfer distance: the mean of both one-way means.
pub fn chamfer(a: &[Vec3], b: &[Vec3]) -> f32 {
    0.5 * (one_way(a, b) + one_way(b, a))
}

pub fn j2j(predicted: &Skeleton, truth: &Skeleton) -> f32 {
    chamfer(&predicted.joints, &truth.joints)
}

/// Bone segments; a lone root counts as a point.
fn segments(s: &Skeleton) -> Vec<(Vec3, Vec3)> {
    let bones = s.bones();
    if bones.is_empty() {
        s.joints.iter().map(|&p| (p, p)).collect()
    } else {
        bones
    }
}

fn joints_to_bones(joints: &[Vec3], bones: &[(Vec3, Vec3)]) -> f32 {
    joints
        .iter()
        .map(|&p| {
            bones
                .iter()
                .map(|&(a, b)| segment_distance(p, a, b))
                .fold(f32::INFINITY, f32::min)
        })
        .sum::<f32>()
        / joints.len().max(1) as f32
}

pub fn j2b(predicted: &Skeleton, truth: &Skeleton) -> f32 {
    0.5 * (joints_to_bones(&predicted.joints, &segments(truth))
        + joints_to_bones(&truth.joints, &segments(predicted)))
}

/// Points every `step` along each bone (both ends included).
fn bone_points(s: &Skeleton, step: f32) -> Vec<Vec3> {
    segments(s)
        .iter()
        .flat_map(|&(a, b)| {
            let n = ((a.distance(b) / step).ceil() as usize).max(1);
            (0..=n).map(move |k| a.lerp(b, k as f32 / n as f32))
        })
        .collect()
}

pub fn b2b(predicted: &Skeleton, truth: &Skeleton) -> f32 {
    chamfer(&bone_points(predicted, 0.01), &bone_points(truth, 0.01))
}

/// Mean over vertices of Σ_bones |predicted − true| (0 when equal, at most 2).
pub fn skin_l1(predicted: &[Vec<f32>], truth: &[Vec<f32>]) -> f32 {
    predicted
        .iter()
        .zip(truth)
        .map(|(p, t)| p.iter().zip(t).map(|(a, b)| (a - b).abs()).sum::<f32>())
        .sum::<f32>()
        / predicted.len().max(1) as f32
}

/// Linear blend skinning of `vertices` with full weights `[vertex][joint]` and one
/// skinning matrix per joint.
pub fn pose(vertices: &[Vec3], weights: &[Vec<f32>], skin: &[Mat4]) -> Vec<Vec3> {
    vertices
        .iter()
        .zip(weights)
        .map(|(&v, w)| {
            w.iter()
                .zip(skin)
                .filter(|(w, _)| **w > 0.0)
                .map(|(&w, m)| w * m.transform_point3(v))
                .sum()
        })
        .collect()
}

/// Mean vertex distance between the two weightings posed by each of `poses` (skinning
/// matrices per joint).
pub fn motion_l2(
    vertices: &[Vec3],
    predicted: &[Vec<f32>],
    truth: &[Vec<f32>],
    poses: &[Vec<Mat4>],
) -> f32 {
    let total: f32 = poses
        .iter()
        .map(|skin| {
            let a = pose(vertices, predicted, skin);
            let b = pose(vertices, truth, skin);
            a.iter().zip(&b).map(|(p, q)| p.distance(*q)).sum::<f32>() / a.len().max(1) as f32
        })
        .sum();
    total / poses.len().max(1) as f32
}

/// Skinning matrices of `count` random poses of a skeleton whose joints rest unrotated:
/// every joint turns up to `degrees` about a random axis.
pub fn random_poses(skeleton: &Skeleton, count: usize, degrees: f32, seed: u64) -> Vec<Vec<Mat4>> {
    let mut rng = Rng::new(seed);
    (0..count)
        .map(|_| {
            let mut world: Vec<Mat4> = Vec::with_capacity(skeleton.len());
            for j in 0..skeleton.len() {
                let axis = Vec3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                )
                .normalize_or(Vec3::X);
                let turn = Quat::from_axis_angle(axis, rng.range(-degrees, degrees).to_radians());
                let local = match skeleton.parents[j] {
                    Some(p) => Mat4::from_rotation_translation(
                        turn,
                        skeleton.joints[j] - skeleton.joints[p],
                    ),
                    None => Mat4::from_rotation_translation(turn, skeleton.joints[j]),
                };
                let parent = skeleton.parents[j].map_or(Mat4::IDENTITY, |p| world[p]);
                world.push(parent * local);
            }
            world
                .iter()
                .zip(&skeleton.joints)
                .map(|(w, &j)| *w * Mat4::from_translation(-j))
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::autorig::skeleton::Class;

    #[test]
    fn edge_stretch_of_known_deformations() {
        let rest = [Vec3::ZERO, Vec3::X, Vec3::Y];
        let indices = [0, 1, 2];
        assert_eq!(edge_stretch(&rest, &rest, &indices, 1e-6), 1.0);
        // Pulling vertex 1 to x = 3 stretches edge 0-1 three times (edge 1-2 √10/√2).
        let posed = [Vec3::ZERO, 3.0 * Vec3::X, Vec3::Y];
        assert!((edge_stretch(&rest, &posed, &indices, 1e-6) - 3.0).abs() < 1e-6);
        // A rigid turn stretches nothing; edges shorter than `shortest` are not counted.
        let turned: Vec<Vec3> = rest
            .iter()
            .map(|&p| Quat::from_rotation_z(1.0) * p)
            .collect();
        assert!((edge_stretch(&rest, &turned, &indices, 1e-6) - 1.0).abs() < 1e-5);
        assert_eq!(edge_stretch(&rest, &posed, &indices, 2.0), 1.0);
    }

    fn line(points: &[Vec3]) -> Skeleton {
        Skeleton {
            class: Class::Other,
            joints: points.to_vec(),
            parents: (0..points.len()).map(|j| j.checked_sub(1)).collect(),
            names: (0..points.len()).map(|j| format!("j{j}")).collect(),
            spring: vec![false; points.len()],
        }
    }

    #[test]
    fn distances_have_known_answers() {
        let a = line(&[Vec3::ZERO, Vec3::X]);
        assert_eq!(j2j(&a, &a), 0.0);
        assert_eq!(b2b(&a, &a), 0.0);
        // The same bone lifted by 0.1: every distance is 0.1.
        let b = line(&[Vec3::new(0.0, 0.1, 0.0), Vec3::new(1.0, 0.1, 0.0)]);
        assert!((j2j(&a, &b) - 0.1).abs() < 1e-6);
        assert!((j2b(&a, &b) - 0.1).abs() < 1e-6);
        assert!((b2b(&a, &b) - 0.1).abs() < 1e-6);
        // A joint in the middle of a bone is far from joints but on the bone.
        let c = line(&[Vec3::ZERO, Vec3::new(0.5, 0.0, 0.0), Vec3::X]);
        assert!((j2j(&c, &a) - 0.5 * (0.5 / 3.0)).abs() < 1e-6);
        assert!(j2b(&c, &a) < 1e-6);
    }

    #[test]
    fn skin_and_motion_errors_vanish_only_for_equal_weights() {
        let s = line(&[Vec3::ZERO, Vec3::Y, Vec3::new(0.0, 2.0, 0.0)]);
        let vertices = [Vec3::new(0.1, 0.5, 0.0), Vec3::new(0.1, 1.5, 0.0)];
        let truth = vec![vec![1.0, 0.0, 0.0], vec![0.0, 1.0, 0.0]];
        let other = vec![vec![0.5, 0.5, 0.0], vec![0.0, 1.0, 0.0]];
        assert_eq!(skin_l1(&truth, &truth), 0.0);
        assert!((skin_l1(&other, &truth) - 0.5).abs() < 1e-6);
        let poses = random_poses(&s, 4, 30.0, 1);
        assert!(motion_l2(&vertices, &truth, &truth, &poses) < 1e-6);
        assert!(motion_l2(&vertices, &other, &truth, &poses) > 1e-3);
        // At rest (no turn) every weighting poses the same.
        let rest = random_poses(&s, 1, 0.0, 1);
        assert!(motion_l2(&vertices, &other, &truth, &rest) < 1e-6);
    }
}
