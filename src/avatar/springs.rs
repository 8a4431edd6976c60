//! Spring bones (VRM 1.0 style): chains of joints whose tails are integrated by Verlet
//! steps — inertia with drag, stiffness toward the rest direction in the parent's frame,
//! gravity — with every bone length restored and sphere/capsule colliders kept out, at
//! fixed 60 Hz sub-steps. The joints are rig nodes; the simulation writes their rotations.

use glam::{Mat4, Quat, Vec3};

use super::rig::{Rig, Transform};

/// Simulation rate: fixed sub-steps per second.
pub const STEP_RATE: f32 = 60.0;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpringParams {
    /// Pull toward the rest direction, per second (VRM `stiffness`).
    pub stiffness: f32,
    /// Share of the velocity lost per step, 0..1 (VRM `dragForce`).
    pub drag: f32,
    /// Gravity displacement per second, in metres (VRM `gravityPower`).
    pub gravity: f32,
    /// Gravity's direction (VRM `gravityDir`; down unless a file says otherwise).
    pub gravity_dir: Vec3,
    /// Radius of each joint's tail against colliders.
    pub hit_radius: f32,
}

impl Default for SpringParams {
    fn default() -> Self {
        Self {
            stiffness: 1.0,
            drag: 0.4,
            gravity: 0.5,
            gravity_dir: Vec3::NEG_Y,
            hit_radius: 0.02,
        }
    }
}

/// A sphere (`end == None`) or a capsule, each end a point in a rig node's frame: a
/// capsule between two bones (`end` on another node) or VRM's, both ends on one node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Collider {
    pub node: usize,
    pub offset: Vec3,
    pub end: Option<(usize, Vec3)>,
    pub radius: f32,
}

impl Collider {
    /// A sphere around a node, or a capsule to another node.
    pub fn between(node: usize, to: Option<usize>, radius: f32) -> Self {
        Self {
            node,
            offset: Vec3::ZERO,
            end: to.map(|to| (to, Vec3::ZERO)),
            radius,
        }
    }

    /// The collider's closest axis point to `p` for world matrices `world`.
    pub fn closest(&self, world: &[Mat4], p: Vec3) -> Vec3 {
        let a = world[self.node].transform_point3(self.offset);
        match self.end {
            None => a,
            Some((node, offset)) => {
                let b = world[node].transform_point3(offset);
                let ab = b - a;
                let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
                a + ab * t
            }
        }
    }
}

/// A collider's radius from the distances of the vertices it stands for to its axis:
/// their median, within 2-15 % of the character's `height` (5 % with no vertices).
pub fn median_radius(mut distances: Vec<f32>, height: f32) -> f32 {
    if distances.is_empty() {
        return 0.05 * height;
    }
    distances.sort_by(f32::total_cmp);
    // max/min rather than clamp: never panics, whatever the height.
    distances[distances.len() / 2]
        .min(0.15 * height)
        .max(0.02 * height)
}

#[derive(Clone, Debug)]
struct Joint {
    node: usize,
    /// Nodes from below the previous joint down to this one (only this one where each
    /// joint is the parent of the next): refreshed in order before this joint moves.
    path: Vec<usize>,
    params: SpringParams,
    /// Direction from the joint to its tail in the joint's rest frame (unit).
    axis: Vec3,
    length: f32,
    tail: Vec3,
    prev_tail: Vec3,
}

/// One chain: joints from the root (attached to a non-simulated parent) to the tip.
#[derive(Clone, Debug)]
pub struct Chain {
    joints: Vec<Joint>,
    /// Indices of the colliders this chain is kept out of (all when `None`).
    pub colliders: Option<Vec<usize>>,
}

impl Chain {
    /// The rig nodes of this chain's joints, root first.
    pub fn nodes(&self) -> impl Iterator<Item = usize> + '_ {
        self.joints.iter().map(|j| j.node)
    }

    /// A chain over rig nodes `nodes` (each the parent of the next), ending in a tail at
    /// `tip` (the last node's rest-frame offset), from the rig's rest pose `world`.
    pub fn new(
        rig: &Rig,
        world: &[Mat4],
        nodes: &[usize],
        tip: Vec3,
        params: SpringParams,
    ) -> Self {
        Self::with_joint_params(rig, world, nodes, tip, &vec![params; nodes.len()])
    }

    /// As [`Chain::new`] with settings per joint; each node is an ancestor of the next
    /// (VRM allows skipped nodes between joints: they follow their parents).
    pub fn with_joint_params(
        rig: &Rig,
        world: &[Mat4],
        nodes: &[usize],
        tip: Vec3,
        params: &[SpringParams],
    ) -> Self {
        assert_eq!(params.len(), nodes.len(), "one setting per joint");
        let joints = nodes
            .iter()
            .enumerate()
            .map(|(i, &node)| {
                let head = world[node].w_axis.truncate();
                let tail = match nodes.get(i + 1) {
                    Some(&next) => world[next].w_axis.truncate(),
                    None => world[node].transform_point3(tip),
                };
                let local_axis = world[node].inverse().transform_vector3(tail - head);
                debug_assert!(
                    rig.nodes[node].parent.is_some(),
                    "a spring joint needs a parent"
                );
                let mut path = vec![node];
                if i > 0 {
                    while let Some(p) = rig.nodes[*path.last().expect("node")].parent {
                        if p == nodes[i - 1] {
                            break;
                        }
                        path.push(p);
                    }
                    debug_assert!(
                        rig.nodes[*path.last().expect("node")].parent == Some(nodes[i - 1]),
                        "each joint is below the one before it"
                    );
                    path.reverse();
                }
                Joint {
                    node,
                    path,
                    params: params[i],
                    axis: local_axis.normalize_or(Vec3::NEG_Y),
                    length: (tail - head).length(),
                    tail,
                    prev_tail: tail,
                }
            })
            .collect();
        Self {
            joints,
            colliders: None,
        }
    }

    /// Keeps this chain out of only those colliders that none of its rest tails is inside
    /// (a collider the chain starts in, like the head under a hat, is not meant for it).
    pub fn choose_colliders(&mut self, colliders: &[Collider], world: &[Mat4]) {
        let outside = |c: &Collider| {
            self.joints.iter().all(|j| {
                j.tail.distance(c.closest(world, j.tail)) >= c.radius + j.params.hit_radius
            })
        };
        self.colliders = Some(
            (0..colliders.len())
                .filter(|&i| outside(&colliders[i]))
                .collect(),
        );
    }

    /// The current tail positions, root joint first.
    pub fn tails(&self) -> Vec<Vec3> {
        self.joints.iter().map(|j| j.tail).collect()
    }

    pub fn lengths(&self) -> Vec<f32> {
        self.joints.iter().map(|j| j.length).collect()
    }

    /// Puts every tail at its rest direction for the current pose (no motion).
    pub fn reset(&mut self, rig: &Rig, local: &mut [Transform], world: &mut [Mat4]) {
        for i in 0..self.joints.len() {
            let joint = &mut self.joints[i];
            local[joint.node].rotation = rig.nodes[joint.node].rest.rotation;
            for &n in &joint.path {
                refresh(rig, local, world, n);
            }
            let tail = world[joint.node]
                .transform_point3(joint.axis * joint.length / world_scale(&world[joint.node]));
            joint.tail = tail;
            joint.prev_tail = tail;
        }
    }

    /// One Verlet step of `dt` seconds: moves the tails, then rotates the joints (in
    /// `local`, with `world` kept in step) to point at them.
    pub fn step(
        &mut self,
        rig: &Rig,
        local: &mut [Transform],
        world: &mut [Mat4],
        colliders: &[Collider],
        dt: f32,
    ) {
        for i in 0..self.joints.len() {
            let node = self.joints[i].node;
            let p = self.joints[i].params;
            let parent = rig.nodes[node].parent.expect("spring joints have parents");
            // The joint at its rest rotation under the (already updated) parent.
            local[node].rotation = rig.nodes[node].rest.rotation;
            for &n in &self.joints[i].path {
                refresh(rig, local, world, n);
            }
            let head = world[node].w_axis.truncate();
            let joint = &mut self.joints[i];
            let rest_direction = world[node]
                .transform_vector3(joint.axis)
                .normalize_or(Vec3::NEG_Y);
            let inertia = (joint.tail - joint.prev_tail) * (1.0 - p.drag);
            let mut next = joint.tail
                + inertia
                + rest_direction * (p.stiffness * dt)
                + p.gravity_dir * (p.gravity * dt);
            next = head + (next - head).normalize_or(rest_direction) * joint.length;
            next = match &self.colliders {
                None => keep_out(
                    head,
                    next,
                    joint.length,
                    colliders.iter(),
                    world,
                    p.hit_radius,
                ),
                Some(chosen) => keep_out(
                    head,
                    next,
                    joint.length,
                    chosen.iter().map(|&i| &colliders[i]),
                    world,
                    p.hit_radius,
                ),
            };
            joint.prev_tail = joint.tail;
            joint.tail = next;
            // Rotate the joint (in its parent's frame) so its axis points at the tail.
            let to_parent = world[parent].inverse();
            let rest_axis = (rig.nodes[node].rest.rotation * joint.axis).normalize();
            let wanted = to_parent
                .transform_vector3(next - head)
                .normalize_or(rest_axis);
            local[node].rotation = (Quat::from_rotation_arc(rest_axis, wanted)
                * rig.nodes[node].rest.rotation)
                .normalize();
            refresh(rig, local, world, node);
        }
    }
}

fn world_scale(m: &Mat4) -> f32 {
    m.x_axis.truncate().length()
}

/// Recomputes one node's world matrix from its parent's.
fn refresh(rig: &Rig, local: &[Transform], world: &mut [Mat4], node: usize) {
    let parent = rig.nodes[node].parent.map_or(Mat4::IDENTITY, |p| world[p]);
    world[node] = parent * local[node].matrix();
}

/// Moves a tail at distance `length` from `head` out of every collider, keeping the
/// distance: the tail turns about the head, in the plane of the head, the tail and the
/// collider's axis point, just far enough. A few rounds settle overlapping colliders.
fn keep_out<'a>(
    head: Vec3,
    mut tail: Vec3,
    length: f32,
    colliders: impl Iterator<Item = &'a Collider> + Clone,
    world: &[Mat4],
    hit: f32,
) -> Vec3 {
    for _ in 0..4 {
        let mut moved = false;
        for collider in colliders.clone() {
            let centre = collider.closest(world, tail);
            let reach = collider.radius + hit;
            if tail.distance_squared(centre) >= reach * reach {
                continue;
            }
            let to_centre = centre - head;
            let d = to_centre.length();
            if d < 1e-6 {
                continue; // the head is on the axis: nowhere sensible to go
            }
            let w = to_centre / d;
            // Directions v with |head + length v - centre| >= reach have v.w <= cos_max.
            let cos_max = (length * length + d * d - reach * reach) / (2.0 * length * d);
            if cos_max <= -1.0 {
                continue; // the collider swallows every direction
            }
            let u = (tail - head) / length;
            let side = (u - w * u.dot(w)).normalize_or(w.any_orthonormal_vector());
            let cos = cos_max.min(1.0) - 1e-5;
            tail = head + (w * cos + side * (1.0 - cos * cos).max(0.0).sqrt()) * length;
            moved = true;
        }
        if !moved {
            break;
        }
    }
    tail
}

/// All the spring chains of a character and its colliders, stepped together.
#[derive(Clone, Debug, Default)]
pub struct SpringSystem {
    pub chains: Vec<Chain>,
    pub colliders: Vec<Collider>,
}

impl SpringSystem {
    /// Simulates `seconds` in fixed sub-steps on top of an animated pose: `local` holds
    /// the animation (chain joints at rest), `world` its matrices; both are updated.
    pub fn advance(
        &mut self,
        rig: &Rig,
        local: &mut [Transform],
        world: &mut [Mat4],
        seconds: f32,
    ) {
        let steps = (seconds * STEP_RATE).round().max(1.0) as usize;
        let dt = seconds / steps as f32;
        for _ in 0..steps {
            for chain in &mut self.chains {
                chain.step(rig, local, world, &self.colliders, dt);
            }
            below_joints(rig, local, world);
        }
    }

    pub fn reset(&mut self, rig: &Rig, local: &mut [Transform], world: &mut [Mat4]) {
        for chain in &mut self.chains {
            chain.reset(rig, local, world);
        }
        below_joints(rig, local, world);
    }
}

/// Recomputes every node under a parent from its parent (parents come first), so the
/// nodes below a spring joint that are not joints themselves (a VRM spring's tail, the
/// rest of a rig under a chain) follow the joints' new rotations. Nodes the springs did
/// not move get the same matrices as before.
fn below_joints(rig: &Rig, local: &[Transform], world: &mut [Mat4]) {
    for (n, node) in rig.nodes.iter().enumerate() {
        if let Some(p) = node.parent {
            world[n] = world[p] * local[n].matrix();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::avatar::rig::Node;

    /// A root and a chain of three 0.2 m joints along `direction` from (0, 2, 0).
    fn chain_rig(direction: Vec3) -> Rig {
        let mut rig = Rig::default();
        rig.nodes.push(Node {
            name: "root".into(),
            parent: None,
            rest: Transform {
                translation: Vec3::new(0.0, 2.0, 0.0),
                ..Default::default()
            },
        });
        for i in 0..3 {
            rig.nodes.push(Node {
                name: format!("j{i}"),
                parent: Some(i),
                rest: Transform {
                    translation: if i == 0 { Vec3::ZERO } else { direction * 0.2 },
                    ..Default::default()
                },
            });
        }
        rig
    }

    fn system(
        rig: &Rig,
        direction: Vec3,
        params: SpringParams,
        colliders: Vec<Collider>,
    ) -> SpringSystem {
        let world = rig.world(&rig.rest_pose(), Mat4::IDENTITY);
        SpringSystem {
            chains: vec![Chain::new(rig, &world, &[1, 2, 3], direction * 0.2, params)],
            colliders,
        }
    }

    fn simulate(
        rig: &Rig,
        springs: &mut SpringSystem,
        frames: usize,
        mut check: impl FnMut(&SpringSystem, &[Mat4]),
    ) {
        for _ in 0..frames {
            // The animation: everything at rest (the springs' joints included).
            let mut local = rig.rest_pose();
            let mut world = rig.world(&local, Mat4::IDENTITY);
            springs.advance(rig, &mut local, &mut world, 1.0 / 30.0);
            check(springs, &world);
        }
    }

    #[test]
    fn a_chain_at_rest_stays_at_rest() {
        let rig = chain_rig(Vec3::X);
        let params = SpringParams {
            gravity: 0.0,
            ..Default::default()
        };
        let mut springs = system(&rig, Vec3::X, params, vec![]);
        let rest = springs.chains[0].tails();
        simulate(&rig, &mut springs, 100, |s, _| {
            for (a, b) in s.chains[0].tails().iter().zip(&rest) {
                assert!(a.distance(*b) < 1e-5, "{a} moved from {b}");
            }
        });
        assert!(rest[2].abs_diff_eq(Vec3::new(0.6, 2.0, 0.0), 1e-6));
    }

    #[test]
    fn under_gravity_alone_a_chain_settles_hanging_straight_down() {
        let rig = chain_rig(Vec3::X);
        let params = SpringParams {
            stiffness: 0.0,
            gravity: 2.0,
            drag: 0.4,
            hit_radius: 0.0,
            ..Default::default()
        };
        let mut springs = system(&rig, Vec3::X, params, vec![]);
        simulate(&rig, &mut springs, 300, |_, _| {});
        let tails = springs.chains[0].tails();
        let heads = [Vec3::new(0.0, 2.0, 0.0), tails[0], tails[1]];
        for (head, tail) in heads.iter().zip(&tails) {
            let direction = (*tail - *head).normalize();
            assert!(direction.abs_diff_eq(Vec3::NEG_Y, 1e-3), "{direction}");
        }
    }

    #[test]
    fn bone_lengths_are_kept_every_step() {
        let rig = chain_rig(Vec3::X);
        let params = SpringParams {
            stiffness: 0.3,
            gravity: 3.0,
            ..Default::default()
        };
        let mut springs = system(&rig, Vec3::X, params, vec![]);
        simulate(&rig, &mut springs, 60, |s, world| {
            let chain = &s.chains[0];
            let tails = chain.tails();
            let heads = [world[1].w_axis.truncate(), tails[0], tails[1]];
            for ((head, tail), length) in heads.iter().zip(&tails).zip(chain.lengths()) {
                assert!((head.distance(*tail) - length).abs() < 1e-5);
            }
            // The joints' world matrices agree with the simulated tails.
            assert!(world[2].w_axis.truncate().abs_diff_eq(tails[0], 1e-4));
            assert!(world[3].w_axis.truncate().abs_diff_eq(tails[1], 1e-4));
        });
    }

    #[test]
    fn colliders_are_never_penetrated() {
        let rig = chain_rig(Vec3::X);
        let params = SpringParams {
            stiffness: 0.0,
            gravity: 3.0,
            drag: 0.2,
            hit_radius: 0.01,
            ..Default::default()
        };
        // A sphere in the way of the hanging chain and a capsule across its lower end.
        let mut rig = rig;
        rig.nodes.push(Node {
            name: "ball".into(),
            parent: Some(0),
            rest: Transform {
                translation: Vec3::new(0.04, -0.3, 0.0),
                ..Default::default()
            },
        });
        rig.nodes.push(Node {
            name: "bar_a".into(),
            parent: Some(0),
            rest: Transform {
                translation: Vec3::new(-0.05, -0.55, -0.5),
                ..Default::default()
            },
        });
        rig.nodes.push(Node {
            name: "bar_b".into(),
            parent: Some(0),
            rest: Transform {
                translation: Vec3::new(-0.05, -0.55, 0.5),
                ..Default::default()
            },
        });
        let colliders = vec![
            Collider::between(4, None, 0.1),
            Collider::between(5, Some(6), 0.06),
        ];
        let mut springs = system(&rig, Vec3::X, params, colliders.clone());
        let mut checked = 0;
        let mut touching = 0;
        simulate(&rig, &mut springs, 120, |s, world| {
            for tail in s.chains[0].tails() {
                for c in &colliders {
                    let gap = tail.distance(c.closest(world, tail)) - c.radius - params.hit_radius;
                    assert!(gap > -1e-4, "tail {tail} inside a collider by {gap}");
                    checked += 1;
                    touching += usize::from(gap < 1e-3);
                }
            }
        });
        assert_eq!(checked, 120 * 3 * 2);
        assert!(
            touching > 10,
            "the chain should come to rest on the colliders ({touching})"
        );
    }
}
