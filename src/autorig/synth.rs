//! Synthetic training characters: a random skeleton tree from a humanoid, quadruped or
//! winged/tailed creature pattern with random proportions (humanoids also chibi or
//! long-limbed, arms held out or resting against the body), posed at random, a surface
//! grown around its bones (smooth union of tapered capsules, meshed by surface nets),
//! open sheets hung on spring chains (skirts, coat tails, capes, hair cards), and
//! ground-truth skin weights (each vertex to the bone that grew it, blended linearly with
//! the neighbouring joints near each end, as artists paint; a sheet's vertices blended
//! between the chains on either side).

use glam::Vec3;

use super::skeleton::{Class, Skeleton};
use super::synth_mesh::{sheet_mesh, skin_of, smooth_min, surface_nets};
use super::synth_skeleton::{Style, creature, humanoid, quadruped, random_pose};
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
    use crate::autorig::synth_mesh::along_chain;
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
