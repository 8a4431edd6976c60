//! Synthetic training characters: a random skeleton tree from a humanoid, quadruped or
//! winged/tailed creature pattern with random proportions, posed at random, a surface
//! grown around its bones (smooth union of tapered capsules, meshed by surface nets),
//! and ground-truth skin weights (each vertex to the bone that grew it, blended linearly
//! with the neighbouring joints near each end, as artists paint).

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

fn humanoid(rng: &mut Rng) -> Builder {
    let mut b = Builder::new(Class::Humanoid);
    let h = rng.range(1.2, 2.1);
    let leg = jitter(rng, 0.47, 0.12) * h;
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
    let head_r = jitter(rng, 0.075, 0.45) * h;
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
    let upper = jitter(rng, 0.17, 0.15) * h;
    let lower = jitter(rng, 0.16, 0.15) * h;
    let arm_r = jitter(rng, 0.03, 0.35) * thick;
    let hands = rng.chance(0.5);
    for (side, sx) in [("L", 1.0f32), ("R", -1.0f32)] {
        let shoulder_at = chest_at + Vec3::new(sx * 0.03 * h, 0.02 * h, 0.0);
        let shoulder = b.joint(&format!("Shoulder.{side}"), Some(chest), shoulder_at, false);
        let dir = Vec3::new(sx * droop.cos(), -droop.sin(), 0.0);
        let upper_at = shoulder_at + Vec3::new(sx * jitter(rng, 0.07, 0.3) * h, 0.0, 0.0);
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
    if rng.chance(0.5) {
        let chains = 1 + rng.below(5);
        for c in 0..chains {
            let angle = std::f32::consts::PI * (c as f32 + 0.5) / chains as f32;
            let start = head_at + Vec3::new(angle.cos() * head_r * 0.8, head_r, -0.6 * head_r);
            let step = Vec3::new(0.0, -1.0, -0.3).normalize() * jitter(rng, 0.07, 0.4) * h;
            let r = 0.012 * h;
            b.chain(
                &format!("Hair{c}_"),
                head,
                start,
                step,
                2 + rng.below(3),
                (r, r * 0.6),
                true,
                Vec3::ZERO,
            );
        }
    }
    if rng.chance(0.4) {
        let chains = 4 + rng.below(5);
        let flare = rng.range(0.2, 0.8);
        let length = jitter(rng, 0.15, 0.4) * h;
        for c in 0..chains {
            let angle = std::f32::consts::TAU * c as f32 / chains as f32;
            let out = Vec3::new(angle.sin(), 0.0, angle.cos());
            let start = hips_at + out * (hip_half + leg_r);
            let step = (Vec3::NEG_Y + out * flare).normalize() * length * 0.5;
            b.chain(
                &format!("Skirt{c}_"),
                hips,
                start,
                step,
                2 + rng.below(2),
                (0.03 * h, 0.03 * h),
                true,
                Vec3::ZERO,
            );
        }
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

/// Ground-truth weights of a surface point: the limb nearest the surface owns it; within
/// the first and last fifth of the limb the weight blends linearly (to half at the end)
/// with the owner's parent or the joint the limb runs into.
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
    let blend = 0.2;
    let mut weights = vec![(owner, 1.0)];
    if t < blend
        && let Some(parent) = skeleton.parents[owner]
        && skeleton.joints[owner].distance(limb.a) < 1e-4
    {
        let w = 0.5 * (1.0 - t / blend);
        weights = vec![(owner, 1.0 - w), (parent, w)];
    } else if t > 1.0 - blend
        && let Some(child) = child
    {
        let w = 0.5 * (t - (1.0 - blend)) / blend;
        weights = vec![(owner, 1.0 - w), (child, w)];
    }
    weights
}

/// A random character of a random class (60 % humanoid, 20 % quadruped, 20 % other);
/// `pose` scales the random pose (0 = rest).
pub fn character(seed: u64, pose: f32) -> Synthetic {
    let class = match Rng::new(seed ^ 0xc1a55).below(10) {
        0..=5 => Class::Humanoid,
        6..=7 => Class::Quadruped,
        _ => Class::Other,
    };
    of_class(seed, class, pose)
}

/// A random character of the given class.
pub fn of_class(seed: u64, class: Class, pose: f32) -> Synthetic {
    let mut rng = Rng::new(seed);
    let mut b = match class {
        Class::Humanoid => humanoid(&mut rng),
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
    let mesh = surface_nets(lo, cell, dims, &field);
    let skin = mesh
        .positions
        .iter()
        .map(|&p| skin_of(p, &b.limbs, &b.skeleton))
        .collect();
    Synthetic {
        skeleton: b.skeleton,
        mesh,
        skin,
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
            let c = character(seed, 1.0);
            assert!(c.skeleton.is_ordered());
            assert!(c.mesh.positions.len() > 500, "seed {seed}");
            // Closed: every edge is shared by exactly two triangles.
            let mut edges = std::collections::HashMap::new();
            for t in c.mesh.indices.chunks_exact(3) {
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
