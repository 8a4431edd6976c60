//! Spring chains for the loose parts of a character (skirt, hair, hat): placed from the
//! description over the part's rest-pose vertices, added to the rig as nodes and bones,
//! and blended into the part's skin weights with a smooth falloff along each chain.

use std::f32::consts::TAU;

use glam::{Mat4, Vec3};

use super::Character;
use super::character::{CharacterError, fail};
use super::description::{ChainLayout, Description, LoosePart, SpringChain};
use super::hanging::horizontal_spread;
use super::locomotion::{angle_difference, heading};
use super::rig::{Bone, Node, Transform};
use super::springs::{Chain, Collider, SpringParams, SpringSystem, median_radius};
use super::vrm::Vrm;

/// Where a part's chains hang: joint points (top to tip) per chain, and how to find a
/// vertex's place among them.
struct Layout {
    chains: Vec<Vec<Vec3>>,
    place: Box<dyn Fn(Vec3) -> Placement>,
}

/// A vertex's place: two neighbouring chains with a mix, and the fraction down the chain.
struct Placement {
    chains: (usize, usize, f32),
    down: f32,
}

/// Adds the description's spring chains to `character` (nodes, bones, skin weights) and
/// returns the simulation for them, with the description's colliders.
pub fn add_spring_chains(
    character: &mut Character,
    description: &Description,
) -> Result<SpringSystem, CharacterError> {
    let rest = character
        .rig
        .world(&character.rig.rest_pose(), Mat4::IDENTITY);
    let rest_mesh = character.rest_mesh();
    let height = rest_mesh.height();
    let forward_heading = description.forward_heading();
    let mut system = SpringSystem::default();
    let mut world = rest.clone();
    for part in &description.loose_parts {
        let vertices = character
            .skinned
            .select(part.mesh.as_deref(), &part.materials);
        if vertices.is_empty() {
            return Err(fail(
                &character.path,
                format!("loose part '{}' matches no vertices", part.name),
            ));
        }
        if part.chains == 0 || part.segments == 0 {
            return Err(fail(
                &character.path,
                format!("loose part '{}' needs chains and segments >= 1", part.name),
            ));
        }
        let parent = character.rig.find(&part.parent_bone).ok_or_else(|| {
            fail(
                &character.path,
                format!(
                    "loose part '{}': bone '{}' not found",
                    part.name, part.parent_bone
                ),
            )
        })?;
        let parent_bone = character
            .rig
            .bones
            .iter()
            .position(|b| b.node == parent)
            .ok_or_else(|| {
                fail(
                    &character.path,
                    format!(
                        "loose part '{}': '{}' is not a skin joint",
                        part.name, part.parent_bone
                    ),
                )
            })?;
        let parent_skin = rest[parent] * character.rig.bones[parent_bone].inverse_bind;
        // Bones that move vertices exactly as the parent does at rest (their weight can go
        // to the chains without changing the rest pose).
        let like_parent: Vec<bool> = character
            .rig
            .bones
            .iter()
            .map(|b| (world[b.node] * b.inverse_bind).abs_diff_eq(parent_skin, 1e-4))
            .collect();
        let points: Vec<Vec3> = vertices.iter().map(|&v| rest_mesh.positions[v]).collect();
        let layout = match part.kind {
            ChainLayout::Ring => ring(&points, part, forward_heading + std::f32::consts::PI),
            ChainLayout::Tip => tip(&points, part, rest[parent].w_axis.truncate()),
            ChainLayout::Sheet => sheet(&points, part),
        };
        // Nodes and bones, one per segment; each chain's last node carries the tip.
        let mut chain_bones = Vec::new();
        for (c, joints) in layout.chains.iter().enumerate() {
            let mut nodes = Vec::new();
            let mut bones = Vec::new();
            let mut above = parent;
            for (s, point) in joints[..part.segments].iter().enumerate() {
                let node = character.rig.nodes.len();
                character.rig.nodes.push(Node {
                    name: format!("spring.{}.{c}.{s}", part.name),
                    parent: Some(above),
                    rest: Transform {
                        translation: world[above].inverse().transform_point3(*point),
                        ..Default::default()
                    },
                });
                world.push(world[above] * character.rig.nodes[node].rest.matrix());
                // At rest this bone moves vertices exactly as the parent bone does.
                bones.push(character.rig.bone(Bone {
                    node,
                    inverse_bind: world[node].inverse() * parent_skin,
                }));
                nodes.push(node);
                above = node;
            }
            let tip_offset = world[above]
                .inverse()
                .transform_point3(joints[part.segments]);
            let params = SpringParams {
                stiffness: part.stiffness,
                drag: part.drag,
                gravity: part.gravity,
                hit_radius: 0.01 * height,
                ..Default::default()
            };
            system.chains.push(Chain::new(
                &character.rig,
                &world,
                &nodes,
                tip_offset,
                params,
            ));
            chain_bones.push(bones);
        }
        reweight(
            character,
            (&vertices, &points),
            &layout,
            &like_parent,
            &chain_bones,
            part.segments,
        );
    }
    match character.vrm.as_ref().filter(|v| !v.springs.is_empty()) {
        Some(vrm) => {
            if !description.spring_chains.is_empty() || !description.colliders.is_empty() {
                log::warn!(
                    "{}: the file's VRMC_springBone springs and colliders are used, not the description's",
                    character.path.display()
                );
            }
            vrm_springs(character, &world, vrm, &mut system)?;
        }
        None => {
            for spec in &description.spring_chains {
                system
                    .chains
                    .push(existing_chain(character, &world, spec, height)?);
            }
            for spec in &description.colliders {
                let node = |name: &str| {
                    character.rig.find(name).ok_or_else(|| {
                        fail(&character.path, format!("collider bone '{name}' not found"))
                    })
                };
                let mut collider = Collider::between(
                    node(&spec.bone)?,
                    spec.to.as_deref().map(node).transpose()?,
                    0.0,
                );
                collider.radius = spec.radius.unwrap_or_else(|| {
                    measured_radius(character, &rest, &rest_mesh.positions, &collider, height)
                });
                system.colliders.push(collider);
            }
        }
    }
    for chain in &mut system.chains {
        if chain.colliders.is_none() {
            chain.choose_colliders(&system.colliders, &world);
        }
    }
    Ok(system)
}

/// The file's own VRM springs and colliders: each spring's joints but the last swing (the
/// last is only a tail), with its settings per joint, kept out of its collider groups.
fn vrm_springs(
    character: &Character,
    world: &[Mat4],
    vrm: &Vrm,
    system: &mut SpringSystem,
) -> Result<(), CharacterError> {
    let rig = &character.rig;
    let base = system.colliders.len();
    for c in &vrm.colliders {
        let scale = world[c.node].x_axis.truncate().length();
        system.colliders.push(Collider {
            node: c.node,
            offset: c.offset,
            end: c.tail.map(|t| (c.node, t)),
            radius: c.radius * scale,
        });
    }
    for (s, spring) in vrm.springs.iter().enumerate() {
        let field = |j: usize| format!("VRMC_springBone.springs[{s}].joints[{j}]");
        for (j, pair) in spring.joints.windows(2).enumerate() {
            let mut above = rig.nodes[pair[1].node].parent;
            while above.is_some_and(|a| a != pair[0].node) {
                above = above.and_then(|a| rig.nodes[a].parent);
            }
            if above.is_none() {
                return Err(fail(
                    &character.path,
                    format!(
                        "{}: node '{}' is not below the joint before it, '{}'",
                        field(j + 1),
                        rig.nodes[pair[1].node].name,
                        rig.nodes[pair[0].node].name
                    ),
                ));
            }
        }
        if rig.nodes[spring.joints[0].node].parent.is_none() {
            return Err(fail(
                &character.path,
                format!("{}: a spring's root needs a parent node", field(0)),
            ));
        }
        let Some((tail, swinging)) = spring.joints.split_last().filter(|(_, s)| !s.is_empty())
        else {
            log::warn!(
                "{}: spring {s} ('{}') has one joint, only a tail: nothing swings",
                character.path.display(),
                spring.name
            );
            continue;
        };
        let nodes: Vec<usize> = swinging.iter().map(|j| j.node).collect();
        // Radii are in the node's units, as the collider's are: scaled to the world.
        let params: Vec<SpringParams> = swinging
            .iter()
            .map(|j| SpringParams {
                stiffness: j.stiffness,
                drag: j.drag,
                gravity: j.gravity_power,
                gravity_dir: j.gravity_dir.normalize_or(Vec3::NEG_Y),
                hit_radius: j.hit_radius * world[j.node].x_axis.truncate().length(),
            })
            .collect();
        let last = *nodes.last().expect("one joint swings");
        let tip = world[last]
            .inverse()
            .transform_point3(world[tail.node].w_axis.truncate());
        let mut chain = Chain::with_joint_params(rig, world, &nodes, tip, &params);
        let mut colliders: Vec<usize> = spring
            .collider_groups
            .iter()
            .flat_map(|&g| vrm.collider_groups[g].iter().map(|&c| base + c))
            .collect();
        colliders.sort_unstable();
        colliders.dedup();
        chain.colliders = Some(colliders);
        system.chains.push(chain);
    }
    Ok(())
}

/// A spring chain over nodes already in the rig: `spec.root` down through first
/// children; the tail runs on past the last node by half its parent segment.
fn existing_chain(
    character: &Character,
    world: &[Mat4],
    spec: &SpringChain,
    height: f32,
) -> Result<Chain, CharacterError> {
    let rig = &character.rig;
    let root = rig
        .find(&spec.root)
        .filter(|&n| rig.nodes[n].parent.is_some())
        .ok_or_else(|| {
            fail(
                &character.path,
                format!(
                    "spring chain root '{}' is not a node with a parent",
                    spec.root
                ),
            )
        })?;
    let mut nodes = vec![root];
    while let Some(child) =
        (0..rig.nodes.len()).find(|&c| rig.nodes[c].parent == nodes.last().copied())
    {
        nodes.push(child);
    }
    let last = *nodes.last().expect("the root");
    let before = rig.nodes[last].parent.expect("checked above");
    let head = world[last].w_axis.truncate();
    let tip = head + 0.5 * (head - world[before].w_axis.truncate());
    let params = SpringParams {
        stiffness: spec.stiffness,
        drag: spec.drag,
        gravity: spec.gravity,
        hit_radius: 0.01 * height,
        ..Default::default()
    };
    Ok(Chain::new(
        rig,
        world,
        &nodes,
        world[last].inverse().transform_point3(tip),
        params,
    ))
}

/// Chains around a vertical axis through the part, over `arc_degrees` centred on the
/// back; each joint sits on the part's outer surface at its height and angle.
fn ring(points: &[Vec3], part: &LoosePart, back: f32) -> Layout {
    let centre = points
        .iter()
        .map(|p| Vec3::new(p.x, 0.0, p.z))
        .sum::<Vec3>()
        / points.len() as f32;
    let top = points.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    let bottom = points.iter().map(|p| p.y).fold(f32::MAX, f32::min);
    let span = (top - bottom).max(1e-4);
    let arc = part.arc_degrees.to_radians().clamp(1e-3, TAU);
    let spacing = arc / part.chains as f32;
    let start = back - arc / 2.0;
    let chain_heading = |k: usize| start + spacing * (k as f32 + 0.5);
    let polar: Vec<(f32, f32, f32)> = points
        .iter()
        .map(|p| {
            let d = Vec3::new(p.x, 0.0, p.z) - centre;
            (heading(d), d.length(), p.y)
        })
        .collect();
    let band = span / part.segments as f32;
    let chains = (0..part.chains)
        .map(|k| {
            let h = chain_heading(k);
            (0..=part.segments)
                .map(|s| {
                    let y = top - span * s as f32 / part.segments as f32;
                    let near = |window: f32| {
                        polar
                            .iter()
                            .filter(|(a, _, py)| {
                                angle_difference(h, *a).abs() <= window && (py - y).abs() <= band
                            })
                            .map(|(_, r, _)| *r)
                            .fold(0.0f32, f32::max)
                    };
                    let r = [spacing / 2.0, spacing, TAU]
                        .into_iter()
                        .map(near)
                        .find(|&r| r > 0.0)
                        .unwrap_or(0.0);
                    centre + Vec3::new(h.sin() * r, y, h.cos() * r)
                })
                .collect()
        })
        .collect();
    let chains_n = part.chains;
    let full = arc >= TAU - 1e-3;
    Layout {
        chains,
        place: Box::new(move |p: Vec3| {
            let a =
                angle_difference(start, heading(Vec3::new(p.x, 0.0, p.z) - centre)).rem_euclid(TAU);
            let position = a / spacing - 0.5;
            let (k0, k1, mix) = if full {
                let k0 = position.floor().rem_euclid(chains_n as f32) as usize;
                (k0, (k0 + 1) % chains_n, position - position.floor())
            } else {
                let clamped = position.clamp(0.0, (chains_n - 1) as f32);
                let k0 = clamped.floor() as usize;
                (k0, (k0 + 1).min(chains_n - 1), clamped - k0 as f32)
            };
            Placement {
                chains: (k0, k1, mix),
                down: ((top - p.y) / span).clamp(0.0, 1.0),
            }
        }),
    }
}

/// Chains side by side across the part's widest horizontal direction, each from its top
/// to its bottom; each joint sits at the mean depth of the part's vertices near it.
fn sheet(points: &[Vec3], part: &LoosePart) -> Layout {
    let (centre, across, _, _) = horizontal_spread(points);
    let depth_axis = Vec3::Y.cross(across);
    let top = points.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    let bottom = points.iter().map(|p| p.y).fold(f32::MAX, f32::min);
    let span = (top - bottom).max(1e-4);
    let side = move |p: &Vec3| (*p - centre).dot(across);
    let (left, right) = points.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(side(p)), hi.max(side(p)))
    });
    let width = (right - left).max(1e-4);
    let spacing = width / part.chains as f32;
    let band = span / part.segments as f32;
    let chains = (0..part.chains)
        .map(|k| {
            let s = left + spacing * (k as f32 + 0.5);
            (0..=part.segments)
                .map(|j| {
                    let y = top - span * j as f32 / part.segments as f32;
                    // The mean depth of the vertices nearest this joint: within half a
                    // spacing and a band when there are any, else the widest window.
                    let depth = [(spacing / 2.0, band), (spacing, band), (width, span)]
                        .into_iter()
                        .find_map(|(w, h)| {
                            let near: Vec<f32> = points
                                .iter()
                                .filter(|p| (side(p) - s).abs() <= w && (p.y - y).abs() <= h)
                                .map(|p| (*p - centre).dot(depth_axis))
                                .collect();
                            (!near.is_empty()).then(|| near.iter().sum::<f32>() / near.len() as f32)
                        })
                        .unwrap_or(0.0);
                    centre + across * s + depth_axis * depth + Vec3::Y * y
                })
                .collect()
        })
        .collect();
    let last = part.chains - 1;
    Layout {
        chains,
        place: Box::new(move |p: Vec3| {
            let position = ((side(&p) - left) / spacing - 0.5).clamp(0.0, last as f32);
            let k0 = position.floor() as usize;
            Placement {
                chains: (k0, (k0 + 1).min(last), position - k0 as f32),
                down: ((top - p.y) / span).clamp(0.0, 1.0),
            }
        }),
    }
}

/// One chain from the part's base (its vertices nearest the parent joint) to its vertex
/// farthest from the parent joint.
fn tip(points: &[Vec3], part: &LoosePart, joint: Vec3) -> Layout {
    let far = points
        .iter()
        .copied()
        .max_by(|a, b| a.distance(joint).total_cmp(&b.distance(joint)))
        .expect("points");
    let mut by_distance: Vec<Vec3> = points.to_vec();
    by_distance.sort_by(|a, b| a.distance(joint).total_cmp(&b.distance(joint)));
    let near = &by_distance[..(by_distance.len() * 3 / 10).max(1)];
    let base = near.iter().sum::<Vec3>() / near.len() as f32;
    let chain = (0..=part.segments)
        .map(|s| base.lerp(far, s as f32 / part.segments as f32))
        .collect();
    let axis = far - base;
    Layout {
        chains: vec![chain],
        place: Box::new(move |p: Vec3| Placement {
            chains: (0, 0, 0.0),
            down: ((p - base).dot(axis) / axis.length_squared().max(1e-12)).clamp(0.0, 1.0),
        }),
    }
}

fn smoothstep(edge: f32, x: f32) -> f32 {
    let t = (x / edge).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Blends chain weights into the part's vertices: none at the part's top (it follows the
/// parent), from a third of the way down all the weight of bones that are at rest like
/// the parent.
fn reweight(
    character: &mut Character,
    part: (&[usize], &[Vec3]),
    layout: &Layout,
    like_parent: &[bool],
    chain_bones: &[Vec<usize>],
    segments: usize,
) {
    let (vertices, points) = part;
    for (&v, &p) in vertices.iter().zip(points) {
        let place = (layout.place)(p);
        let share = smoothstep(0.35, place.down);
        let along = place.down * segments as f32;
        let s = (along.floor() as usize).min(segments - 1);
        let g = along - s as f32;
        // Within a chain: this segment's joint, blended with the one above near its top.
        let in_chain = |bones: &Vec<usize>| -> Vec<(usize, f32)> {
            if s > 0 && g < 0.5 {
                vec![(bones[s], 0.5 + g), (bones[s - 1], 0.5 - g)]
            } else {
                vec![(bones[s], 1.0)]
            }
        };
        let (k0, k1, mix) = place.chains;
        // The chain bones equal the parent bone at rest, as do the bones `like_parent`, so
        // weight moved among them (and folded together when there are too many) keeps the
        // rest pose exact.
        let mut others: Vec<(usize, f32)> = Vec::new();
        let mut group: Vec<(usize, f32)> = Vec::new();
        let add = |list: &mut Vec<(usize, f32)>, bone: usize, w: f32| match list
            .iter_mut()
            .find(|(b, _)| *b == bone)
        {
            Some(entry) => entry.1 += w,
            None => list.push((bone, w)),
        };
        for k in 0..4 {
            let (bone, w) = (
                character.skinned.joints[v][k] as usize,
                character.skinned.weights[v][k],
            );
            if w == 0.0 {
                continue;
            }
            if like_parent[bone] {
                add(&mut group, bone, w * (1.0 - share));
                for (chain_bone, cw) in in_chain(&chain_bones[k0]) {
                    add(&mut group, chain_bone, cw * w * share * (1.0 - mix));
                }
                for (chain_bone, cw) in in_chain(&chain_bones[k1]) {
                    add(&mut group, chain_bone, cw * w * share * mix);
                }
            } else {
                add(&mut others, bone, w);
            }
        }
        group.retain(|(_, w)| *w > 0.0);
        group.sort_by(|a, b| b.1.total_cmp(&a.1));
        let slots = 4 - others.len().min(4);
        if group.len() > slots && slots > 0 {
            let folded: f32 = group[slots..].iter().map(|(_, w)| w).sum();
            group.truncate(slots);
            group[0].1 += folded;
        }
        let mut weights = others;
        weights.extend(group);
        weights.truncate(4);
        let total: f32 = weights.iter().map(|(_, w)| w).sum();
        let mut joints = [0u16; 4];
        let mut ws = [0.0f32; 4];
        for (k, (bone, w)) in weights.into_iter().enumerate() {
            joints[k] = bone as u16;
            ws[k] = w / total;
        }
        character.skinned.joints[v] = joints;
        character.skinned.weights[v] = ws;
    }
}

/// A collider's radius from the vertices its bone mostly moves: their median distance to
/// the collider's axis, within 2-15 % of the character's height.
fn measured_radius(
    character: &Character,
    rest: &[Mat4],
    positions: &[Vec3],
    collider: &Collider,
    height: f32,
) -> f32 {
    let bones: Vec<usize> = (0..character.rig.bones.len())
        .filter(|&b| character.rig.bones[b].node == collider.node)
        .collect();
    let distances: Vec<f32> = (0..positions.len())
        .filter(|&v| {
            bones.contains(&(character.skinned.joints[v][0] as usize))
                && character.skinned.weights[v][0] > 0.5
        })
        .map(|v| positions[v].distance(collider.closest(rest, positions[v])))
        .collect();
    median_radius(distances, height)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sheet_hangs_its_chains_evenly_across_the_part() {
        // A 1 m wide, 2 m tall sheet at z = -0.5: chains at x = -0.3, 0 and 0.3 (centres
        // of thirds), joints every 0.5 m from y = 2 down to 0, on the sheet.
        let mut points = Vec::new();
        for i in 0..=10 {
            for j in 0..=20 {
                points.push(Vec3::new(-0.5 + i as f32 * 0.1, j as f32 * 0.1, -0.5));
            }
        }
        let part = LoosePart {
            name: "cape".into(),
            kind: ChainLayout::Sheet,
            mesh: None,
            materials: Vec::new(),
            parent_bone: "chest".into(),
            chains: 3,
            segments: 4,
            arc_degrees: 360.0,
            stiffness: 1.0,
            drag: 0.4,
            gravity: 0.5,
        };
        let layout = sheet(&points, &part);
        assert_eq!(layout.chains.len(), 3);
        for (k, chain) in layout.chains.iter().enumerate() {
            assert_eq!(chain.len(), 5);
            for (s, joint) in chain.iter().enumerate() {
                let expected = Vec3::new(-1.0 / 3.0 + k as f32 / 3.0, 2.0 - 0.5 * s as f32, -0.5);
                assert!(
                    joint.abs_diff_eq(expected, 1e-4),
                    "chain {k} joint {s}: {joint}"
                );
            }
        }
        // A vertex halfway between the first two chains, a quarter of the way down.
        let place = (layout.place)(Vec3::new(-1.0 / 6.0, 1.5, -0.5));
        let (k0, k1, mix) = place.chains;
        assert_eq!((k0, k1), (0, 1));
        assert!((mix - 0.5).abs() < 1e-4 && (place.down - 0.25).abs() < 1e-4);
        // Beyond the last chain: all on it.
        let place = (layout.place)(Vec3::new(0.5, 0.0, -0.5));
        assert_eq!((place.chains.0, place.chains.2), (2, 0.0));
        assert!((place.down - 1.0).abs() < 1e-6);
    }
}
