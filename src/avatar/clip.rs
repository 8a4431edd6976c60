//! Animation clips: keyframed translation/rotation/scale channels of rig nodes, sampled
//! with glTF's linear, step and cubic-spline interpolation.

use glam::{Quat, Vec3, Vec4};

use super::rig::Transform;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    Linear,
    Step,
    /// Hermite spline; values are stored as (in-tangent, value, out-tangent) triples.
    CubicSpline,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    Translation(Vec<Vec3>),
    /// Quaternions as (x, y, z, w).
    Rotation(Vec<Vec4>),
    Scale(Vec<Vec3>),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    pub node: usize,
    pub times: Vec<f32>,
    pub interpolation: Interpolation,
    pub values: Values,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    pub name: String,
    pub duration: f32,
    pub channels: Vec<Channel>,
}

impl Clip {
    /// Writes the clip's values at time `t` (clamped to the keyframes) into `pose`;
    /// nodes without channels keep what `pose` holds.
    pub fn sample(&self, t: f32, pose: &mut [Transform]) {
        for channel in &self.channels {
            let target = &mut pose[channel.node];
            match &channel.values {
                Values::Translation(v) => target.translation = channel.sample(v, t).truncate(),
                Values::Scale(v) => target.scale = channel.sample(v, t).truncate(),
                Values::Rotation(v) => {
                    target.rotation = Quat::from_vec4(channel.sample(v, t)).normalize()
                }
            }
        }
    }

    /// Samples a looping clip at any time (wrapped into the clip's duration).
    pub fn sample_looped(&self, t: f32, pose: &mut [Transform]) {
        let d = self.duration.max(1e-6);
        self.sample(t.rem_euclid(d), pose);
    }
}

/// Keyframe values as 4-vectors so one interpolation serves every path.
trait Key: Copy {
    fn to4(self) -> Vec4;
}

impl Key for Vec3 {
    fn to4(self) -> Vec4 {
        self.extend(0.0)
    }
}

impl Key for Vec4 {
    fn to4(self) -> Vec4 {
        self
    }
}

impl Channel {
    fn sample<K: Key>(&self, values: &[K], t: f32) -> Vec4 {
        let cubic = self.interpolation == Interpolation::CubicSpline;
        let value = |k: usize| if cubic { values[3 * k + 1] } else { values[k] }.to4();
        let n = self.times.len();
        if n == 1 || t.is_nan() || t <= self.times[0] {
            return value(0);
        }
        if t >= self.times[n - 1] {
            return value(n - 1);
        }
        let k = self.times.partition_point(|&x| x <= t) - 1;
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let s = if dt > 0.0 { (t - t0) / dt } else { 0.0 };
        match self.interpolation {
            Interpolation::Step => value(k),
            Interpolation::Linear => match self.values {
                Values::Rotation(_) => {
                    let (a, b) = (Quat::from_vec4(value(k)), Quat::from_vec4(value(k + 1)));
                    Vec4::from(a.slerp(b, s))
                }
                _ => value(k).lerp(value(k + 1), s),
            },
            Interpolation::CubicSpline => {
                let out_tangent = values[3 * k + 2].to4() * dt;
                let in_tangent = values[3 * (k + 1)].to4() * dt;
                let (s2, s3) = (s * s, s * s * s);
                value(k) * (2.0 * s3 - 3.0 * s2 + 1.0)
                    + out_tangent * (s3 - 2.0 * s2 + s)
                    + value(k + 1) * (-2.0 * s3 + 3.0 * s2)
                    + in_tangent * (s3 - s2)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clip(interpolation: Interpolation, values: Values, times: Vec<f32>) -> Clip {
        Clip {
            name: "c".into(),
            duration: *times.last().unwrap(),
            channels: vec![Channel {
                node: 0,
                times,
                interpolation,
                values,
            }],
        }
    }

    fn translation_at(clip: &Clip, t: f32) -> Vec3 {
        let mut pose = [Transform::default()];
        clip.sample(t, &mut pose);
        pose[0].translation
    }

    #[test]
    fn linear_step_and_clamping() {
        let values = Values::Translation(vec![
            Vec3::ZERO,
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 4.0, 0.0),
        ]);
        let linear = clip(Interpolation::Linear, values.clone(), vec![0.0, 1.0, 2.0]);
        assert_eq!(translation_at(&linear, 0.25), Vec3::new(0.5, 0.0, 0.0));
        assert_eq!(translation_at(&linear, 1.5), Vec3::new(2.0, 2.0, 0.0));
        assert_eq!(translation_at(&linear, -1.0), Vec3::ZERO);
        assert_eq!(translation_at(&linear, 9.0), Vec3::new(2.0, 4.0, 0.0));
        let step = clip(Interpolation::Step, values, vec![0.0, 1.0, 2.0]);
        assert_eq!(translation_at(&step, 0.99), Vec3::ZERO);
        assert_eq!(translation_at(&step, 1.0), Vec3::new(2.0, 0.0, 0.0));
    }

    #[test]
    fn cubic_spline_with_zero_tangents_is_smoothstep() {
        let z = Vec3::ZERO;
        let values = Values::Translation(vec![z, z, z, z, Vec3::X, z]);
        let c = clip(Interpolation::CubicSpline, values, vec![0.0, 2.0]);
        // s = 0.25: 3s^2 - 2s^3 = 0.15625
        assert!((translation_at(&c, 0.5).x - 0.15625).abs() < 1e-6);
        assert_eq!(translation_at(&c, 2.0), Vec3::X);
    }

    #[test]
    fn cubic_spline_follows_a_straight_line_with_matching_tangents() {
        // x(t) = t with tangent 1 at both keys: the Hermite curve is exactly linear.
        let values = Values::Translation(vec![
            Vec3::X,
            Vec3::ZERO,
            Vec3::X,
            Vec3::X,
            Vec3::new(3.0, 0.0, 0.0),
            Vec3::X,
        ]);
        let c = clip(Interpolation::CubicSpline, values, vec![0.0, 3.0]);
        for t in [0.3f32, 1.0, 2.2] {
            assert!((translation_at(&c, t).x - t).abs() < 1e-5, "{t}");
        }
    }

    #[test]
    fn rotations_slerp_and_stay_unit() {
        let a = Vec4::from(Quat::IDENTITY);
        let b = Vec4::from(Quat::from_rotation_y(2.0));
        let c = clip(
            Interpolation::Linear,
            Values::Rotation(vec![a, b]),
            vec![0.0, 1.0],
        );
        let mut pose = [Transform::default()];
        c.sample(0.25, &mut pose);
        assert!(
            pose[0]
                .rotation
                .abs_diff_eq(Quat::from_rotation_y(0.5), 1e-6)
        );
        c.sample_looped(1.25, &mut pose);
        assert!(
            pose[0]
                .rotation
                .abs_diff_eq(Quat::from_rotation_y(0.5), 1e-6)
        );
    }
}
