//! The avatar description: what the teacher needs to know about a character that its
//! file does not say (which clips are idle/walk/run, the waist and feet, loose parts,
//! colliders). A JSON file beside the character, a shipped one, or inferred defaults.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use glam::Vec3;

use super::Character;
use super::character::{CharacterError, fail};
use super::clip::Clip;
use super::hanging::hanging_parts;

/// Descriptions shipped with unica, by lower-case character file stem.
const SHIPPED: &[(&str, &str)] = &[(
    "witch",
    include_str!("../../assets/avatars/witch.avatar.json"),
)];

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Description {
    pub clips: ClipNames,
    /// Bones whose mean position is the root (the waist).
    pub waist_bones: Vec<String>,
    /// Foot bones, used to measure each clip's ground speed.
    pub feet: Vec<String>,
    /// The character's facing axis in its own space: "+z", "-z", "+x" or "-x".
    #[serde(default = "default_forward")]
    pub forward: String,
    /// Ground speeds in m/s; measured from the feet in the clips when absent.
    #[serde(default)]
    pub walk_speed: Option<f32>,
    #[serde(default)]
    pub run_speed: Option<f32>,
    #[serde(default)]
    pub loose_parts: Vec<LoosePart>,
    #[serde(default)]
    pub colliders: Vec<ColliderSpec>,
    /// Spring chains already in the rig (as `unica rig` writes them).
    #[serde(default)]
    pub spring_chains: Vec<SpringChain>,
    /// What [`Description::infer`] inferred, in one line (none for a written description).
    #[serde(skip)]
    pub inferred: Option<String>,
}

/// A chain of existing rig nodes driven by spring physics: `root` and its descendants
/// through first children down to a leaf.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SpringChain {
    pub root: String,
    #[serde(default = "default_stiffness")]
    pub stiffness: f32,
    #[serde(default = "default_drag")]
    pub drag: f32,
    #[serde(default = "default_gravity")]
    pub gravity: f32,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ClipNames {
    pub idle: String,
    pub walk: String,
    pub run: String,
}

/// The most spring chains one loose part may ask for, and segments per chain.
pub const MAX_CHAINS: usize = 64;
pub const MAX_SEGMENTS: usize = 32;

/// How spring chains are laid out over a loose part.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ChainLayout {
    /// Chains hang around a vertical axis (skirt, long hair): from the part's top to its
    /// bottom at evenly spaced angles over `arc_degrees`, centred on the back.
    Ring,
    /// One chain from the part's base to its point farthest from the parent bone (hat tip).
    Tip,
    /// Chains hang side by side across a flat part (a cape, a banner): each from the
    /// part's top to its bottom, evenly spaced across its widest horizontal extent.
    Sheet,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LoosePart {
    pub name: String,
    pub kind: ChainLayout,
    /// Vertices of this mesh (node name) ...
    #[serde(default)]
    pub mesh: Option<String>,
    /// ... with one of these materials (any when empty).
    #[serde(default)]
    pub materials: Vec<String>,
    /// The bone the chains hang from.
    pub parent_bone: String,
    pub chains: usize,
    pub segments: usize,
    #[serde(default = "full_circle")]
    pub arc_degrees: f32,
    /// Spring parameters (see `springs::SpringParams`).
    #[serde(default = "default_stiffness")]
    pub stiffness: f32,
    #[serde(default = "default_drag")]
    pub drag: f32,
    #[serde(default = "default_gravity")]
    pub gravity: f32,
}

fn default_stiffness() -> f32 {
    1.0
}

fn default_drag() -> f32 {
    0.4
}

fn default_gravity() -> f32 {
    0.5
}

/// A collider around a bone: a sphere at `bone`, or a capsule from `bone` to `to`.
/// The radius is measured from the vertices the bone moves when absent.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ColliderSpec {
    pub bone: String,
    #[serde(default)]
    pub to: Option<String>,
    #[serde(default)]
    pub radius: Option<f32>,
}

fn default_forward() -> String {
    "+z".into()
}

fn full_circle() -> f32 {
    360.0
}

impl Description {
    /// The heading (rotation about +Y, 0 = +Z) of the character's own forward axis.
    pub fn forward_heading(&self) -> f32 {
        match self.forward.as_str() {
            "-z" => std::f32::consts::PI,
            "+x" => std::f32::consts::FRAC_PI_2,
            "-x" => -std::f32::consts::FRAC_PI_2,
            _ => 0.0,
        }
    }

    /// The description for `character`: `explicit` if given, else `<file>.avatar.json`
    /// beside the character, else a shipped one for its name, else inferred (printing what
    /// was inferred in one line on standard error).
    pub fn find(character: &Character, explicit: Option<&Path>) -> Result<Self, CharacterError> {
        if let Some(path) = explicit {
            return Self::read(path);
        }
        let beside: PathBuf = character.path.with_extension("avatar.json");
        if beside.is_file() {
            return Self::read(&beside);
        }
        let stem = character.name.to_lowercase();
        if let Some((_, text)) = SHIPPED.iter().find(|(name, _)| *name == stem) {
            return Self::parse(text, Path::new(&format!("<shipped {stem}.avatar.json>")));
        }
        let inferred = Self::infer(character)?;
        if let Some(line) = &inferred.inferred {
            eprintln!("{}: {line}", character.path.display());
        }
        Ok(inferred)
    }

    pub fn read(path: &Path) -> Result<Self, CharacterError> {
        let text = std::fs::read_to_string(path).map_err(|e| fail(path, e.to_string()))?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, CharacterError> {
        let description: Self =
            serde_json::from_str(text).map_err(|e| fail(path, e.to_string()))?;
        if !["+z", "-z", "+x", "-x"].contains(&description.forward.as_str()) {
            return Err(fail(
                path,
                format!(
                    "forward '{}' is not one of +z -z +x -x",
                    description.forward
                ),
            ));
        }
        for part in &description.loose_parts {
            let bad =
                |problem: String| Err(fail(path, format!("loose part '{}': {problem}", part.name)));
            if !(1..=MAX_CHAINS).contains(&part.chains)
                || !(1..=MAX_SEGMENTS).contains(&part.segments)
            {
                return bad(format!(
                    "{} chains of {} segments (1 to {MAX_CHAINS} chains of 1 to {MAX_SEGMENTS} are possible)",
                    part.chains, part.segments
                ));
            }
            let values = [part.arc_degrees, part.stiffness, part.drag, part.gravity];
            if values.iter().any(|v| !v.is_finite())
                || !(part.arc_degrees > 0.0 && part.arc_degrees <= 360.0)
            {
                return bad(format!(
                    "arc_degrees, stiffness, drag and gravity must be finite (arc in (0, 360]): {values:?}"
                ));
            }
        }
        for (name, speed) in [
            ("walk_speed", description.walk_speed),
            ("run_speed", description.run_speed),
        ] {
            if speed.is_some_and(|v| !(v.is_finite() && v > 0.0 && v < 1000.0)) {
                return Err(fail(
                    path,
                    format!("{name} {speed:?} is not a speed in (0, 1000) m/s"),
                ));
            }
        }
        if let Some(c) = description
            .colliders
            .iter()
            .find(|c| c.radius.is_some_and(|r| !(r.is_finite() && r > 0.0)))
        {
            return Err(fail(
                path,
                format!(
                    "collider '{}': radius {:?} is not a positive number",
                    c.bone, c.radius
                ),
            ));
        }
        Ok(description)
    }

    /// Inferred defaults: the waist and feet from the file's VRM humanoid map (hips,
    /// leftFoot, rightFoot), else from the names of bones that deform the mesh (hips or
    /// pelvis; foot or ankle), else from the skeleton ([`legs`]); each clip role from clip
    /// names (containing idle/walk/run), else from the motion ([`assign_roles`] on each
    /// clip's [`stance_speed`]); loose parts (with leg colliders) for rigid meshes that
    /// hang from a joint ([`hanging_loose_parts`]). `inferred` says what was
    /// inferred, in one line.
    pub fn infer(character: &Character) -> Result<Self, CharacterError> {
        if character.clips.is_empty() {
            return Err(fail(
                &character.path,
                "the file has no animation clips; give animation files with --clips FILE… \
                 (glTF/GLB with idle/walk/run clips on the same joint names)",
            ));
        }
        let rig = &character.rig;
        // Only bones that move vertices: rigs exported with IK and control helpers name
        // some of them after the foot (`control-foot-roll.l`, `IK-foot.l`), and those
        // stand still while the foot walks.
        let deforms = deforming_nodes(character);
        let bones = |words: &[&str]| -> Vec<usize> {
            (0..rig.nodes.len())
                .filter(|&n| {
                    let name = rig.nodes[n].name.to_lowercase();
                    deforms[n] && words.iter().any(|w| name.contains(w))
                })
                .collect()
        };
        let (named_waist, named_feet) = (bones(&["hips", "pelvis"]), bones(&["foot", "ankle"]));
        let world = rig.world(&rig.rest_pose(), glam::Mat4::IDENTITY);
        let positions: Vec<Vec3> = world.iter().map(|m| m.w_axis.truncate()).collect();
        let vrm_legs = character.vrm.as_ref().and_then(|v| {
            Some((
                v.bone("hips")?,
                vec![v.bone("leftFoot")?, v.bone("rightFoot")?],
            ))
        });
        let (waist, feet, bones_from) = if let Some((hips, feet)) = vrm_legs {
            (hips, feet, "VRMC_vrm")
        } else if !named_waist.is_empty() && !named_feet.is_empty() {
            (
                named_waist[0],
                named_feet.iter().take(2).copied().collect(),
                "names",
            )
        } else {
            let parents: Vec<Option<usize>> = rig.nodes.iter().map(|n| n.parent).collect();
            let mut joints: Vec<usize> = rig
                .bones
                .iter()
                .map(|b| b.node)
                .filter(|&n| deforms[n])
                .collect();
            joints.sort_unstable();
            joints.dedup();
            let (hips, feet) = legs(&parents, &positions, &joints).ok_or_else(|| {
                fail(
                    &character.path,
                    format!(
                        "cannot tell the waist and feet: no bone is named hips/pelvis and \
                         foot/ankle, and the skeleton has no two leg chains (lowest leaf joints \
                         left and right); write a {}.avatar.json description (bones: {})",
                        character.name,
                        super::character::node_names(rig, 30)
                    ),
                )
            })?;
            (hips, feet.to_vec(), "the skeleton")
        };
        let by_name = |word: &str| {
            character
                .clips
                .iter()
                .map(|c| c.name.as_str())
                .filter(|n| n.to_lowercase().contains(word))
                .min_by_key(|n| n.len())
                .map(str::to_string)
        };
        let mut roles = [by_name("idle"), by_name("walk"), by_name("run")];
        let mut speeds: Vec<(String, f32)> = Vec::new();
        let from_motion = roles.iter().any(Option::is_none);
        if from_motion {
            let unused: Vec<&super::clip::Clip> = character
                .clips
                .iter()
                .filter(|c| !roles.iter().flatten().any(|r| *r == c.name))
                .collect();
            let measured: Vec<f32> = unused
                .iter()
                .map(|c| stance_speed(character, c, &feet, waist))
                .collect();
            let leg = (positions[waist].y
                - feet
                    .iter()
                    .map(|&f| positions[f].y)
                    .fold(f32::MAX, f32::min))
            .max(1e-3);
            let (idle, walk, run) = assign_roles(&measured, STILL * leg).ok_or_else(|| {
                let list: Vec<String> = unused
                    .iter()
                    .zip(&measured)
                    .map(|(c, s)| format!("{} {s:.2} m/s", c.name))
                    .collect();
                fail(
                    &character.path,
                    format!(
                        "cannot tell the walk and run clips: names do not say and no clip moves \
                         the feet (clips: {}); write a {}.avatar.json description",
                        list.join(", "),
                        character.name
                    ),
                )
            })?;
            let name = |i: usize| unused[i].name.clone();
            roles[0] = roles[0]
                .take()
                .or_else(|| Some(idle.map_or(REST_CLIP.to_string(), name)));
            roles[1] = roles[1].take().or_else(|| Some(name(walk)));
            roles[2] = roles[2].take().or_else(|| Some(name(run)));
            speeds = unused
                .iter()
                .zip(&measured)
                .map(|(c, &s)| (c.name.clone(), s))
                .collect();
        }
        let [idle, walk, run] = roles.map(|r| r.expect("every role is assigned"));
        let (loose_parts, colliders) = hanging_loose_parts(character, waist, &feet);
        let node_name = |n: usize| rig.nodes[n].name.clone();
        let shown = |clip: &str| {
            let speed = speeds
                .iter()
                .find(|(n, _)| n == clip)
                .map(|(_, s)| format!(" ({s:.2} m/s)"))
                .unwrap_or_default();
            format!("{clip}{speed}")
        };
        let run_shown = if run == walk {
            "- (the walk clip played faster)".to_string()
        } else {
            shown(&run)
        };
        let idle_shown = if idle == REST_CLIP {
            "- (the rest pose)".to_string()
        } else {
            shown(&idle)
        };
        let loose: String = loose_parts
            .iter()
            .map(|p| {
                let kind = format!("{:?}", p.kind).to_lowercase();
                format!(" loose={} ({kind}, {} chains)", p.name, p.chains)
            })
            .collect();
        let inferred = format!(
            "inferred: waist={} feet={} idle={idle_shown} walk={} run={run_shown}{loose} (bones from {}, clips from {})",
            node_name(waist),
            feet.iter()
                .map(|&f| node_name(f))
                .collect::<Vec<_>>()
                .join(","),
            shown(&walk),
            bones_from,
            if from_motion { "motion" } else { "names" },
        );
        Ok(Self {
            clips: ClipNames { idle, walk, run },
            waist_bones: vec![node_name(waist)],
            feet: feet.iter().map(|&f| node_name(f)).collect(),
            forward: default_forward(),
            walk_speed: None,
            run_speed: None,
            loose_parts,
            colliders,
            spring_chains: Vec::new(),
            inferred: Some(inferred),
        })
    }
}

/// Loose parts for the rigid meshes that hang from a joint ([`hanging_parts`]): five
/// spring chains side by side across a flat one (`sheet`), eight around one that wraps
/// around its axis (`ring`), four segments each; with any, colliders on the legs (each
/// bone from the waist to a foot, a capsule to the joint below it) and at the waist, so
/// that the part swings around them. Each part is named by its mesh and hangs from the
/// mesh's own node.
fn hanging_loose_parts(
    character: &Character,
    waist: usize,
    feet: &[usize],
) -> (Vec<LoosePart>, Vec<ColliderSpec>) {
    let parts: Vec<LoosePart> = hanging_parts(character)
        .into_iter()
        .map(|h| {
            let (kind, chains) = if h.flat {
                (ChainLayout::Sheet, 5)
            } else {
                (ChainLayout::Ring, 8)
            };
            LoosePart {
                name: h.mesh.clone(),
                kind,
                mesh: Some(h.mesh.clone()),
                materials: Vec::new(),
                parent_bone: h.mesh,
                chains,
                segments: 4,
                arc_degrees: full_circle(),
                stiffness: default_stiffness(),
                drag: default_drag(),
                gravity: default_gravity(),
            }
        })
        .collect();
    if parts.is_empty() {
        return (parts, Vec::new());
    }
    let rig = &character.rig;
    let mut colliders = vec![ColliderSpec {
        bone: rig.nodes[waist].name.clone(),
        to: None,
        radius: None,
    }];
    for &foot in feet {
        let mut below = foot;
        while let Some(above) = rig.nodes[below].parent.filter(|&a| a != waist) {
            colliders.push(ColliderSpec {
                bone: rig.nodes[above].name.clone(),
                to: Some(rig.nodes[below].name.clone()),
                radius: None,
            });
            below = above;
        }
    }
    (parts, colliders)
}

/// Per rig node: whether it is the node of a bone that carries skin weight on some vertex.
pub fn deforming_nodes(character: &Character) -> Vec<bool> {
    let mut deforms = vec![false; character.rig.nodes.len()];
    let skinned = &character.skinned;
    for (joints, weights) in skinned.joints.iter().zip(&skinned.weights) {
        for (&j, &w) in joints.iter().zip(weights) {
            if w > 0.0 {
                deforms[character.rig.bones[j as usize].node] = true;
            }
        }
    }
    deforms
}

/// The idle clip's name when no clip stands still: the rig's rest pose (a clip with no
/// channels, added by the teacher).
pub const REST_CLIP: &str = "(rest pose)";

/// Below this stance speed, in leg lengths (hips height above the feet) per second, a clip
/// stands still (idle); walks are around 1.5, runs 3 or more.
pub const STILL: f32 = 0.2;

/// Clip roles from measured stance speeds: idle the slowest clip under `still` (none if
/// no clip is that slow), walk the slowest and run the fastest of the others (the same
/// clip when only one moves). `None` when no clip moves.
pub fn assign_roles(speeds: &[f32], still: f32) -> Option<(Option<usize>, usize, usize)> {
    let by_speed = |a: &usize, b: &usize| speeds[*a].total_cmp(&speeds[*b]).then(a.cmp(b));
    let idle = (0..speeds.len())
        .filter(|&i| speeds[i] < still)
        .min_by(by_speed);
    let moving: Vec<usize> = (0..speeds.len()).filter(|&i| speeds[i] >= still).collect();
    let walk = moving.iter().copied().min_by(by_speed)?;
    let run = moving.iter().copied().max_by(by_speed)?;
    Some((idle, walk, run))
}

/// The hips and the two feet of a skeleton: the feet are the lowest leaf joints left and
/// right (x) of the joints' mean, each in the bottom quarter of the skeleton's height; the hips the joint where
/// their chains meet (nearest common ancestor). `parents` and `positions` (rest, world)
/// cover every node; `joints` are the skeleton's nodes. `None` without two such legs.
pub fn legs(
    parents: &[Option<usize>],
    positions: &[Vec3],
    joints: &[usize],
) -> Option<(usize, [usize; 2])> {
    let is_joint = |n: usize| joints.contains(&n);
    let leaves: Vec<usize> = joints
        .iter()
        .copied()
        .filter(|&j| !joints.iter().any(|&k| parents[k] == Some(j)))
        .collect();
    let centre = joints.iter().map(|&j| positions[j].x).sum::<f32>() / joints.len().max(1) as f32;
    let (bottom, top) = joints.iter().fold((f32::MAX, f32::MIN), |(lo, hi), &j| {
        (lo.min(positions[j].y), hi.max(positions[j].y))
    });
    let low = bottom + 0.25 * (top - bottom);
    let lowest = |side: f32| {
        leaves
            .iter()
            .copied()
            .filter(|&l| (positions[l].x - centre) * side > 0.0 && positions[l].y <= low)
            .min_by(|&a, &b| positions[a].y.total_cmp(&positions[b].y).then(a.cmp(&b)))
    };
    let (left, right) = (lowest(1.0)?, lowest(-1.0)?);
    let ancestors = |mut n: usize| {
        let mut chain = vec![n];
        while let Some(p) = parents[n] {
            chain.push(p);
            n = p;
        }
        chain
    };
    let of_right = ancestors(right);
    let hips = ancestors(left)
        .into_iter()
        .skip(1)
        .find(|a| of_right.contains(a) && is_joint(*a))?;
    Some((hips, [left, right]))
}

/// How fast a clip's planted (lowest) foot slides horizontally relative to `hips` (so
/// in-place and root-motion clips read alike); the median over the cycle, m/s.
pub fn stance_speed(character: &Character, clip: &Clip, feet: &[usize], hips: usize) -> f32 {
    const SAMPLES: usize = 60;
    let dt = clip.duration.max(1e-3) / SAMPLES as f32;
    super::gait::planted_speed(character, clip, feet, Some(hips), SAMPLES, dt, |step| {
        Vec3::new(step.x, 0.0, step.z).length()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_witch_description_parses() {
        let d = Description::parse(SHIPPED[0].1, Path::new("witch")).unwrap();
        assert_eq!(d.clips.run, "Run");
        assert_eq!(d.loose_parts.len(), 3);
        assert_eq!(d.loose_parts[0].kind, ChainLayout::Ring);
        assert_eq!(d.loose_parts[0].arc_degrees, 360.0);
    }

    #[test]
    fn bad_descriptions_name_the_file_and_field() {
        let err = Description::parse(r#"{"clips": {"idle": "I"}}"#, Path::new("x.avatar.json"))
            .unwrap_err();
        assert!(
            err.to_string().contains("x.avatar.json") && err.to_string().contains("walk"),
            "{err}"
        );
        let text = SHIPPED[0].1.replace("\"+z\"", "\"up\"");
        let err = Description::parse(&text, Path::new("y.avatar.json")).unwrap_err();
        assert!(err.to_string().contains("forward 'up'"), "{err}");
    }

    #[test]
    fn roles_from_foot_speeds() {
        // Leg 0.9 m: still below 0.18 m/s.
        let still = STILL * 0.9;
        assert_eq!(
            assign_roles(&[3.1, 0.02, 1.3, 0.1], still),
            Some((Some(1), 2, 0))
        );
        // No clip stands still: the rest pose is idle; one moving clip walks and runs.
        assert_eq!(assign_roles(&[1.2], still), Some((None, 0, 0)));
        assert_eq!(
            assign_roles(&[0.4, 0.9, 0.05], still),
            Some((Some(2), 0, 1))
        );
        // Nothing moves: no walk.
        assert_eq!(assign_roles(&[0.01, 0.0], still), None);
        assert_eq!(assign_roles(&[], still), None);
    }

    #[test]
    fn hips_where_the_leg_chains_meet_and_feet_the_lowest_leaves() {
        // 0 root (ground) > 1 pelvis > {2 spine > 3 head, 4 thigh.l > 5 shin.l > 6 toe.l,
        // 7 thigh.r > 8 shin.r > 9 toe.r}; 10 an arm leaf hanging low on the left but
        // above the toes.
        let parents = [
            None,
            Some(0),
            Some(1),
            Some(2),
            Some(1),
            Some(4),
            Some(5),
            Some(1),
            Some(7),
            Some(8),
            Some(2),
        ];
        let p = |x: f32, y: f32| Vec3::new(x, y, 0.0);
        let positions = [
            p(0.0, 0.0),
            p(0.0, 0.5),
            p(0.0, 0.9),
            p(0.0, 1.3),
            p(0.15, 0.45),
            p(0.15, 0.25),
            p(0.15, 0.02),
            p(-0.15, 0.45),
            p(-0.15, 0.25),
            p(-0.15, 0.03),
            p(0.5, 0.3),
        ];
        let joints: Vec<usize> = (0..11).collect();
        assert_eq!(legs(&parents, &positions, &joints), Some((1, [6, 9])));
        // One leg only (nothing on the right): no answer.
        let one_sided: Vec<usize> = (0..7).collect();
        assert_eq!(legs(&parents, &positions, &one_sided), None);
    }
}
