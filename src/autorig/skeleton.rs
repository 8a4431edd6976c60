//! The skeleton the auto-rigger predicts: joints as positions with parents, names and a
//! spring flag, the humanoid template (body and hands, named as our rigs name them), the
//! unit-cube normalisation the tokens use, and the skeleton of an existing rig.

use glam::Vec3;

use crate::avatar::Character;

/// What kind of character a skeleton belongs to: the class token of the sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// Body (and optionally hands) follow the humanoid template.
    Humanoid,
    Quadruped,
    /// Any other tree (tails, wings, creatures).
    Other,
}

impl Class {
    pub const ALL: [Class; 3] = [Class::Humanoid, Class::Quadruped, Class::Other];
}

/// A joint tree in parent-before-child order.
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    pub class: Class,
    pub joints: Vec<Vec3>,
    pub parents: Vec<Option<usize>>,
    /// Template name for template joints, a generated one for the rest.
    pub names: Vec<String>,
    /// Joints driven by spring physics (hair, skirt, tails), not by clips.
    pub spring: Vec<bool>,
}

/// The humanoid template's body: (name, parent index in this list).
pub const BODY: [(&str, Option<usize>); 20] = [
    ("Hips", None),
    ("Abdomen", Some(0)),
    ("Torso", Some(1)),
    ("Chest", Some(2)),
    ("Neck", Some(3)),
    ("Head", Some(4)),
    ("Shoulder.L", Some(3)),
    ("UpperArm.L", Some(6)),
    ("LowerArm.L", Some(7)),
    ("Wrist.L", Some(8)),
    ("Shoulder.R", Some(3)),
    ("UpperArm.R", Some(10)),
    ("LowerArm.R", Some(11)),
    ("Wrist.R", Some(12)),
    ("UpperLeg.L", Some(0)),
    ("LowerLeg.L", Some(14)),
    ("Foot.L", Some(15)),
    ("UpperLeg.R", Some(0)),
    ("LowerLeg.R", Some(17)),
    ("Foot.R", Some(18)),
];

/// Fingers of one hand, each a chain from the wrist: (name stem, joints).
pub const FINGERS: [(&str, usize); 5] = [
    ("Thumb", 3),
    ("Index", 4),
    ("Middle", 4),
    ("Ring", 4),
    ("Pinky", 4),
];

/// The hands part of the template: names with their parent names, left hand first.
pub fn hand_joints() -> Vec<(String, String)> {
    let mut out = Vec::new();
    for side in ["L", "R"] {
        for (stem, count) in FINGERS {
            for k in 1..=count {
                let parent = if k == 1 {
                    format!("Wrist.{side}")
                } else {
                    format!("{stem}{}.{side}", k - 1)
                };
                out.push((format!("{stem}{k}.{side}"), parent));
            }
        }
    }
    out
}

/// All template joints in token order (body, then hands) with their parent names.
pub fn template_joints(hands: bool) -> Vec<(String, Option<String>)> {
    let mut out: Vec<(String, Option<String>)> = BODY
        .iter()
        .map(|(name, parent)| (name.to_string(), parent.map(|p| BODY[p].0.to_string())))
        .collect();
    if hands {
        out.extend(hand_joints().into_iter().map(|(n, p)| (n, Some(p))));
    }
    out
}

/// Maps mesh coordinates into the unit cube [-1, 1]³: centre of the bounds, largest
/// half-extent to 1 (the same for all axes so shapes keep their proportions).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnitCube {
    pub centre: Vec3,
    pub half_extent: f32,
}

impl UnitCube {
    pub fn of_points(points: &[Vec3]) -> Self {
        let (lo, hi) = points.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), &p| (lo.min(p), hi.max(p)),
        );
        let half_extent = ((hi - lo) * 0.5).max_element().max(1e-6);
        Self {
            centre: (lo + hi) * 0.5,
            half_extent,
        }
    }

    pub fn to_unit(&self, p: Vec3) -> Vec3 {
        (p - self.centre) / self.half_extent
    }

    pub fn from_unit(&self, p: Vec3) -> Vec3 {
        p * self.half_extent + self.centre
    }

    /// `mesh` moved into the cube (normals keep their directions: the map is uniform).
    pub fn mesh_to_unit(&self, mesh: &crate::mesh::Mesh) -> crate::mesh::Mesh {
        crate::mesh::Mesh {
            positions: mesh.positions.iter().map(|&p| self.to_unit(p)).collect(),
            ..mesh.clone()
        }
    }
}

impl Skeleton {
    pub fn len(&self) -> usize {
        self.joints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.joints.is_empty()
    }

    pub fn children(&self, joint: usize) -> impl Iterator<Item = usize> + '_ {
        (0..self.len()).filter(move |&c| self.parents[c] == Some(joint))
    }

    /// The bone ending at `joint` as a segment (parent joint, joint); none for a root.
    pub fn bone(&self, joint: usize) -> Option<(Vec3, Vec3)> {
        self.parents[joint].map(|p| (self.joints[p], self.joints[joint]))
    }

    /// The bones as segments (parent joint, joint), one per non-root joint.
    pub fn bones(&self) -> Vec<(Vec3, Vec3)> {
        (0..self.len()).filter_map(|j| self.bone(j)).collect()
    }

    /// The same skeleton with every joint mapped by `f`.
    pub fn map_joints(&self, f: impl Fn(Vec3) -> Vec3) -> Skeleton {
        Skeleton {
            joints: self.joints.iter().map(|&p| f(p)).collect(),
            ..self.clone()
        }
    }

    /// The joints where `keep` holds and whose ancestors all do, in order, re-indexed.
    pub fn keep(&self, keep: impl Fn(usize) -> bool) -> Skeleton {
        let mut index = vec![None; self.len()];
        let mut out = Skeleton {
            class: self.class,
            joints: Vec::new(),
            parents: Vec::new(),
            names: Vec::new(),
            spring: Vec::new(),
        };
        for j in 0..self.len() {
            let parent_kept = self.parents[j].map(|p| index[p]);
            if !keep(j) || parent_kept == Some(None) {
                continue;
            }
            index[j] = Some(out.len());
            out.joints.push(self.joints[j]);
            out.parents.push(parent_kept.flatten());
            out.names.push(self.names[j].clone());
            out.spring.push(self.spring[j]);
        }
        out
    }

    /// The skeleton without the template's finger joints (and anything below them).
    pub fn without_hands(&self) -> Skeleton {
        let fingers: Vec<String> = hand_joints().into_iter().map(|(n, _)| n).collect();
        self.keep(|j| !fingers.contains(&self.names[j]))
    }

    /// Whether joints come before their children (the order every consumer relies on).
    pub fn is_ordered(&self) -> bool {
        self.parents
            .iter()
            .enumerate()
            .all(|(j, p)| p.is_none_or(|p| p < j))
    }
}

/// The deforming skeleton of a rigged character in its bind pose: the joints that
/// carry skin weight and their ancestors up to the template's root, each re-parented to
/// its nearest kept ancestor. Template names get the template's parents, so an IK rig
/// (feet under the root) reads as the template's chain. Humanoid when every body
/// template joint is present.
pub fn of_character(character: &Character) -> Skeleton {
    let rig = &character.rig;
    let skinned = &character.skinned;
    let world = rig.world(&rig.rest_pose(), glam::Mat4::IDENTITY);
    let mut weighted = vec![false; rig.nodes.len()];
    for (joints, weights) in skinned.joints.iter().zip(&skinned.weights) {
        for (&b, &w) in joints.iter().zip(weights) {
            if w > 0.0 {
                weighted[rig.bones[b as usize].node] = true;
            }
        }
    }
    let template = template_joints(true);
    let in_template = |name: &str| template.iter().any(|(n, _)| n == name);
    let humanoid = BODY.iter().all(|(name, _)| rig.find(name).is_some());
    let hips = rig.find("Hips");
    // Keep weighted nodes and template nodes; drop the ancestors of the template root.
    let mut above_hips = vec![false; rig.nodes.len()];
    if let Some(hips) = hips {
        let mut at = rig.nodes[hips].parent;
        while let Some(a) = at {
            above_hips[a] = true;
            at = rig.nodes[a].parent;
        }
    }
    let keep: Vec<bool> = (0..rig.nodes.len())
        .map(|n| {
            let name = &rig.nodes[n].name;
            let template_node = humanoid && in_template(name);
            (weighted[n] || template_node) && !(humanoid && above_hips[n])
        })
        .collect();
    let kept: Vec<usize> = (0..rig.nodes.len()).filter(|&n| keep[n]).collect();
    let index_of = |n: usize| kept.iter().position(|&k| k == n);
    let mut skeleton = Skeleton {
        class: if humanoid {
            Class::Humanoid
        } else {
            Class::Other
        },
        joints: kept.iter().map(|&n| world[n].w_axis.truncate()).collect(),
        parents: Vec::new(),
        names: kept.iter().map(|&n| rig.nodes[n].name.clone()).collect(),
        spring: vec![false; kept.len()],
    };
    skeleton.parents = kept
        .iter()
        .map(|&n| {
            let name = &rig.nodes[n].name;
            if humanoid && let Some((_, Some(parent))) = template.iter().find(|(t, _)| t == name) {
                return rig.find(parent).and_then(index_of);
            }
            let mut at = rig.nodes[n].parent;
            while let Some(a) = at {
                if let Some(i) = index_of(a) {
                    return Some(i);
                }
                at = rig.nodes[a].parent;
            }
            None
        })
        .collect();
    reorder_parents_first(skeleton)
}

/// Reorders joints so that every parent comes before its children (depth-first from the
/// roots, keeping the given order among siblings).
pub fn reorder_parents_first(skeleton: Skeleton) -> Skeleton {
    let n = skeleton.len();
    let mut order = Vec::with_capacity(n);
    let mut stack: Vec<usize> = (0..n)
        .rev()
        .filter(|&j| skeleton.parents[j].is_none())
        .collect();
    while let Some(j) = stack.pop() {
        order.push(j);
        let children: Vec<usize> = skeleton.children(j).collect();
        stack.extend(children.into_iter().rev());
    }
    let new_index = |old: usize| order.iter().position(|&o| o == old).expect("in order");
    Skeleton {
        class: skeleton.class,
        joints: order.iter().map(|&o| skeleton.joints[o]).collect(),
        parents: order
            .iter()
            .map(|&o| skeleton.parents[o].map(new_index))
            .collect(),
        names: order.iter().map(|&o| skeleton.names[o].clone()).collect(),
        spring: order.iter().map(|&o| skeleton.spring[o]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_hands_drops_the_fingers_and_what_hangs_from_them() {
        let template = template_joints(true);
        let mut skeleton = Skeleton {
            class: Class::Humanoid,
            joints: (0..template.len()).map(|j| Vec3::splat(j as f32)).collect(),
            parents: template
                .iter()
                .map(|(_, p)| {
                    p.as_ref()
                        .map(|p| template.iter().position(|(n, _)| n == p).unwrap())
                })
                .collect(),
            names: template.iter().map(|(n, _)| n.clone()).collect(),
            spring: vec![false; template.len()],
        };
        // A spring chain on the head and one hanging from a finger tip.
        for (name, parent) in [("Hair0", "Head"), ("Ribbon0", "Index4.L")] {
            let p = skeleton.names.iter().position(|n| n == parent).unwrap();
            skeleton.joints.push(Vec3::ZERO);
            skeleton.parents.push(Some(p));
            skeleton.names.push(name.into());
            skeleton.spring.push(true);
        }
        let body = skeleton.without_hands();
        assert_eq!(body.len(), BODY.len() + 1);
        assert!(body.is_ordered());
        for (j, (name, parent)) in BODY.iter().enumerate() {
            assert_eq!(body.names[j], *name);
            assert_eq!(body.parents[j], *parent);
            assert_eq!(body.joints[j], Vec3::splat(j as f32));
        }
        let hair = BODY.len();
        assert_eq!(body.names[hair], "Hair0");
        assert_eq!(body.parents[hair], Some(5));
        assert!(body.spring[hair]);
    }
}
