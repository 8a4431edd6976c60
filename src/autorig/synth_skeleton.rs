//! The skeletons of synthetic characters: a humanoid (also chibi or long-limbed, arms
//! out or against the body, with skirts, coat tails, capes and hair on spring chains), a
//! quadruped or a winged, tailed creature, with random proportions and a random pose,
//! and the limbs and sheets their surface grows from.

use glam::{Quat, Vec3};

use super::skeleton::{BODY, Class, FINGERS, Skeleton};
use super::synth_mesh::{Limb, Sheet};
use crate::random::Rng;

/// Skeleton under construction plus the limbs grown around it.
pub(super) struct Builder {
    pub(super) skeleton: Skeleton,
    pub(super) limbs: Vec<Limb>,
    pub(super) sheets: Vec<Sheet>,
}

impl Builder {
    pub(super) fn new(class: Class) -> Self {
        Self {
            skeleton: Skeleton {
                class,
                joints: Vec::new(),
                parents: Vec::new(),
                names: Vec::new(),
                spring: Vec::new(),
            },
            limbs: Vec::new(),
            sheets: Vec::new(),
        }
    }

    pub(super) fn joint(
        &mut self,
        name: &str,
        parent: Option<usize>,
        at: Vec3,
        spring: bool,
    ) -> usize {
        let s = &mut self.skeleton;
        s.joints.push(at);
        s.parents.push(parent);
        s.names.push(name.to_string());
        s.spring.push(spring);
        s.joints.len() - 1
    }

    /// A chain of `count` joints from `parent` along `step` (each joint one step on), with
    /// a limb around each segment tapering from `r0` to `r1`.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn chain(
        &mut self,
        name: &str,
        parent: usize,
        start: Vec3,
        step: Vec3,
        count: usize,
        (r0, r1): (f32, f32),
        spring: bool,
        droop: Vec3,
    ) -> Vec<usize> {
        let mut out = Vec::new();
        let mut at = start;
        let mut previous = self.joint(&format!("{name}0"), Some(parent), at, spring);
        out.push(previous);
        let mut dir = step;
        for k in 1..=count.saturating_sub(1) {
            dir = (dir + droop).normalize() * step.length();
            let next = at + dir;
            let r = r0 + (r1 - r0) * k as f32 / count as f32;
            let joint = self.joint(&format!("{name}{k}"), Some(previous), next, spring);
            self.limb(at, next, r, r * 0.9, previous);
            at = next;
            previous = joint;
            out.push(joint);
        }
        // The last joint's own limb runs on by half a step.
        self.limb(at, at + 0.5 * dir, r1, r1 * 0.7, previous);
        out
    }

    /// A spring chain like [`Builder::chain`] that grows no limbs: a sheet hangs on it.
    pub(super) fn bare_chain(
        &mut self,
        name: &str,
        parent: usize,
        start: Vec3,
        step: Vec3,
        count: usize,
    ) -> Vec<usize> {
        let limbs = self.limbs.len();
        let out = self.chain(
            name,
            parent,
            start,
            step,
            count,
            (0.0, 0.0),
            true,
            Vec3::ZERO,
        );
        self.limbs.truncate(limbs);
        out
    }

    pub(super) fn limb(&mut self, a: Vec3, b: Vec3, ra: f32, rb: f32, joint: usize) {
        self.limbs.push(Limb {
            a,
            b,
            ra,
            rb,
            joint,
        });
    }

    /// A limb from joint `j` to its child `c`, owned by `j`.
    pub(super) fn bone(&mut self, j: usize, c: usize, ra: f32, rb: f32) {
        let (a, b) = (self.skeleton.joints[j], self.skeleton.joints[c]);
        self.limb(a, b, ra, rb, j);
    }
}

/// Scales a nominal value by a random factor in [1 − spread, 1 + spread].
pub(super) fn jitter(rng: &mut Rng, value: f32, spread: f32) -> f32 {
    value * rng.range(1.0 - spread, 1.0 + spread)
}

/// Humanoid proportions beyond the jitter: adult-like, chibi (a head two to three times
/// as large over short limbs) or long-limbed.
#[derive(Clone, Copy, PartialEq, Debug)]
pub(super) enum Build {
    Plain,
    Chibi,
    Long,
}

/// Where a humanoid's variety comes from: a random stream, or none (the plain generator
/// the shipped models were trained on: adult build, arms held out, capsule loose parts,
/// no capes).
pub(super) struct Style(pub(super) Option<Rng>);

impl Style {
    pub(super) fn chance(&mut self, p: f32) -> bool {
        self.0.as_mut().is_some_and(|r| r.chance(p))
    }

    /// A number below `n`; `n - 1` for the plain generator.
    pub(super) fn below(&mut self, n: usize) -> usize {
        self.0.as_mut().map_or(n - 1, |r| r.below(n))
    }

    /// A number in [lo, hi); `lo` for the plain generator.
    pub(super) fn range(&mut self, lo: f32, hi: f32) -> f32 {
        self.0.as_mut().map_or(lo, |r| r.range(lo, hi))
    }
}

/// A humanoid. `rng` draws what every humanoid has (as it did before the builds, arms at
/// the sides and sheets were added, so older seeds keep their skeletons); `style` draws
/// the build, the arms' rest and whether loose parts are sheets.
pub(super) fn humanoid(rng: &mut Rng, style: &mut Style) -> Builder {
    let mut b = Builder::new(Class::Humanoid);
    let build = match style.below(20) {
        0..=2 => Build::Chibi,
        3..=5 => Build::Long,
        _ => Build::Plain,
    };
    let (head_scale, leg_scale, arm_scale) = match build {
        Build::Plain => (1.0, 1.0, 1.0),
        Build::Chibi => (style.range(2.0, 2.8), 0.6, 0.6),
        Build::Long => (1.0, 1.15, 1.25),
    };
    let arms_at_sides = style.chance(0.35);
    let h = rng.range(1.2, 2.1);
    let leg = jitter(rng, 0.47, 0.12) * h * leg_scale;
    let hip_half = jitter(rng, 0.085, 0.3) * h;
    let thick = jitter(rng, 1.0, 0.35) * h;
    let hips_at = Vec3::new(0.0, leg + 0.04 * h, 0.0);
    let hips = b.joint("Hips", None, hips_at, false);
    let mut spine = vec![hips];
    let mut y = hips_at.y;
    for (name, frac) in [
        ("Abdomen", 0.06),
        ("Torso", 0.08),
        ("Chest", 0.08),
        ("Neck", 0.08),
        ("Head", 0.05),
    ] {
        y += jitter(rng, frac, 0.25) * h;
        let parent = *spine.last().unwrap();
        let j = b.joint(
            name,
            Some(parent),
            Vec3::new(0.0, y, jitter(rng, 0.0, 0.0)),
            false,
        );
        spine.push(j);
    }
    let torso_r = jitter(rng, 0.075, 0.35) * thick;
    for k in 0..3 {
        b.bone(
            spine[k],
            spine[k + 1],
            torso_r * (1.0 + 0.1 * k as f32),
            torso_r,
        );
    }
    b.bone(spine[3], spine[4], torso_r * 1.05, 0.035 * thick);
    b.bone(spine[4], spine[5], 0.03 * thick, 0.035 * thick);
    let head_r = jitter(rng, 0.075, 0.45) * h * head_scale;
    let head = spine[5];
    let head_at = b.skeleton.joints[head];
    b.limb(
        head_at,
        head_at + Vec3::Y * 1.2 * head_r,
        head_r * 0.8,
        head_r,
        head,
    );
    let chest = spine[3];
    let chest_at = b.skeleton.joints[chest];
    let droop = rng.range(0.0, 80f32.to_radians());
    // Arms at the sides hang nearly straight down, their inner surface against the torso.
    let droop = if arms_at_sides {
        style.range(82f32.to_radians(), 88f32.to_radians())
    } else {
        droop
    };
    let upper = jitter(rng, 0.17, 0.15) * h * arm_scale;
    let lower = jitter(rng, 0.16, 0.15) * h * arm_scale;
    let arm_r = jitter(rng, 0.03, 0.35) * thick;
    let hands = rng.chance(0.5);
    for (side, sx) in [("L", 1.0f32), ("R", -1.0f32)] {
        let shoulder_at = chest_at + Vec3::new(sx * 0.03 * h, 0.02 * h, 0.0);
        let shoulder = b.joint(&format!("Shoulder.{side}"), Some(chest), shoulder_at, false);
        let dir = Vec3::new(sx * droop.cos(), -droop.sin(), 0.0);
        let out = jitter(rng, 0.07, 0.3) * h;
        let out = if arms_at_sides {
            (torso_r * 1.2 + arm_r * 1.2 - 0.03 * h).max(0.01 * h)
        } else {
            out
        };
        let upper_at = shoulder_at + Vec3::new(sx * out, 0.0, 0.0);
        let upper_arm = b.joint(&format!("UpperArm.{side}"), Some(shoulder), upper_at, false);
        let lower_at = upper_at + dir * upper;
        let lower_arm = b.joint(
            &format!("LowerArm.{side}"),
            Some(upper_arm),
            lower_at,
            false,
        );
        let wrist_at = lower_at + dir * lower;
        let wrist = b.joint(&format!("Wrist.{side}"), Some(lower_arm), wrist_at, false);
        b.bone(shoulder, upper_arm, torso_r * 0.6, arm_r * 1.2);
        b.bone(upper_arm, lower_arm, arm_r * 1.2, arm_r);
        b.bone(lower_arm, wrist, arm_r, arm_r * 0.8);
        let palm = 0.06 * h;
        if hands {
            let side_dir = Vec3::new(0.0, 0.0, 1.0);
            for (f, (stem, count)) in FINGERS.iter().enumerate() {
                let spread = (f as f32 - 2.0) * 0.012 * h;
                let base = wrist_at + dir * 0.015 * h + side_dir * spread;
                let (start, step) = if *stem == "Thumb" {
                    (base, (dir * 0.5 + side_dir * 0.8).normalize() * 0.025 * h)
                } else {
                    (base, dir * 0.025 * h)
                };
                let mut previous = wrist;
                let mut at = start;
                for k in 1..=*count {
                    let j = b.joint(&format!("{stem}{k}.{side}"), Some(previous), at, false);
                    let length = if k == 1 && *stem != "Thumb" {
                        palm
                    } else {
                        step.length()
                    };
                    let next = at + step.normalize() * length;
                    b.limb(at, next, 0.008 * thick, 0.007 * thick, j);
                    previous = j;
                    at = next;
                }
            }
            b.limb(
                wrist_at,
                wrist_at + dir * 0.05 * h,
                arm_r * 0.8,
                arm_r * 0.9,
                wrist,
            );
        } else {
            b.limb(
                wrist_at,
                wrist_at + dir * 0.09 * h,
                arm_r * 0.8,
                arm_r * 1.1,
                wrist,
            );
        }
    }
    let leg_r = jitter(rng, 0.05, 0.35) * thick;
    for (side, sx) in [("L", 1.0f32), ("R", -1.0f32)] {
        let upper_at = hips_at + Vec3::new(sx * hip_half, -0.03 * h, 0.0);
        let upper_leg = b.joint(&format!("UpperLeg.{side}"), Some(hips), upper_at, false);
        let knee = upper_at - Vec3::Y * 0.52 * leg;
        let lower_leg = b.joint(&format!("LowerLeg.{side}"), Some(upper_leg), knee, false);
        let ankle = Vec3::new(knee.x, 0.05 * h, knee.z);
        let foot = b.joint(&format!("Foot.{side}"), Some(lower_leg), ankle, false);
        b.limb(hips_at, upper_at, torso_r, leg_r * 1.1, hips);
        b.bone(upper_leg, lower_leg, leg_r * 1.1, leg_r * 0.8);
        b.bone(lower_leg, foot, leg_r * 0.8, leg_r * 0.6);
        b.limb(
            ankle,
            ankle + Vec3::new(0.0, -0.03 * h, 0.12 * h),
            leg_r * 0.6,
            leg_r * 0.5,
            foot,
        );
    }
    // Loose parts on spring chains.
    // Hair: strands (capsules thinner than a voxel) or, mostly, cards (open ribbons).
    if rng.chance(0.5) {
        let chains = 1 + rng.below(5);
        let cards = style.chance(0.8);
        let width = style.range(0.03, 0.06) * h;
        for c in 0..chains {
            let angle = std::f32::consts::PI * (c as f32 + 0.5) / chains as f32;
            let start = head_at + Vec3::new(angle.cos() * head_r * 0.8, head_r, -0.6 * head_r);
            let step = Vec3::new(0.0, -1.0, -0.3).normalize() * jitter(rng, 0.07, 0.4) * h;
            let r = 0.012 * h;
            let count = 2 + rng.below(3);
            let name = format!("Hair{c}_");
            if cards {
                let chain = b.bare_chain(&name, head, start, step, count);
                b.sheets.push(Sheet {
                    chains: vec![chain],
                    closed: false,
                    width,
                    around: head,
                    vertical: false,
                });
            } else {
                b.chain(
                    &name,
                    head,
                    start,
                    step,
                    count,
                    (r, r * 0.6),
                    true,
                    Vec3::ZERO,
                );
            }
        }
    }
    // A skirt: a ring of chains, as capsules or, mostly, as one sheet; some sheets are
    // coat tails, the back half of the ring.
    if rng.chance(0.4) {
        let chains = 4 + rng.below(5);
        let flare = rng.range(0.2, 0.8);
        let length = jitter(rng, 0.15, 0.4) * h;
        let sheet = style.chance(0.75);
        let coat = sheet && style.chance(0.35);
        let mut ring = Vec::new();
        for c in 0..chains {
            let angle = if coat {
                std::f32::consts::FRAC_PI_2 + std::f32::consts::PI * c as f32 / (chains - 1) as f32
            } else {
                std::f32::consts::TAU * c as f32 / chains as f32
            };
            let out = Vec3::new(angle.sin(), 0.0, angle.cos());
            let step = (Vec3::NEG_Y + out * flare).normalize() * length * 0.5;
            let count = 2 + rng.below(2);
            let name = format!("Skirt{c}_");
            if sheet {
                // Around the hips, outside the legs and the torso.
                let radius = (hip_half + leg_r).max(torso_r * 1.2) * 1.05;
                ring.push(b.bare_chain(&name, hips, hips_at + out * radius, step, count));
            } else {
                let start = hips_at + out * (hip_half + leg_r);
                let r = 0.03 * h;
                b.chain(&name, hips, start, step, count, (r, r), true, Vec3::ZERO);
            }
        }
        if sheet {
            b.sheets.push(Sheet {
                chains: ring,
                closed: !coat,
                width: 0.0,
                around: hips,
                vertical: true,
            });
        }
    }
    // A cape: a strip of chains down the back from the chest.
    if style.chance(0.15) {
        let chains = 3 + style.below(3);
        let length = style.range(0.3, 0.55) * h;
        let count = 3 + style.below(2);
        let half = torso_r * 1.2;
        let mut strip = Vec::new();
        for c in 0..chains {
            let x = half * (2.0 * c as f32 / (chains - 1) as f32 - 1.0);
            let start = chest_at + Vec3::new(x, 0.02 * h, -(torso_r * 1.2 + 0.01 * h));
            let step = Vec3::new(0.0, -1.0, -0.15).normalize() * length / count as f32;
            strip.push(b.bare_chain(&format!("Cape{c}_"), chest, start, step, count));
        }
        b.sheets.push(Sheet {
            chains: strip,
            closed: false,
            width: 0.0,
            around: chest,
            vertical: true,
        });
    }
    if rng.chance(0.25) {
        let start = head_at + Vec3::Y * 1.8 * head_r;
        let step = Vec3::new(0.0, 1.0, -0.3).normalize() * 0.08 * h;
        b.chain(
            "Hat",
            head,
            start,
            step,
            2 + rng.below(2),
            (head_r * 0.5, 0.01 * h),
            true,
            Vec3::new(0.0, -0.2, -0.2),
        );
    }
    if rng.chance(0.2) {
        add_tail(rng, &mut b, hips, h);
    }
    b
}

pub(super) fn add_tail(rng: &mut Rng, b: &mut Builder, from: usize, h: f32) {
    let start = b.skeleton.joints[from] + Vec3::new(0.0, -0.02 * h, -0.08 * h);
    let step = Vec3::new(0.0, rng.range(-0.5, 0.3), -1.0).normalize() * jitter(rng, 0.08, 0.3) * h;
    let r = 0.03 * h;
    b.chain(
        "Tail",
        from,
        start,
        step,
        3 + rng.below(4),
        (r, r * 0.3),
        true,
        Vec3::new(0.0, -0.1, 0.0),
    );
}

pub(super) fn quadruped(rng: &mut Rng) -> Builder {
    let mut b = Builder::new(Class::Quadruped);
    let length = rng.range(0.8, 1.8);
    let leg = jitter(rng, 0.45, 0.3) * length;
    let body_r = jitter(rng, 0.12, 0.35) * length;
    let hips_at = Vec3::new(0.0, leg + body_r * 0.5, -0.3 * length);
    let hips = b.joint("Hips", None, hips_at, false);
    let mut spine = vec![hips];
    for k in 1..=3 {
        let at = hips_at + Vec3::new(0.0, 0.02 * k as f32 * length, 0.2 * k as f32 * length);
        let j = b.joint(&format!("Spine{k}"), Some(spine[k - 1]), at, false);
        b.bone(spine[k - 1], j, body_r, body_r * 1.05);
        spine.push(j);
    }
    let chest = spine[3];
    let neck = b.chain(
        "Neck",
        chest,
        b.skeleton.joints[chest] + Vec3::new(0.0, 0.08, 0.08) * length,
        Vec3::new(0.0, 0.6, 0.8).normalize() * 0.15 * length,
        2,
        (body_r * 0.5, body_r * 0.4),
        false,
        Vec3::ZERO,
    );
    let head_at = b.skeleton.joints[*neck.last().unwrap()];
    let head = b.joint(
        "Head",
        neck.last().copied(),
        head_at + Vec3::new(0.0, 0.02, 0.08) * length,
        false,
    );
    let head_r = jitter(rng, 0.08, 0.3) * length;
    let hp = b.skeleton.joints[head];
    b.limb(
        hp,
        hp + Vec3::new(0.0, -0.03, 0.15) * length,
        head_r,
        head_r * 0.6,
        head,
    );
    let leg_r = jitter(rng, 0.035, 0.3) * length;
    for (at_joint, tag) in [(hips, "Back"), (chest, "Front")] {
        for (side, sx) in [("L", 1.0f32), ("R", -1.0f32)] {
            let top =
                b.skeleton.joints[at_joint] + Vec3::new(sx * body_r * 0.7, -body_r * 0.3, 0.0);
            let step = Vec3::new(0.0, -leg / 3.0, if tag == "Back" { -0.02 } else { 0.02 });
            b.chain(
                &format!("{tag}Leg{side}"),
                at_joint,
                top,
                step,
                4,
                (leg_r, leg_r * 0.8),
                false,
                Vec3::ZERO,
            );
        }
    }
    if rng.chance(0.7) {
        add_tail(rng, &mut b, hips, length);
    }
    b
}

/// A winged or many-limbed creature: an upright trunk with symmetric limbs.
pub(super) fn creature(rng: &mut Rng) -> Builder {
    let mut b = Builder::new(Class::Other);
    let h = rng.range(0.8, 2.0);
    let trunk_r = jitter(rng, 0.1, 0.35) * h;
    let root = b.joint("Root", None, Vec3::new(0.0, 0.45 * h, 0.0), false);
    let trunk = {
        let at = b.skeleton.joints[root];
        let mut out = vec![root];
        out.extend(b.chain(
            "Trunk",
            root,
            at + Vec3::Y * 0.12 * h,
            Vec3::Y * 0.12 * h,
            3,
            (trunk_r, trunk_r * 0.8),
            false,
            Vec3::ZERO,
        ));
        b.bone(root, out[1], trunk_r, trunk_r);
        out
    };
    let pairs = 1 + rng.below(3);
    for p in 0..pairs {
        let at = trunk[rng.below(trunk.len())];
        let base = b.skeleton.joints[at];
        let dir = Vec3::new(1.0, rng.range(-1.0, 0.6), rng.range(-0.4, 0.4)).normalize();
        let segments = 2 + rng.below(3);
        let step_len = jitter(rng, 0.13, 0.4) * h;
        let wing = rng.chance(0.3);
        let r = if wing {
            0.02 * h
        } else {
            jitter(rng, 0.03, 0.3) * h
        };
        for (side, sx) in [("L", 1.0f32), ("R", -1.0f32)] {
            let d = Vec3::new(dir.x * sx, dir.y, dir.z);
            let start = base + d * trunk_r;
            b.chain(
                &format!("Limb{p}{side}"),
                at,
                start,
                d * step_len,
                segments,
                (r, r * 0.7),
                wing,
                Vec3::new(0.0, -0.05, 0.0),
            );
        }
    }
    // Legs to stand on.
    for (side, sx) in [("L", 1.0f32), ("R", -1.0f32)] {
        let start = b.skeleton.joints[root] + Vec3::new(sx * trunk_r * 0.6, -0.05 * h, 0.0);
        b.chain(
            &format!("Leg{side}"),
            root,
            start,
            Vec3::NEG_Y * 0.13 * h,
            3,
            (0.04 * h, 0.03 * h),
            false,
            Vec3::ZERO,
        );
    }
    if rng.chance(0.5) {
        add_tail(rng, &mut b, root, h);
    }
    b
}

/// Turns each joint's subtree by a random angle around a random axis (larger for limbs
/// and loose parts, small for the spine), limbs included.
pub(super) fn random_pose(rng: &mut Rng, b: &mut Builder, amount: f32) {
    let s = &b.skeleton;
    let n = s.len();
    let mut descendants: Vec<Vec<usize>> = vec![Vec::new(); n];
    for j in (0..n).rev() {
        if let Some(p) = s.parents[j] {
            let mut below = descendants[j].clone();
            below.push(j);
            descendants[p].extend(below);
        }
    }
    for (j, moved) in descendants.iter().enumerate() {
        let name = &b.skeleton.names[j];
        let limit = if b.skeleton.spring[j] {
            25.0
        } else if name.contains("Arm") || name.contains("Limb") || name.contains("Leg") {
            35.0
        } else if BODY.iter().any(|(t, _)| t == name)
            || name.contains("Spine")
            || name.contains("Trunk")
        {
            8.0
        } else {
            10.0
        };
        let axis = Vec3::new(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        )
        .normalize_or(Vec3::X);
        let turn =
            Quat::from_axis_angle(axis, (limit * amount * rng.range(-1.0, 1.0)).to_radians());
        let pivot = b.skeleton.joints[j];
        for &d in moved {
            b.skeleton.joints[d] = pivot + turn * (b.skeleton.joints[d] - pivot);
        }
        for limb in b
            .limbs
            .iter_mut()
            .filter(|l| l.joint == j || moved.contains(&l.joint))
        {
            limb.a = pivot + turn * (limb.a - pivot);
            limb.b = pivot + turn * (limb.b - pivot);
        }
    }
}
