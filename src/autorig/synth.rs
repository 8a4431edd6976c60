//! Synthetic training characters: a random skeleton tree from a humanoid, quadruped or
//! winged/tailed creature pattern with random proportions (humanoids also chibi or
//! long-limbed, arms held out or resting against the body), posed at random, a surface
//! grown around its bones (smooth union of tapered capsules, meshed by surface nets),
//! open sheets hung on spring chains (skirts, coat tails, capes, hair cards), and
//! ground-truth skin weights (each vertex to the bone that grew it, blended linearly with
//! the neighbouring joints near each end, as artists paint; a sheet's vertices blended
//! between the chains on either side).

use glam::{Quat, Vec3};

use super::skeleton::{BODY, Class, FINGERS, Skeleton};
use crate::mesh::Mesh;
use crate::random::Rng;

/// A synthetic character: its skeleton (world units), mesh and skin weights per vertex
/// as (joint, weight) pairs.
pub struct Synthetic {
    pub skeleton: Skeleton,
    pub mesh: Mesh,
    pub skin: Vec<Vec<(usize, f32)>>,
    /// The first `body_vertices` vertices are the closed body; the rest are open sheets.
    pub body_vertices: usize,
}

/// An open sheet hung on spring chains (no volume: it is not part of the grown surface):
/// a ring or strip between neighbouring chains, or a card of `width` along one chain.
/// Its triangles face away from joint `around` (horizontally when `vertical`).
struct Sheet {
    chains: Vec<Vec<usize>>,
    closed: bool,
    width: f32,
    around: usize,
    vertical: bool,
}

/// A tapered capsule the surface grows around, owned by the joint that moves it.
#[derive(Clone, Copy)]
struct Limb {
    a: Vec3,
    b: Vec3,
    ra: f32,
    rb: f32,
    joint: usize,
}

impl Limb {
    /// Signed distance and the position along the limb (0 at a, 1 at b).
    fn distance(&self, p: Vec3) -> (f32, f32) {
        let ab = self.b - self.a;
        let t = ((p - self.a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
        let r = self.ra + (self.rb - self.ra) * t;
        (p.distance(self.a + t * ab) - r, t)
    }
}

/// Skeleton under construction plus the limbs grown around it.
struct Builder {
    skeleton: Skeleton,
    limbs: Vec<Limb>,
    sheets: Vec<Sheet>,
}

impl Builder {
    fn new(class: Class) -> Self {
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

    fn joint(&mut self, name: &str, parent: Option<usize>, at: Vec3, spring: bool) -> usize {
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
    fn chain(
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
    fn bare_chain(
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

    fn limb(&mut self, a: Vec3, b: Vec3, ra: f32, rb: f32, joint: usize) {
        self.limbs.push(Limb {
            a,
            b,
            ra,
            rb,
            joint,
        });
    }

    /// A limb from joint `j` to its child `c`, owned by `j`.
    fn bone(&mut self, j: usize, c: usize, ra: f32, rb: f32) {
        let (a, b) = (self.skeleton.joints[j], self.skeleton.joints[c]);
        self.limb(a, b, ra, rb, j);
    }
}

/// Scales a nominal value by a random factor in [1 − spread, 1 + spread].
fn jitter(rng: &mut Rng, value: f32, spread: f32) -> f32 {
    value * rng.range(1.0 - spread, 1.0 + spread)
}

/// Humanoid proportions beyond the jitter: adult-like, chibi (a head two to three times
/// as large over short limbs) or long-limbed.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Build {
    Plain,
    Chibi,
    Long,
}

/// Where a humanoid's variety comes from: a random stream, or none (the plain generator
/// the shipped models were trained on: adult build, arms held out, capsule loose parts,
/// no capes).
struct Style(Option<Rng>);

impl Style {
    fn chance(&mut self, p: f32) -> bool {
        self.0.as_mut().is_some_and(|r| r.chance(p))
    }

    /// A number below `n`; `n - 1` for the plain generator.
    fn below(&mut self, n: usize) -> usize {
        self.0.as_mut().map_or(n - 1, |r| r.below(n))
    }

    /// A number in [lo, hi); `lo` for the plain generator.
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        self.0.as_mut().map_or(lo, |r| r.range(lo, hi))
    }
}

/// A humanoid. `rng` draws what every humanoid has (as it did before the builds, arms at
/// the sides and sheets were added, so older seeds keep their skeletons); `style` draws
/// the build, the arms' rest and whether loose parts are sheets.
fn humanoid(rng: &mut Rng, style: &mut Style) -> Builder {
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

fn add_tail(rng: &mut Rng, b: &mut Builder, from: usize, h: f32) {
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

fn quadruped(rng: &mut Rng) -> Builder {
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
fn creature(rng: &mut Rng) -> Builder {
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
fn random_pose(rng: &mut Rng, b: &mut Builder, amount: f32) {
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

/// Smooth union of the limbs' distances (polynomial smooth minimum, radius k).
fn smooth_min(a: f32, b: f32, k: f32) -> f32 {
    let h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0);
    b + (a - b) * h - k * h * (1.0 - h)
}

/// Meshes the zero level of `field` sampled on a grid (surface nets: one vertex per cell
/// crossing the surface at the mean of its edge crossings, one quad per crossing edge).
fn surface_nets(lo: Vec3, cell: f32, dims: [usize; 3], field: &[f32]) -> Mesh {
    let [nx, ny, nz] = dims;
    let at = |x: usize, y: usize, z: usize| field[x + nx * (y + ny * z)];
    let corner = |x: usize, y: usize, z: usize| lo + Vec3::new(x as f32, y as f32, z as f32) * cell;
    let mut vertex_of = vec![u32::MAX; nx * ny * nz];
    let mut mesh = Mesh::default();
    for z in 0..nz - 1 {
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let mut sum = Vec3::ZERO;
                let mut crossings = 0;
                for (a, b) in CUBE_EDGES {
                    let pa = [x + a[0], y + a[1], z + a[2]];
                    let pb = [x + b[0], y + b[1], z + b[2]];
                    let (fa, fb) = (at(pa[0], pa[1], pa[2]), at(pb[0], pb[1], pb[2]));
                    if (fa < 0.0) != (fb < 0.0) {
                        let t = fa / (fa - fb);
                        sum += corner(pa[0], pa[1], pa[2]).lerp(corner(pb[0], pb[1], pb[2]), t);
                        crossings += 1;
                    }
                }
                if crossings > 0 {
                    vertex_of[x + nx * (y + ny * z)] = mesh.positions.len() as u32;
                    mesh.positions.push(sum / crossings as f32);
                }
            }
        }
    }
    let v = |x: usize, y: usize, z: usize| vertex_of[x + nx * (y + ny * z)];
    for z in 1..nz - 1 {
        for y in 1..ny - 1 {
            for x in 1..nx - 1 {
                let inside = at(x, y, z) < 0.0;
                // Edges from this grid point along +x, +y, +z, and the four cells around each.
                let quads = [
                    (
                        at(x + 1, y, z),
                        [
                            v(x, y - 1, z - 1),
                            v(x, y, z - 1),
                            v(x, y, z),
                            v(x, y - 1, z),
                        ],
                    ),
                    (
                        at(x, y + 1, z),
                        [
                            v(x - 1, y, z - 1),
                            v(x - 1, y, z),
                            v(x, y, z),
                            v(x, y, z - 1),
                        ],
                    ),
                    (
                        at(x, y, z + 1),
                        [
                            v(x - 1, y - 1, z),
                            v(x, y - 1, z),
                            v(x, y, z),
                            v(x - 1, y, z),
                        ],
                    ),
                ];
                for (other, [a, b, c, d]) in quads {
                    if inside == (other < 0.0) || [a, b, c, d].contains(&u32::MAX) {
                        continue;
                    }
                    let quad = if inside { [a, b, c, d] } else { [d, c, b, a] };
                    mesh.indices
                        .extend([quad[0], quad[1], quad[2], quad[0], quad[2], quad[3]]);
                }
            }
        }
    }
    mesh.compute_normals();
    mesh.colors = vec![Vec3::splat(0.7); mesh.positions.len()];
    mesh
}

const CUBE_EDGES: [([usize; 3], [usize; 3]); 12] = [
    ([0, 0, 0], [1, 0, 0]),
    ([0, 1, 0], [1, 1, 0]),
    ([0, 0, 1], [1, 0, 1]),
    ([0, 1, 1], [1, 1, 1]),
    ([0, 0, 0], [0, 1, 0]),
    ([1, 0, 0], [1, 1, 0]),
    ([0, 0, 1], [0, 1, 1]),
    ([1, 0, 1], [1, 1, 1]),
    ([0, 0, 0], [0, 0, 1]),
    ([1, 0, 0], [1, 0, 1]),
    ([0, 1, 0], [0, 1, 1]),
    ([1, 1, 0], [1, 1, 1]),
];

/// Ground-truth weights of a surface point: the limb nearest the surface owns it,
/// [`painted`] with the owner's parent (where the limb starts at the owner) or the joint
/// the limb runs into.
fn skin_of(p: Vec3, limbs: &[Limb], skeleton: &Skeleton) -> Vec<(usize, f32)> {
    let (limb, t) = limbs
        .iter()
        .map(|l| (l, l.distance(p)))
        .min_by(|a, b| a.1.0.total_cmp(&b.1.0))
        .map(|(l, (_, t))| (l, t))
        .expect("a character has limbs");
    let owner = limb.joint;
    let child = (0..skeleton.len()).find(|&c| {
        skeleton.parents[c] == Some(owner) && skeleton.joints[c].distance(limb.b) < 1e-4
    });
    let parent = skeleton.parents[owner].filter(|_| skeleton.joints[owner].distance(limb.a) < 1e-4);
    painted(owner, t, parent, child)
}

/// The weights of a point at `t` along a bone of `owner` (0 at its start, 1 at its end):
/// all to `owner`, except over the first and last fifth, where it blends linearly (to
/// half at the end) with `previous` (the joint before the bone's start) or `next` (the
/// joint at its end), as artists paint.
fn painted(
    owner: usize,
    t: f32,
    previous: Option<usize>,
    next: Option<usize>,
) -> Vec<(usize, f32)> {
    let blend = 0.2;
    match (previous, next) {
        (Some(p), _) if t < blend => {
            let w = 0.5 * (1.0 - t / blend);
            vec![(owner, 1.0 - w), (p, w)]
        }
        (_, Some(c)) if t > 1.0 - blend => {
            let w = 0.5 * (t - (1.0 - blend)) / blend;
            vec![(owner, 1.0 - w), (c, w)]
        }
        _ => vec![(owner, 1.0)],
    }
}

/// A point of a sheet and its weights.
type Weighted = (Vec3, Vec<(usize, f32)>);

/// Rows of vertices along a sheet's chains, and columns between two neighbouring chains.
const SHEET_ROWS: usize = 9;
const SHEET_SPAN: usize = 3;

/// The point at fraction `t` of a chain's length (its joints, then half a bone past the
/// last, as [`Builder::chain`] grows it) and its weights: the joint whose bone it lies on,
/// [`painted`] as [`skin_of`] does.
fn along_chain(skeleton: &Skeleton, chain: &[usize], t: f32) -> Weighted {
    let mut line: Vec<Vec3> = chain.iter().map(|&j| skeleton.joints[j]).collect();
    let n = line.len();
    let last = line[n - 1];
    let before = if n > 1 {
        line[n - 2]
    } else {
        skeleton.parents[chain[0]].map_or(last + Vec3::Y, |p| skeleton.joints[p])
    };
    line.push(last + 0.5 * (last - before));
    let lengths: Vec<f32> = line.windows(2).map(|w| w[0].distance(w[1])).collect();
    let mut target = t.clamp(0.0, 1.0) * lengths.iter().sum::<f32>();
    let mut k = 0;
    while k + 1 < lengths.len() && target > lengths[k] {
        target -= lengths[k];
        k += 1;
    }
    let f = (target / lengths[k].max(1e-12)).clamp(0.0, 1.0);
    let at = line[k].lerp(line[k + 1], f);
    let owner = chain[k];
    let previous = if k == 0 {
        skeleton.parents[owner]
    } else {
        Some(chain[k - 1])
    };
    (at, painted(owner, f, previous, chain.get(k + 1).copied()))
}

/// Sums weights by joint.
fn mix(parts: &[(f32, &[(usize, f32)])]) -> Vec<(usize, f32)> {
    let mut out: Vec<(usize, f32)> = Vec::new();
    for &(scale, weights) in parts {
        for &(j, w) in weights {
            match out.iter_mut().find(|(k, _)| *k == j) {
                Some(slot) => slot.1 += scale * w,
                None => out.push((j, scale * w)),
            }
        }
    }
    out.retain(|&(_, w)| w > 0.0);
    out
}

/// A sheet's mesh on the posed skeleton and each vertex's weights: a grid of
/// [`SHEET_ROWS`] rows by [`SHEET_SPAN`] columns between neighbouring chains (a card: two
/// columns, `width` apart, across its one chain), one layer of triangles facing away
/// from the sheet's `around` joint.
fn sheet_mesh(sheet: &Sheet, skeleton: &Skeleton) -> (Mesh, Vec<Vec<(usize, f32)>>) {
    let chains = &sheet.chains;
    let mut columns: Vec<Vec<Weighted>> = Vec::new();
    let rows = |c: usize| -> Vec<Weighted> {
        (0..SHEET_ROWS)
            .map(|r| along_chain(skeleton, &chains[c], r as f32 / (SHEET_ROWS - 1) as f32))
            .collect()
    };
    let center = skeleton.joints[sheet.around];
    if chains.len() == 1 {
        let line = rows(0);
        for side in [-0.5f32, 0.5] {
            let column = (0..SHEET_ROWS)
                .map(|r| {
                    let (at, w) = &line[r];
                    let tangent = line[(r + 1).min(SHEET_ROWS - 1)].0 - line[r.saturating_sub(1)].0;
                    let across = tangent.cross(*at - center).normalize_or(Vec3::X);
                    (*at + across * side * sheet.width, w.clone())
                })
                .collect();
            columns.push(column);
        }
    } else {
        let lines: Vec<_> = (0..chains.len()).map(rows).collect();
        let spans = if sheet.closed {
            chains.len()
        } else {
            chains.len() - 1
        };
        for c in 0..spans {
            let (a, b) = (&lines[c], &lines[(c + 1) % chains.len()]);
            for q in 0..SHEET_SPAN {
                let u = q as f32 / SHEET_SPAN as f32;
                columns.push(
                    (0..SHEET_ROWS)
                        .map(|r| {
                            let at = a[r].0.lerp(b[r].0, u);
                            (at, mix(&[(1.0 - u, &a[r].1), (u, &b[r].1)]))
                        })
                        .collect(),
                );
            }
        }
        if !sheet.closed {
            columns.push(lines[chains.len() - 1].clone());
        }
    }
    let mut mesh = Mesh::default();
    let mut skin = Vec::new();
    for column in &columns {
        for (at, w) in column {
            mesh.positions.push(*at);
            skin.push(w.clone());
        }
    }
    let index = |c: usize, r: usize| (c % columns.len() * SHEET_ROWS + r) as u32;
    let quads = if sheet.closed {
        columns.len()
    } else {
        columns.len() - 1
    };
    for c in 0..quads {
        for r in 0..SHEET_ROWS - 1 {
            let quad = [
                index(c, r),
                index(c + 1, r),
                index(c + 1, r + 1),
                index(c, r + 1),
            ];
            for tri in [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]] {
                let [a, b, d] = tri.map(|i| mesh.positions[i as usize]);
                let mut away = (a + b + d) / 3.0 - center;
                if sheet.vertical {
                    away.y = 0.0;
                }
                let tri = if (b - a).cross(d - a).dot(away) < 0.0 {
                    [tri[0], tri[2], tri[1]]
                } else {
                    tri
                };
                mesh.indices.extend(tri);
            }
        }
    }
    mesh.colors = vec![Vec3::splat(0.7); mesh.positions.len()];
    (mesh, skin)
}

/// A random character of a random class (60 % humanoid, 20 % quadruped, 20 % other);
/// `pose` scales the random pose (0 = rest); `variety` false gives the plain generator
/// (see [`Style`]).
pub fn character(seed: u64, pose: f32, variety: bool) -> Synthetic {
    let class = match Rng::new(seed ^ 0xc1a55).below(10) {
        0..=5 => Class::Humanoid,
        6..=7 => Class::Quadruped,
        _ => Class::Other,
    };
    of_class(seed, class, pose, variety)
}

/// A random character of the given class (`variety`: see [`character`]).
pub fn of_class(seed: u64, class: Class, pose: f32, variety: bool) -> Synthetic {
    let mut rng = Rng::new(seed);
    let mut b = match class {
        Class::Humanoid => {
            let style = variety.then(|| Rng::new(seed ^ 0x57_11e));
            humanoid(&mut rng, &mut Style(style))
        }
        Class::Quadruped => quadruped(&mut rng),
        Class::Other => creature(&mut rng),
    };
    random_pose(&mut rng, &mut b, pose);
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for l in &b.limbs {
        let r = l.ra.max(l.rb);
        lo = lo.min(l.a.min(l.b) - r);
        hi = hi.max(l.a.max(l.b) + r);
    }
    let cell = (hi - lo).max_element() / 72.0;
    let lo = lo - Vec3::splat(2.0 * cell);
    let dims = ((hi - lo) / cell).ceil().as_uvec3() + 3;
    let dims = [dims.x as usize, dims.y as usize, dims.z as usize];
    let blend = 0.4
        * b.limbs
            .iter()
            .map(|l| l.ra.min(l.rb))
            .fold(f32::MAX, f32::min);
    let mut field = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = lo + Vec3::new(x as f32, y as f32, z as f32) * cell;
                let d = b
                    .limbs
                    .iter()
                    .map(|l| l.distance(p).0)
                    .fold(f32::MAX, |acc, d| smooth_min(acc, d, blend));
                field.push(d);
            }
        }
    }
    let mut mesh = surface_nets(lo, cell, dims, &field);
    let mut skin: Vec<_> = mesh
        .positions
        .iter()
        .map(|&p| skin_of(p, &b.limbs, &b.skeleton))
        .collect();
    let body_vertices = mesh.positions.len();
    for sheet in &b.sheets {
        let (part, weights) = sheet_mesh(sheet, &b.skeleton);
        mesh.append(part);
        skin.extend(weights);
    }
    mesh.compute_normals();
    Synthetic {
        skeleton: b.skeleton,
        mesh,
        skin,
        body_vertices,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::autorig::skeleton::UnitCube;
    use crate::autorig::tokens::{decode, encode};

    #[test]
    fn characters_are_closed_skinned_and_tokenisable() {
        for seed in 0..12 {
            let c = character(seed, 1.0, true);
            assert!(c.skeleton.is_ordered());
            assert!(c.mesh.positions.len() > 500, "seed {seed}");
            // Closed: every edge is shared by exactly two triangles.
            let mut edges = std::collections::HashMap::new();
            let body = c.body_vertices as u32;
            for t in c.mesh.indices.chunks_exact(3).filter(|t| t[0] < body) {
                for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                    *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
                }
            }
            let open = edges.values().filter(|&&n| n != 2).count();
            assert!(
                open * 100 < edges.len(),
                "seed {seed}: {open} of {} edges open",
                edges.len()
            );
            for w in &c.skin {
                let sum: f32 = w.iter().map(|(_, w)| w).sum();
                assert!((sum - 1.0).abs() < 1e-5);
            }
            let cube = UnitCube::of_points(&c.mesh.positions);
            let unit = c.skeleton.map_joints(|p| cube.to_unit(p));
            let tokens = encode(&unit).unwrap_or_else(|e| panic!("seed {seed}: {e}"));
            assert_eq!(decode(&tokens).unwrap().len(), unit.len());
        }
    }

    #[test]
    fn a_point_along_a_chain_and_its_weights() {
        // Parent 0 at y = 1, chain joints 1 and 2 at y = 0 and y = -1: the line runs on
        // to y = -1.5 (half a bone past the last joint), 2.5 long in all... 1.5 below 0.
        let skeleton = Skeleton {
            class: Class::Humanoid,
            joints: vec![Vec3::Y, Vec3::ZERO, Vec3::NEG_Y],
            parents: vec![None, Some(0), Some(1)],
            names: vec!["Hips".into(), "Skirt0".into(), "Skirt1".into()],
            spring: vec![false, true, true],
        };
        let chain = [1, 2];
        let (at, w) = along_chain(&skeleton, &chain, 0.0);
        assert!(at.distance(Vec3::ZERO) < 1e-6);
        assert_eq!(w, vec![(1, 0.5), (0, 0.5)]);
        // 0.5 of 1.5 is 0.75 down the first bone: inside its middle, all to joint 1.
        let (at, w) = along_chain(&skeleton, &chain, 0.5);
        assert!(at.distance(Vec3::new(0.0, -0.75, 0.0)) < 1e-6);
        assert_eq!(w, vec![(1, 1.0)]);
        // 0.6 of 1.5 is 0.9 down: 0.1 from its end, blended a quarter to the next joint.
        let (at, w) = along_chain(&skeleton, &chain, 0.6);
        assert!(at.distance(Vec3::new(0.0, -0.9, 0.0)) < 1e-6);
        assert!(
            (w[0].1 - 0.75).abs() < 1e-5 && w[1] == (2, w[1].1) && (w[1].1 - 0.25).abs() < 1e-5
        );
        let (at, w) = along_chain(&skeleton, &chain, 1.0);
        assert!(at.distance(Vec3::new(0.0, -1.5, 0.0)) < 1e-6);
        assert_eq!(w, vec![(2, 1.0)]);
    }

    #[test]
    fn humanoids_come_in_builds_with_sheets_on_spring_chains() {
        let (mut sheets, mut capes, mut cards, mut chibi, mut at_sides) = (0, 0, 0, 0, 0);
        for seed in 0..200 {
            let c = of_class(seed, Class::Humanoid, 0.0, true);
            let s = &c.skeleton;
            let at = |name: &str| s.joints[s.names.iter().position(|n| n == name).unwrap()];
            // Chibi: a head (head joint to the top) over 30 % of the height.
            let (lo, hi) = c.mesh.bounds().unwrap();
            if (hi.y - at("Head").y) > 0.3 * (hi.y - lo.y) {
                chibi += 1;
            }
            let arm = at("Wrist.L") - at("UpperArm.L");
            if arm.y < -arm.length() * 75f32.to_radians().sin() {
                at_sides += 1;
            }
            if c.mesh.positions.len() > c.body_vertices {
                sheets += 1;
            }
            capes += s.names.iter().any(|n| n == "Cape0_0") as usize;
            // Every sheet vertex is weighted to spring joints or the joint a chain hangs
            // from, and its weights sum to one.
            for w in &c.skin[c.body_vertices..] {
                let sum: f32 = w.iter().map(|(_, w)| w).sum();
                assert!((sum - 1.0).abs() < 1e-5, "seed {seed}: {w:?}");
                for &(j, _) in w {
                    let hangs_from = s
                        .spring
                        .iter()
                        .enumerate()
                        .any(|(k, &sp)| sp && s.parents[k] == Some(j));
                    assert!(
                        s.spring[j] || hangs_from,
                        "seed {seed}: joint {}",
                        s.names[j]
                    );
                    if s.names[j].starts_with("Hair") {
                        cards += 1;
                    }
                }
            }
        }
        // The build, the arms and the sheets are drawn at 15 %, 35 % and (skirts 40 % x
        // 75 %, hair 50 % x 80 %, capes 15 %) of humanoids.
        println!("chibi {chibi}, arms at the sides {at_sides}, sheets {sheets}, capes {capes}");
        assert!((15..=50).contains(&chibi), "{chibi}");
        assert!((45..=110).contains(&at_sides), "{at_sides}");
        assert!((70..=170).contains(&sheets), "{sheets}");
        assert!((15..=50).contains(&capes), "{capes}");
        assert!(cards > 0);
        // The plain generator: no sheets, no capes, no chibi heads, arms never below 80°.
        for seed in 0..100 {
            let c = of_class(seed, Class::Humanoid, 0.0, false);
            assert_eq!(c.body_vertices, c.mesh.positions.len());
            assert!(!c.skeleton.names.iter().any(|n| n.starts_with("Cape")));
            let s = &c.skeleton;
            let at = |name: &str| s.joints[s.names.iter().position(|n| n == name).unwrap()];
            let arm = at("Wrist.L") - at("UpperArm.L");
            assert!(
                arm.y >= -arm.length() * 80.5f32.to_radians().sin(),
                "seed {seed}"
            );
        }
    }

    #[test]
    fn surface_nets_mesh_a_sphere() {
        let cell = 0.1;
        let lo = Vec3::splat(-1.5);
        let dims = [31, 31, 31];
        let mut field = Vec::new();
        for z in 0..31 {
            for y in 0..31 {
                for x in 0..31 {
                    field
                        .push((lo + Vec3::new(x as f32, y as f32, z as f32) * cell).length() - 1.0);
                }
            }
        }
        let mesh = surface_nets(lo, cell, dims, &field);
        for (&p, &n) in mesh.positions.iter().zip(&mesh.normals) {
            assert!((p.length() - 1.0).abs() < 0.02, "{p}");
            // Outward normals.
            assert!(n.dot(p.normalize()) > 0.9, "{n} at {p}");
        }
    }
}
