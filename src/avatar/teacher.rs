//! The teacher: a character driven by actions through the locomotion controller, its
//! clips blended by speed, spring bones for loose parts, and skinning — one deterministic
//! frame per step at [`FRAME_RATE`]. The ground truth the neural avatar learns from.

use glam::{Mat4, Vec3};

use super::character::{Character, CharacterError, fail, node_names};
use super::clip::Clip;
use super::description::{Description, REST_CLIP};
use super::gait::planted_speed;
use super::locomotion::{FRAME_RATE, GaitParams, Locomotion};
use super::loose::add_spring_chains;
use super::rig::Transform;
use super::springs::SpringSystem;
use crate::action::Action;
use crate::mesh::Mesh;

/// Run speed over walk speed when one clip serves both gaits.
pub const RUN_FROM_WALK: f32 = 1.8;

#[derive(Clone)]
pub struct Teacher {
    pub character: Character,
    pub description: Description,
    /// Indices of the idle, walk and run clips.
    clips: [usize; 3],
    forward_heading: f32,
    pub locomotion: Locomotion,
    pub springs: SpringSystem,
    waist: Vec<usize>,
    world: Vec<Mat4>,
    pub frame: u64,
}

impl Teacher {
    pub fn new(mut character: Character, description: Description) -> Result<Self, CharacterError> {
        let springs = add_spring_chains(&mut character, &description)?;
        if description.clips.idle == REST_CLIP && character.clip(REST_CLIP).is_err() {
            character.clips.push(Clip {
                name: REST_CLIP.into(),
                duration: 1.0,
                channels: Vec::new(),
            });
        }
        let clip_index = |name: &str| {
            character.clip(name)?;
            Ok::<_, CharacterError>(
                character
                    .clips
                    .iter()
                    .position(|c| c.name == name)
                    .expect("found"),
            )
        };
        let clips = [
            clip_index(&description.clips.idle)?,
            clip_index(&description.clips.walk)?,
            clip_index(&description.clips.run)?,
        ];
        let node = |name: &String| {
            character.rig.find(name).ok_or_else(|| {
                fail(
                    &character.path,
                    format!(
                        "bone '{name}' (from the avatar description) not found; the rig's nodes: {}",
                        node_names(&character.rig, 80)
                    ),
                )
            })
        };
        let waist: Vec<usize> = description
            .waist_bones
            .iter()
            .map(node)
            .collect::<Result<_, _>>()?;
        let feet: Vec<usize> = description
            .feet
            .iter()
            .map(node)
            .collect::<Result<_, _>>()?;
        if waist.is_empty() || feet.is_empty() {
            return Err(fail(
                &character.path,
                "the avatar description names no waist or no feet bones",
            ));
        }
        let forward_heading = description.forward_heading();
        let forward = Vec3::new(forward_heading.sin(), 0.0, forward_heading.cos());
        let [_, walk, run] = clips.map(|i| &character.clips[i]);
        let walk_speed = description
            .walk_speed
            .unwrap_or_else(|| ground_speed(&character, walk, &feet, forward));
        // One clip for both gaits: the run plays the walk faster, its stride kept.
        let same = clips[1] == clips[2];
        let run_speed = description.run_speed.unwrap_or_else(|| {
            if same {
                walk_speed * RUN_FROM_WALK
            } else {
                ground_speed(&character, run, &feet, forward)
            }
        });
        if !(walk_speed > 0.0 && run_speed > walk_speed) {
            return Err(fail(
                &character.path,
                format!(
                    "walk speed {walk_speed:.2} m/s and run speed {run_speed:.2} m/s (measured from the feet) \
                     must satisfy 0 < walk < run; set walk_speed/run_speed in the avatar description"
                ),
            ));
        }
        let run_cycle = if same {
            walk.duration * walk_speed / run_speed
        } else {
            run.duration
        };
        let params = GaitParams::new(walk_speed, run_speed, walk.duration, run_cycle);
        let mut teacher = Self {
            world: Vec::new(),
            character,
            description,
            clips,
            forward_heading,
            locomotion: Locomotion::new(params),
            springs,
            waist,
            frame: 0,
        };
        let mut local = teacher.animate();
        let rig = &teacher.character.rig;
        teacher.springs.reset(rig, &mut local, &mut teacher.world);
        Ok(teacher)
    }

    /// The world matrices of the rig's nodes after the last step.
    pub fn world(&self) -> &[Mat4] {
        &self.world
    }

    /// Advances one frame (1 / [`FRAME_RATE`] s) under `action`.
    pub fn step(&mut self, action: Action) {
        self.locomotion.step(action, 1.0 / FRAME_RATE);
        let mut local = self.animate();
        let rig = &self.character.rig;
        self.springs
            .advance(rig, &mut local, &mut self.world, 1.0 / FRAME_RATE);
        self.frame += 1;
    }

    /// Blends the clips for the current locomotion state into world matrices (spring
    /// joints at rest) and returns the local pose.
    fn animate(&mut self) -> Vec<Transform> {
        let rig = &self.character.rig;
        let sample = |clip: &Clip, t: f32| {
            let mut pose = rig.rest_pose();
            clip.sample_looped(t, &mut pose);
            pose
        };
        let loco = &self.locomotion;
        let [idle, walk, run] = self.clips.map(|i| &self.character.clips[i]);
        let blend = loco.blend();
        let moving = sample(walk, loco.phase * walk.duration);
        let running = sample(run, loco.phase * run.duration);
        let still = sample(idle, loco.idle_time);
        let gait_share = blend.run / (blend.walk + blend.run).max(1e-6);
        let local: Vec<Transform> = still
            .iter()
            .zip(moving.iter().zip(&running))
            .map(|(i, (w, r))| i.blend(&w.blend(r, gait_share), 1.0 - blend.idle))
            .collect();
        self.world = rig.world(&local, self.locomotion.root_matrix(self.forward_heading));
        local
    }

    /// The skinning matrices of the current frame (world × inverse bind, every bone).
    pub fn skin_matrices(&self) -> Vec<Mat4> {
        self.character.rig.skin_matrices(&self.world)
    }

    /// The posed mesh in world space.
    pub fn mesh(&self) -> Mesh {
        self.character
            .skinned
            .pose(&self.character.rig.skin_matrices(&self.world))
    }

    /// The rig nodes of the waist bones.
    pub fn waist_nodes(&self) -> &[usize] {
        &self.waist
    }

    /// World position of the root: the mean of the waist bones.
    pub fn root(&self) -> Vec3 {
        self.waist
            .iter()
            .map(|&n| self.world[n].w_axis.truncate())
            .sum::<Vec3>()
            / self.waist.len() as f32
    }
}

/// A clip's ground speed: how fast the planted (lowest) foot slides backward along
/// `forward` while the clip plays in place; the median over the cycle.
pub fn ground_speed(character: &Character, clip: &Clip, feet: &[usize], forward: Vec3) -> f32 {
    const SAMPLES: usize = 120;
    let dt = clip.duration / SAMPLES as f32;
    planted_speed(character, clip, feet, None, SAMPLES, dt, |step| {
        -step.dot(forward)
    })
}
