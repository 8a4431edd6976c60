//! Spring chains on a rigged mesh: which predicted chains swing, and keeping only those
//! on thin loose geometry (skirts, hair, capes, tails), snapped onto the nearest thin
//! surface that is not an arm or wrapped round a bone.

use glam::Vec3;

use super::data::{POINTS, outward_samples};
use super::skeleton::{FINGERS, Skeleton};
use super::voxel::segment_distance;
use crate::mesh::Mesh;
use crate::random::Rng;

/// The first joint of each spring chain (a spring joint under a non-spring one).
pub fn chain_roots(skeleton: &Skeleton) -> Vec<usize> {
    (0..skeleton.len())
        .filter(|&j| skeleton.spring[j] && skeleton.parents[j].is_some_and(|p| !skeleton.spring[p]))
        .collect()
}

/// The spring chains that swing something (at least two joints), each from its root.
pub fn swinging(skeleton: &Skeleton) -> Vec<Vec<usize>> {
    chain_roots(skeleton)
        .into_iter()
        .map(|root| chain_from(skeleton, root))
        .filter(|chain| chain.len() >= 2)
        .collect()
}

/// How many spring chains swing something ([`swinging`]).
pub fn swinging_chains(skeleton: &Skeleton) -> usize {
    swinging(skeleton).len()
}

/// A chain's joints: `root`, then its first spring child, and so on to the end.
fn chain_from(skeleton: &Skeleton, root: usize) -> Vec<usize> {
    let mut chain = vec![root];
    while let Some(next) = skeleton
        .children(*chain.last().expect("the root"))
        .find(|&c| skeleton.spring[c])
    {
        chain.push(next);
    }
    chain
}

/// A spring joint is on a loose part only when it lies within this share of the mesh's
/// height of its surface: hair strands, tails and cloth are thin (a joint in one, or on
/// a skirt's sheet, is within 1-3 % of the height of the surface), a joint deep in the
/// head, torso or hips is 6-10 % in, and one off the mesh is on no part at all. Measured
/// on 100 held-out synthetic characters (`unica rig-eval`, docs/autorig/report.md): 3 %
/// keeps 2.2 of 5.1 true chains per character, 4.5 % keeps 3.4, 6 % 4.2.
pub const LOOSE_DEPTH: f32 = 0.045;

/// A spring chain is on a loose part only where the body around it is thin: the median
/// [`thickness`] under the surface samples within [`LOOSE_DEPTH`] of its joints is at
/// most this share of the height. Hair strands, tails and cloth are thin (the Witch's
/// hair: 0.7 %; an open sheet counts as 0); a torso, hips or head is not (a block
/// humanoid's hips 6.7 %, its torso 13.9 %, a chibi's body 56 %).
pub const THIN_PART: f32 = 0.04;

/// The skeleton without spring joints that are not on a loose part: each spring joint
/// first moves onto the nearest thin surface within [`SNAP`] (see [`loose_springs`]);
/// then a chain stops at its first joint farther than [`LOOSE_DEPTH`] from the surface,
/// with everything below it, a chain on a thick part ([`THIN_PART`]) goes whole, and a
/// lone root left goes too; each chain left gets an end joint ([`with_chain_ends`]).
pub fn springs_on_loose_parts(skeleton: &Skeleton, mesh: &Mesh) -> Skeleton {
    let height = mesh.height();
    // As many samples as the skeleton model and `rig-eval` see.
    let (surface, normals) = outward_samples(mesh, POINTS, &mut Rng::new(0));
    let kept = loose_springs(skeleton, &surface, &normals, height);
    with_chain_ends(&kept, &surface, LOOSE_DEPTH * height)
}

/// The skeleton's spring chains that are on loose parts of the surface given by samples
/// and their outward normals (see [`springs_on_loose_parts`]), without end joints. The
/// spring joints are first snapped ([`snapped_to`]) onto thin samples: thin themselves
/// and in the median around them, off the arms ([`on_limbs`]) and not wrapped round a
/// bone ([`around_bones`]).
pub fn loose_springs(
    skeleton: &Skeleton,
    surface: &[Vec3],
    normals: &[Vec3],
    height: f32,
) -> Skeleton {
    let reach = LOOSE_DEPTH * height;
    let depth: Vec<f32> = (0..surface.len())
        .map(|i| thickness(surface, normals, i, height))
        .collect();
    let on_limb = on_limbs(skeleton, surface);
    let enclosing = around_bones(skeleton, surface, normals, &depth, height);
    // A target is on a thin part when the samples around it are (one sample's thickness
    // is 0 where its line misses the far wall's sparse samples).
    let thin_around = |i: usize| {
        let mut around: Vec<f32> = (0..surface.len())
            .filter(|&k| surface[k].distance_squared(surface[i]) <= reach * reach)
            .map(|k| depth[k])
            .collect();
        around.sort_by(f32::total_cmp);
        around[around.len() / 2] <= THIN_PART * height
    };
    let targets: Vec<Vec3> = (0..surface.len())
        .filter(|&i| {
            !on_limb[i] && !enclosing[i] && depth[i] <= THIN_PART * height && thin_around(i)
        })
        .map(|i| surface[i])
        .collect();
    let snapped = snapped_to(skeleton, &targets, SNAP * height);
    let near = springs_near(&snapped, surface, reach);
    let mut thick = vec![false; near.len()];
    for root in chain_roots(&near) {
        let chain = chain_from(&near, root);
        let joints: Vec<Vec3> = chain.iter().map(|&j| near.joints[j]).collect();
        let mut under: Vec<f32> = (0..surface.len())
            .filter(|&i| within(&joints, surface[i], reach))
            .map(|i| depth[i])
            .collect();
        under.sort_by(f32::total_cmp);
        if under.is_empty() || under[under.len() / 2] > THIN_PART * height {
            for j in chain {
                thick[j] = true;
            }
        }
    }
    near.keep(|j| !thick[j])
}

/// How far a predicted spring joint may move onto a thin part of the surface, as a share
/// of the height: the skeleton model puts chains a few centimetres inside the hips and
/// head, under the skirt or hair they should swing. Chains kept / kept along a true
/// chain per held-out humanoid with loose parts (50 each; `unica rig-eval` on `rig-data
/// --count 100 --seed 2900`, with `--plain` 5.1 true chains each, without 5.7):
///
/// | SNAP | plain generator | new generator |
/// | --- | --- | --- |
/// | 0 (none) | 0.58 / 0.42 | 0.48 / 0.30 |
/// | 5 % | 0.98 / 0.86 | 0.74 / 0.56 |
/// | 8 % | 1.80 / 1.64 | 1.06 / 0.74 |
/// | 12 % | 2.30 / 2.02 | 1.50 / 0.94 |
/// | 16 % | 2.86 / 2.28 | 1.92 / 1.14 |
///
/// None is kept on the 16 plain bodies at any of them. 12 %: three to five times as
/// many chains along a true one as without snapping; at 16 % more are kept, but fewer of
/// them along a true chain (80 % and 59 % against 88 % and 63 %).
pub const SNAP: f32 = 0.12;

/// Each spring joint moved to the nearest of `targets` within `reach` not taken by an
/// earlier joint (left where it is when none is, or when the nearest is within a tenth
/// of `reach` of where the chain's previous joint went: a chain never folds onto one
/// point, and two chains never start at one).
pub fn snapped_to(skeleton: &Skeleton, targets: &[Vec3], reach: f32) -> Skeleton {
    let mut out = skeleton.clone();
    let mut taken = vec![false; targets.len()];
    for j in 0..skeleton.len() {
        if !skeleton.spring[j] {
            continue;
        }
        let at = skeleton.joints[j];
        let Some(nearest) = (0..targets.len())
            .filter(|&t| !taken[t] && targets[t].distance(at) <= reach)
            .min_by(|&a, &b| targets[a].distance(at).total_cmp(&targets[b].distance(at)))
        else {
            continue;
        };
        // Parents come before children, so the parent has already moved.
        let parent = skeleton.parents[j].map(|p| out.joints[p]);
        if parent.is_none_or(|p| p.distance(targets[nearest]) > 0.1 * reach) {
            out.joints[j] = targets[nearest];
            taken[nearest] = true;
        }
    }
    out
}

/// Which surface samples are on a part wrapped round a bone of the skeleton (not a spring
/// bone): the point halfway to the far wall, `depth[i]` in along the inward normal, lies
/// within half that depth plus 1 % of the height (the predicted bones' slack) of a bone.
/// A slender leg is as thin as a skirt, but a skirt has no bone inside it.
pub fn around_bones(
    skeleton: &Skeleton,
    surface: &[Vec3],
    normals: &[Vec3],
    depth: &[f32],
    height: f32,
) -> Vec<bool> {
    let bones: Vec<(Vec3, Vec3)> = (0..skeleton.len())
        .filter(|&j| !skeleton.spring[j])
        .filter_map(|j| skeleton.bone(j))
        .collect();
    (0..surface.len())
        .map(|i| {
            let middle = surface[i] - 0.5 * depth[i] * normals[i];
            depth[i] > 0.0
                && bones
                    .iter()
                    .any(|&(a, b)| segment_distance(middle, a, b) <= 0.5 * depth[i] + 0.01 * height)
        })
        .collect()
}

/// Which surface samples lie nearest to an arm bone (upper arm, forearm, hand, fingers)
/// of the skeleton's humanoid template: hands and fingers are thin, but they are limbs
/// with bones of their own, not loose parts to hang springs on. All false for a
/// skeleton without those joints. (Not the neck: the head, its hair and hat are nearest
/// the neck's bone too; a slender neck is left out by [`around_bones`].)
pub fn on_limbs(skeleton: &Skeleton, surface: &[Vec3]) -> Vec<bool> {
    let limb = |name: &str| {
        let stem = name.split('.').next().unwrap_or(name);
        ["UpperArm", "LowerArm", "Wrist"].contains(&stem)
            || FINGERS.iter().any(|(finger, _)| stem.starts_with(finger))
    };
    // Each bone with whether it is an arm's (named by the joint it starts from).
    let bones: Vec<((Vec3, Vec3), bool)> = (0..skeleton.len())
        .filter(|&j| !skeleton.spring[j])
        .filter_map(|j| {
            Some((
                skeleton.bone(j)?,
                limb(&skeleton.names[skeleton.parents[j]?]),
            ))
        })
        .collect();
    surface
        .iter()
        .map(|&s| {
            bones
                .iter()
                .map(|&((a, b), arm)| (segment_distance(s, a, b), arm))
                .min_by(|x, y| x.0.total_cmp(&y.0))
                .is_some_and(|(_, arm)| arm)
        })
        .collect()
}

/// How thick the body is under surface sample `i`: the distance along its inward normal
/// to the nearest sample that faces away (the far wall), among those within 3 % of the
/// `height` of that line (the samples' spacing); 0 when no wall is found (an open sheet,
/// a card of hair).
pub fn thickness(surface: &[Vec3], normals: &[Vec3], i: usize, height: f32) -> f32 {
    let (from, inward) = (surface[i], -normals[i]);
    let (radius, skip) = (0.03 * height, 0.002 * height);
    let far = surface
        .iter()
        .zip(normals)
        .filter_map(|(&p, &n)| {
            let along = (p - from).dot(inward);
            let off = (p - from - along * inward).length();
            (along > skip && off < radius && n.dot(inward) > 0.3).then_some(along)
        })
        .fold(f32::INFINITY, f32::min);
    if far.is_finite() { far } else { 0.0 }
}

/// Whether some `surface` point lies within `reach` of `p`.
fn within(surface: &[Vec3], p: Vec3, reach: f32) -> bool {
    surface
        .iter()
        .any(|s| s.distance_squared(p) <= reach * reach)
}

/// The skeleton with an end joint below each chain's last joint, half its bone further
/// on (shortened until it is within `reach` of a `surface` point; none if even an eighth
/// is not): VRM's last joint of a spring is only a tail, so without an end the last
/// predicted joint would not swing.
pub fn with_chain_ends(skeleton: &Skeleton, surface: &[Vec3], reach: f32) -> Skeleton {
    let mut out = skeleton.clone();
    let near = |p: Vec3| within(surface, p, reach);
    for root in chain_roots(skeleton) {
        let last = *chain_from(skeleton, root).last().expect("the root");
        let Some(parent) = skeleton.parents[last] else {
            continue;
        };
        let (at, step) = (
            skeleton.joints[last],
            skeleton.joints[last] - skeleton.joints[parent],
        );
        let end = [0.5, 0.25, 0.125]
            .into_iter()
            .map(|f| at + f * step)
            .find(|&p| near(p));
        if let Some(end) = end {
            out.joints.push(end);
            out.parents.push(Some(last));
            out.names.push(format!("{}_end", skeleton.names[last]));
            out.spring.push(true);
        }
    }
    out
}

/// The skeleton without spring joints farther than `reach` from every `surface` point,
/// chains cut there and lone roots left out.
pub fn springs_near(skeleton: &Skeleton, surface: &[Vec3], reach: f32) -> Skeleton {
    let near = |p: Vec3| within(surface, p, reach);
    let keep: Vec<bool> = (0..skeleton.len())
        .map(|j| !skeleton.spring[j] || near(skeleton.joints[j]))
        .collect();
    let kept = skeleton.keep(|j| keep[j]);
    let lone: Vec<usize> = chain_roots(&kept)
        .into_iter()
        .filter(|&root| chain_from(&kept, root).len() < 2)
        .collect();
    kept.keep(|j| !lone.contains(&j))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::autorig::skeleton::Class;

    /// A body joint at the origin with three spring chains of three joints each, going
    /// up along x = 0, x = 1 and x = 2.
    fn three_chains() -> Skeleton {
        let mut s = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO],
            parents: vec![None],
            names: vec!["Body".into()],
            spring: vec![false],
        };
        for c in 0..3 {
            for k in 0..3 {
                s.parents
                    .push(Some(if k == 0 { 0 } else { s.joints.len() - 1 }));
                s.joints.push(Vec3::new(c as f32, 1.0 + k as f32, 0.0));
                s.names.push(format!("chain{c}_{k}"));
                s.spring.push(true);
            }
        }
        s
    }

    #[test]
    fn chains_are_cut_where_they_leave_the_surface_and_get_ends() {
        let skeleton = three_chains();
        assert_eq!(chain_roots(&skeleton), vec![1, 4, 7]);
        assert_eq!(swinging_chains(&skeleton), 3);
        // The surface runs along chain 0 (to y = 4), past chain 1's first joint only,
        // and nowhere near chain 2.
        let mut surface: Vec<Vec3> = (0..=40)
            .map(|i| Vec3::new(0.0, i as f32 * 0.1, 0.0))
            .collect();
        surface.push(Vec3::new(1.0, 1.0, 0.0));
        let kept = springs_near(&skeleton, &surface, 0.2);
        // Chain 0 whole; chain 1 cut to a lone root and dropped; chain 2 gone.
        assert_eq!(kept.names, ["Body", "chain0_0", "chain0_1", "chain0_2"]);
        assert_eq!(kept.parents, [None, Some(0), Some(1), Some(2)]);
        // Its end half a bone on (y = 3.5), on the surface.
        let ended = with_chain_ends(&kept, &surface, 0.2);
        assert_eq!(ended.len(), 5);
        assert_eq!(ended.names[4], "chain0_2_end");
        assert_eq!(ended.parents[4], Some(3));
        assert_eq!(ended.joints[4], Vec3::new(0.0, 3.5, 0.0));
        assert!(ended.spring[4]);
        // Where half a bone on is off the surface, the end comes closer (a quarter).
        let short: Vec<Vec3> = surface.iter().copied().filter(|p| p.y <= 3.25).collect();
        let ended = with_chain_ends(&kept, &short, 0.06);
        assert_eq!(ended.joints[4], Vec3::new(0.0, 3.25, 0.0));
    }

    /// A box 1 tall, 0.4 wide and 0.3 deep (the body) and a plate 1 cm thick beside it
    /// (a loose part), every other triangle wound the wrong way (the vertex normals say
    /// which side is out).
    fn body_and_plate() -> Mesh {
        let mut mesh = Mesh::cuboid(
            Vec3::new(-0.2, 0.0, -0.15),
            Vec3::new(0.2, 1.0, 0.15),
            Vec3::ONE,
        );
        mesh.append(Mesh::cuboid(
            Vec3::new(0.3, 0.2, -0.005),
            Vec3::new(0.5, 0.8, 0.005),
            Vec3::ONE,
        ));
        for t in mesh.indices.chunks_exact_mut(6) {
            t.swap(1, 2);
        }
        mesh
    }

    #[test]
    fn thickness_is_the_distance_to_the_far_wall() {
        let mesh = body_and_plate();
        let (surface, normals) = outward_samples(&mesh, 8000, &mut Rng::new(1));
        let mut checked = 0;
        for i in 0..surface.len() {
            let p = surface[i];
            // Samples on the box's front face away from its edges: the back wall is 0.3 in.
            if normals[i].z > 0.99 && p.x.abs() < 0.15 && (0.05..0.95).contains(&p.y) && p.z > 0.1 {
                assert!(
                    (thickness(&surface, &normals, i, 1.0) - 0.3).abs() < 1e-4,
                    "{p}"
                );
                checked += 1;
            }
            // On the plate's faces: 1 cm.
            if normals[i].z.abs() > 0.99
                && (0.35..0.45).contains(&p.x)
                && (0.25..0.75).contains(&p.y)
            {
                assert!(
                    (thickness(&surface, &normals, i, 1.0) - 0.01).abs() < 1e-4,
                    "{p}"
                );
                checked += 1;
            }
        }
        assert!(checked > 500, "{checked}");
        // A lone sheet has no far wall.
        let sheet = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            normals: vec![Vec3::Z; 3],
            colors: vec![Vec3::ONE; 3],
            indices: vec![0, 1, 2],
        };
        let (surface, normals) = outward_samples(&sheet, 100, &mut Rng::new(1));
        assert_eq!(thickness(&surface, &normals, 0, 1.0), 0.0);
    }

    #[test]
    fn spring_joints_move_to_the_nearest_target_within_reach() {
        // Body -> a -> b -> c, the last three spring joints.
        let skeleton = Skeleton {
            class: Class::Other,
            joints: vec![
                Vec3::ZERO,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.4, 0.0, 0.0),
                Vec3::new(3.0, 0.0, 0.0),
            ],
            parents: vec![None, Some(0), Some(1), Some(2)],
            names: ["Body", "a", "b", "c"].map(String::from).to_vec(),
            spring: vec![false, true, true, true],
        };
        let targets = [
            Vec3::new(0.0, 0.1, 0.0),   // near the body joint, which never moves
            Vec3::new(1.0, 0.2, 0.0),   // a's nearest (0.2 away)
            Vec3::new(1.02, 0.22, 0.0), // b's nearest (0.44), 0.03 from where a went
            Vec3::new(3.0, 0.0, 0.6),   // c's, 0.6 away
        ];
        let snapped = snapped_to(&skeleton, &targets, 0.5);
        assert_eq!(snapped.joints[0], Vec3::ZERO);
        assert_eq!(snapped.joints[1], targets[1]);
        // b would fold onto a (within a tenth of the reach): it stays.
        assert_eq!(snapped.joints[2], skeleton.joints[2]);
        // c's nearest is out of reach: it stays, until the reach is wider.
        assert_eq!(snapped.joints[3], skeleton.joints[3]);
        let snapped = snapped_to(&skeleton, &targets, 0.7);
        assert_eq!(snapped.joints[3], targets[3]);
        // Given a target of its own (0.3 away, 0.41 from a's place), b moves.
        let own = Vec3::new(1.4, 0.3, 0.0);
        let snapped = snapped_to(&skeleton, &[targets[1], own], 0.5);
        assert_eq!(snapped.joints[1], targets[1]);
        assert_eq!(snapped.joints[2], own);
        // Two chains from one place: the first takes the nearest target, the second the
        // next (never two chains from one point).
        let twins = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO, Vec3::X, Vec3::X],
            parents: vec![None, Some(0), Some(0)],
            names: ["Body", "a", "b"].map(String::from).to_vec(),
            spring: vec![false, true, true],
        };
        let near = [Vec3::new(1.0, 0.1, 0.0), Vec3::new(1.0, -0.2, 0.0)];
        let snapped = snapped_to(&twins, &near, 0.5);
        assert_eq!(snapped.joints[1..], near);
    }

    #[test]
    fn samples_nearest_an_arm_bone_are_on_the_limbs() {
        // Chest -> Shoulder.L -> UpperArm.L -> LowerArm.L -> Wrist.L -> Index1.L, and a
        // spring chain from the chest that does not count as a bone here.
        let skeleton = Skeleton {
            class: Class::Humanoid,
            joints: vec![
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.1, 1.0, 0.0),
                Vec3::new(0.2, 1.0, 0.0),
                Vec3::new(0.5, 1.0, 0.0),
                Vec3::new(0.8, 1.0, 0.0),
                Vec3::new(0.9, 1.0, 0.0),
                Vec3::new(0.0, 1.0, -0.1),
                Vec3::new(0.6, 1.0, -0.1),
            ],
            parents: vec![
                None,
                Some(0),
                Some(1),
                Some(2),
                Some(3),
                Some(4),
                Some(0),
                Some(6),
            ],
            names: [
                "Chest",
                "Shoulder.L",
                "UpperArm.L",
                "LowerArm.L",
                "Wrist.L",
                "Index1.L",
                "Spring1",
                "Spring2",
            ]
            .map(String::from)
            .to_vec(),
            spring: vec![false, false, false, false, false, false, true, true],
        };
        let surface = [
            Vec3::new(0.35, 1.05, 0.0), // upper arm
            Vec3::new(0.65, 0.95, 0.0), // forearm
            Vec3::new(0.85, 1.0, 0.05), // hand
            Vec3::new(0.15, 1.05, 0.0), // shoulder: not a limb bone
            Vec3::new(0.0, 0.9, 0.0),   // at the chest
            Vec3::new(0.5, 1.0, -0.1),  // by the spring chain, nearest the upper arm
        ];
        assert_eq!(
            on_limbs(&skeleton, &surface),
            [true, true, true, false, false, true]
        );
        // A skeleton without arm joints has no limbs.
        let plain = skeleton.keep(|j| j == 0 || j >= 6);
        assert!(on_limbs(&plain, &surface).iter().all(|&l| !l));
    }

    #[test]
    fn a_part_wrapped_round_a_bone_is_a_limb_and_a_sheet_beside_it_is_not() {
        // A bone up the y axis (a leg 10 cm across) and a spring chain at x = 1.
        let skeleton = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO, Vec3::Y, Vec3::X, Vec3::new(1.0, 1.0, 0.0)],
            parents: vec![None, Some(0), None, Some(2)],
            names: ["Knee", "Hip", "Spring0", "Spring1"]
                .map(String::from)
                .to_vec(),
            spring: vec![false, false, true, true],
        };
        let surface = [
            Vec3::new(0.05, 0.5, 0.0), // the leg's side: 10 cm to its far wall
            Vec3::new(0.2, 0.5, 0.0),  // a sheet 20 cm out: no far wall
            Vec3::new(0.2, 0.5, 0.0),  // a 10 cm plate 20 cm out: its middle is 15 cm off
            Vec3::new(1.05, 0.5, 0.0), // round the spring chain only
        ];
        let normals = [Vec3::X; 4];
        let depth = [0.1, 0.0, 0.1, 0.1];
        let height = 2.0; // slack: 2 cm
        assert_eq!(
            around_bones(&skeleton, &surface, &normals, &depth, height),
            [true, false, false, false]
        );
        // Half the depth plus the slack: a bone 6.5 cm from the middle of the 10 cm leg
        // is within 5 + 2 cm, one 7.5 cm off is not.
        let off = skeleton.map_joints(|p| p + Vec3::new(-0.065, 0.0, 0.0));
        assert!(around_bones(&off, &surface, &normals, &depth, height)[0]);
        let far = skeleton.map_joints(|p| p + Vec3::new(-0.075, 0.0, 0.0));
        assert!(!around_bones(&far, &surface, &normals, &depth, height)[0]);
    }

    #[test]
    fn chains_on_a_thick_body_go_and_chains_on_a_thin_part_stay() {
        let mut skeleton = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::new(0.0, 0.5, 0.0)],
            parents: vec![None],
            names: vec!["Body".into()],
            spring: vec![false],
        };
        // Chain "plate" down the plate's middle; chain "back" 4 cm under the box's back
        // face (within LOOSE_DEPTH of the surface, but in a body 30 cm deep).
        for (name, x, z) in [("plate", 0.4, 0.0), ("back", 0.0, -0.11)] {
            for (k, y) in [0.7, 0.5, 0.3].into_iter().enumerate() {
                skeleton
                    .parents
                    .push(Some(if k == 0 { 0 } else { skeleton.joints.len() - 1 }));
                skeleton.joints.push(Vec3::new(x, y, z));
                skeleton.names.push(format!("{name}{k}"));
                skeleton.spring.push(true);
            }
        }
        let kept = springs_on_loose_parts(&skeleton, &body_and_plate());
        assert_eq!(
            kept.names,
            ["Body", "plate0", "plate1", "plate2", "plate2_end"]
        );
    }
}
