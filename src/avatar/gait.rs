//! Gait measures of a character's clips: how fast the planted foot moves over a cycle
//! (the teacher's ground speed and the descriptions' still-or-moving inference).

use glam::{Mat4, Vec3};

use super::Character;
use super::clip::Clip;

/// The median over a looped clip's cycle of `measure(step) / dt`, where `step` is the
/// planted (lowest) foot's move between consecutive samples (`samples` of them, `dt`
/// apart) while the same foot stays planted; feet are measured from the horizontal
/// position of joint `origin` when given. 0 when no foot stays planted.
pub(crate) fn planted_speed(
    character: &Character,
    clip: &Clip,
    feet: &[usize],
    origin: Option<usize>,
    samples: usize,
    dt: f32,
    measure: impl Fn(Vec3) -> f32,
) -> f32 {
    let feet_at = |k: usize| {
        let mut pose = character.rig.rest_pose();
        clip.sample_looped(k as f32 * dt, &mut pose);
        let world = character.rig.world(&pose, Mat4::IDENTITY);
        let from = origin.map_or(Vec3::ZERO, |o| {
            let at = world[o].w_axis;
            Vec3::new(at.x, 0.0, at.z)
        });
        feet.iter()
            .map(|&f| world[f].w_axis.truncate() - from)
            .collect::<Vec<Vec3>>()
    };
    let planted = |f: &[Vec3]| {
        (0..f.len())
            .min_by(|&a, &b| f[a].y.total_cmp(&f[b].y))
            .expect("feet")
    };
    let mut speeds = Vec::new();
    let mut previous = feet_at(0);
    for k in 1..=samples {
        let current = feet_at(k);
        let foot = planted(&current);
        if planted(&previous) == foot {
            speeds.push(measure(current[foot] - previous[foot]) / dt);
        }
        previous = current;
    }
    if speeds.is_empty() {
        return 0.0;
    }
    speeds.sort_by(f32::total_cmp);
    speeds[speeds.len() / 2]
}
