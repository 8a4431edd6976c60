//! Retargeting clips through the humanoid template: each template joint of the source
//! rig turns, in world space, by the same rotation away from its bind pose on the target,
//! whose joints rest unrotated; the hips' travel scales with the hip height. Joints
//! outside the template (spring chains, extra bones) follow their parents. Source bones
//! are found by the template's, VRM, Mixamo or Unreal names (`avatar::humanoid`).

use glam::{Mat4, Quat, Vec3};

use super::gltf_out::ClipOut;
use super::skeleton::{Skeleton, template_joints};
use crate::avatar::Character;
use crate::avatar::humanoid;
use crate::avatar::locomotion::FRAME_RATE;

fn rotation_of(m: &Mat4) -> Quat {
    m.to_scale_rotation_translation().1.normalize()
}

/// `clip` of `source` resampled at the teacher's frame rate onto `target` (joints in
/// bind pose, the template's names), as per-joint local rotations relative to joints that
/// rest unrotated, and the root's (joint 0's) translation.
pub fn retarget(source: &Character, clip: &str, target: &Skeleton) -> anyhow::Result<ClipOut> {
    let clip = source.clip(clip)?;
    let rig = &source.rig;
    let rest_world = rig.world(&rig.rest_pose(), Mat4::IDENTITY);
    let template = template_joints(true);
    // Source node per target joint, for the template joints the source has.
    let templates: Vec<&str> = target
        .names
        .iter()
        .map(|name| {
            if template.iter().any(|(t, _)| t == name) {
                name.as_str()
            } else {
                ""
            }
        })
        .collect();
    let source_of = humanoid::find_all(rig, source.vrm.as_ref(), &templates);
    let hips = source_of[0]
        .filter(|_| target.names[0] == "Hips")
        .ok_or_else(|| anyhow::anyhow!("retargeting needs a humanoid target whose root is Hips"))?;
    let source_hips = rest_world[hips].w_axis.truncate();
    let ground = |s: &Skeleton| s.joints.iter().map(|p| p.y).fold(f32::MAX, f32::min);
    let source_ground = {
        let mesh = source.rest_mesh();
        mesh.bounds().map_or(0.0, |(lo, _)| lo.y)
    };
    let scale = (target.joints[0].y - ground(target)) / (source_hips.y - source_ground).max(1e-6);
    let frames = ((clip.duration * FRAME_RATE).round() as usize).max(1) + 1;
    let mut out = ClipOut {
        name: clip.name.clone(),
        times: Vec::with_capacity(frames),
        rotations: vec![Vec::with_capacity(frames); target.len()],
        root_translations: Vec::with_capacity(frames),
    };
    let mut pose = rig.rest_pose();
    for f in 0..frames {
        let t = (f as f32 / FRAME_RATE).min(clip.duration);
        pose.copy_from_slice(&rig.rest_pose());
        clip.sample(t, &mut pose);
        let world = rig.world(&pose, Mat4::IDENTITY);
        let mut target_world = vec![Quat::IDENTITY; target.len()];
        for j in 0..target.len() {
            let parent_world = target.parents[j].map_or(Quat::IDENTITY, |p| target_world[p]);
            target_world[j] = match source_of[j] {
                Some(node) => rotation_of(&world[node]) * rotation_of(&rest_world[node]).inverse(),
                None => parent_world,
            };
            out.rotations[j].push((parent_world.inverse() * target_world[j]).normalize());
        }
        let travel = world[hips].w_axis.truncate() - source_hips;
        out.root_translations
            .push(target.joints[0] + travel * scale);
        out.times.push(t);
    }
    Ok(out)
}

/// Local rest transforms of a skeleton whose joints rest unrotated: each joint sits at its
/// offset from its parent.
pub fn rest_offsets(skeleton: &Skeleton) -> Vec<Vec3> {
    (0..skeleton.len())
        .map(|j| {
            skeleton.parents[j].map_or(skeleton.joints[j], |p| {
                skeleton.joints[j] - skeleton.joints[p]
            })
        })
        .collect()
}
