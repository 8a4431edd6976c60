//! The locomotion controller — the motion planning the neural model replaces: actions to
//! a world root path with acceleration, braking and bounded turning, and the idle/walk/run
//! blend whose gait phase advances with distance travelled (so feet do not skate).
//!
//! Convention (fixed world directions, y up): W moves toward +Z, S toward -Z, A toward
//! +X, D toward -X. A standing start faces +Z, so W runs straight ahead and, seen from
//! behind (camera at -Z), A goes left and D right on screen.

use std::f32::consts::PI;

use glam::{Mat4, Quat, Vec3};

use crate::action::Action;

/// The teacher's fixed simulation rate: one frame per generated frame of the model.
pub const FRAME_RATE: f32 = 30.0;

/// The unit world direction an action moves toward, `None` for Idle.
pub fn action_direction(action: Action) -> Option<Vec3> {
    match action {
        Action::Idle => None,
        Action::Forward => Some(Vec3::Z),
        Action::Backward => Some(Vec3::NEG_Z),
        Action::Left => Some(Vec3::X),
        Action::Right => Some(Vec3::NEG_X),
    }
}

/// Heading (rotation about +Y) of a horizontal direction; 0 is +Z, PI/2 is +X.
pub fn heading(direction: Vec3) -> f32 {
    direction.x.atan2(direction.z)
}

/// The signed smallest angle from `from` to `to`, in (-PI, PI].
pub fn angle_difference(from: f32, to: f32) -> f32 {
    let d = (to - from).rem_euclid(2.0 * PI);
    if d > PI { d - 2.0 * PI } else { d }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaitParams {
    /// Ground speeds (m/s) at which the walk and run clips play without foot sliding.
    pub walk_speed: f32,
    pub run_speed: f32,
    /// Seconds per cycle of the walk and run clips.
    pub walk_cycle: f32,
    pub run_cycle: f32,
    /// m/s² when speeding up and when braking.
    pub acceleration: f32,
    pub deceleration: f32,
    /// Largest turning rate, rad/s.
    pub turn_rate: f32,
}

impl GaitParams {
    /// Dynamics for measured clip speeds: full run speed in 0.4 s, stop from a run in
    /// 0.3 s, a 180 degree turn in 12 frames.
    pub fn new(walk_speed: f32, run_speed: f32, walk_cycle: f32, run_cycle: f32) -> Self {
        Self {
            walk_speed,
            run_speed,
            walk_cycle,
            run_cycle,
            acceleration: run_speed / 0.4,
            deceleration: run_speed / 0.3,
            turn_rate: PI / (12.0 / FRAME_RATE),
        }
    }
}

/// Weights of the three clips; they sum to 1.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Blend {
    pub idle: f32,
    pub walk: f32,
    pub run: f32,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Locomotion {
    pub params: GaitParams,
    /// World position of the character's origin on the ground.
    pub position: Vec3,
    /// Facing heading (see [`heading`]).
    pub yaw: f32,
    pub speed: f32,
    /// Gait cycle phase in [0, 1), shared by walk and run.
    pub phase: f32,
    /// Seconds into the idle clip.
    pub idle_time: f32,
}

impl Locomotion {
    /// A standing start at the origin facing +Z.
    pub fn new(params: GaitParams) -> Self {
        Self {
            params,
            position: Vec3::ZERO,
            yaw: 0.0,
            speed: 0.0,
            phase: 0.0,
            idle_time: 0.0,
        }
    }

    pub fn facing(&self) -> Vec3 {
        Vec3::new(self.yaw.sin(), 0.0, self.yaw.cos())
    }

    /// Advances one step of `dt` seconds under `action`.
    pub fn step(&mut self, action: Action, dt: f32) {
        let p = self.params;
        let target_speed = match action_direction(action) {
            None => 0.0,
            Some(direction) => {
                let error = angle_difference(self.yaw, heading(direction));
                let turn = error.clamp(-p.turn_rate * dt, p.turn_rate * dt);
                self.yaw = (self.yaw + turn).rem_euclid(2.0 * PI);
                // Slow down while facing away from where the key points.
                let remaining = error - turn;
                p.run_speed * remaining.cos().max(0.0)
            }
        };
        self.speed = if target_speed > self.speed {
            (self.speed + p.acceleration * dt).min(target_speed)
        } else {
            (self.speed - p.deceleration * dt).max(target_speed)
        };
        let distance = self.speed * dt;
        self.position += self.facing() * distance;
        self.phase = (self.phase + distance / self.stride()).rem_euclid(1.0);
        self.idle_time += dt;
    }

    /// Metres per gait cycle at the current blend of walk and run.
    fn stride(&self) -> f32 {
        let p = self.params;
        let t = self.run_share();
        (1.0 - t) * p.walk_speed * p.walk_cycle + t * p.run_speed * p.run_cycle
    }

    fn run_share(&self) -> f32 {
        let p = self.params;
        ((self.speed - p.walk_speed) / (p.run_speed - p.walk_speed).max(1e-6)).clamp(0.0, 1.0)
    }

    pub fn blend(&self) -> Blend {
        let moving = (self.speed / self.params.walk_speed.max(1e-6)).clamp(0.0, 1.0);
        let run = self.run_share();
        Blend {
            idle: 1.0 - moving,
            walk: moving * (1.0 - run),
            run: moving * run,
        }
    }

    /// The world transform above the rig: position and facing, with the character's own
    /// forward axis (at heading `forward_heading` in its space) turned onto the facing.
    pub fn root_matrix(&self, forward_heading: f32) -> Mat4 {
        Mat4::from_rotation_translation(
            Quat::from_rotation_y(self.yaw - forward_heading),
            self.position,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> GaitParams {
        GaitParams::new(1.5, 4.0, 1.0, 0.7)
    }

    fn run(loco: &mut Locomotion, action: Action, frames: usize) {
        for _ in 0..frames {
            loco.step(action, 1.0 / FRAME_RATE);
        }
    }

    #[test]
    fn headings_and_differences() {
        assert_eq!(heading(Vec3::Z), 0.0);
        assert!((heading(Vec3::X) - PI / 2.0).abs() < 1e-6);
        assert!((angle_difference(0.1, 2.0 * PI - 0.1) + 0.2).abs() < 1e-6);
        assert!((angle_difference(0.0, PI) - PI).abs() < 1e-6);
    }

    #[test]
    fn forward_accelerates_to_run_speed_along_plus_z() {
        let mut loco = Locomotion::new(params());
        run(&mut loco, Action::Forward, 11);
        assert!(
            loco.speed < 3.9,
            "not yet at full speed after 11 frames: {}",
            loco.speed
        );
        run(&mut loco, Action::Forward, 1);
        assert!(
            (loco.speed - 4.0).abs() < 1e-5,
            "full speed after 0.4 s: {}",
            loco.speed
        );
        assert!(loco.position.x.abs() < 1e-6 && loco.position.z > 0.0);
        let z = loco.position.z;
        run(&mut loco, Action::Forward, 30);
        assert!(
            (loco.position.z - z - 4.0).abs() < 1e-3,
            "4 m in one second at full speed"
        );
        assert_eq!(
            loco.blend(),
            Blend {
                idle: 0.0,
                walk: 0.0,
                run: 1.0
            }
        );
    }

    #[test]
    fn idle_brakes_to_a_stop_and_blends_to_idle() {
        let mut loco = Locomotion::new(params());
        run(&mut loco, Action::Forward, 30);
        run(&mut loco, Action::Idle, 8);
        assert!(loco.speed > 0.0, "still moving after 8 frames");
        run(&mut loco, Action::Idle, 2);
        assert_eq!(loco.speed, 0.0, "stopped within 0.3 s (+ rounding)");
        let stopped = loco.position;
        run(&mut loco, Action::Idle, 10);
        assert_eq!(loco.position, stopped);
        assert_eq!(loco.blend().idle, 1.0);
    }

    #[test]
    fn turns_are_bounded_180_in_12_frames_and_90_in_6() {
        let mut loco = Locomotion::new(params());
        run(&mut loco, Action::Forward, 30);
        run(&mut loco, Action::Backward, 11);
        assert!(
            angle_difference(loco.yaw, PI).abs() > 0.1,
            "not turned round after 11 frames"
        );
        run(&mut loco, Action::Backward, 1);
        assert!(
            angle_difference(loco.yaw, PI).abs() < 1e-4,
            "turned round after 12 frames"
        );
        let mut loco = Locomotion::new(params());
        run(&mut loco, Action::Forward, 30);
        run(&mut loco, Action::Left, 6);
        assert!(angle_difference(loco.yaw, PI / 2.0).abs() < 1e-4);
    }

    #[test]
    fn the_phase_advances_one_cycle_per_stride() {
        let mut loco = Locomotion::new(params());
        run(&mut loco, Action::Forward, 30);
        loco.phase = 0.0;
        // At full run speed one cycle covers 4.0 m/s * 0.7 s = 2.8 m, i.e. 0.7 s.
        run(&mut loco, Action::Forward, 21);
        assert!(
            loco.phase < 1e-4 || loco.phase > 1.0 - 1e-4,
            "{}",
            loco.phase
        );
    }

    #[test]
    fn the_same_keys_give_the_same_path() {
        let keys = [
            Action::Forward,
            Action::Left,
            Action::Idle,
            Action::Right,
            Action::Backward,
        ];
        let path = || {
            let mut loco = Locomotion::new(params());
            keys.iter()
                .flat_map(|&a| (0..20).map(move |_| a))
                .map(|a| {
                    loco.step(a, 1.0 / FRAME_RATE);
                    loco.position
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(path(), path());
    }

    #[test]
    fn the_root_matrix_turns_the_character_forward_onto_the_facing() {
        let mut loco = Locomotion::new(params());
        loco.yaw = PI / 2.0;
        loco.position = Vec3::new(1.0, 0.0, 2.0);
        let m = loco.root_matrix(0.0);
        assert!(m.transform_vector3(Vec3::Z).abs_diff_eq(Vec3::X, 1e-6));
        assert!(
            m.transform_point3(Vec3::ZERO)
                .abs_diff_eq(loco.position, 1e-6)
        );
    }
}
