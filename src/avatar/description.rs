//! The avatar description: what the teacher needs to know about a character that its
//! file does not say (which clips are idle/walk/run, the waist and feet, loose parts,
//! colliders). A JSON file beside the character, a shipped one, or inferred defaults.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::Character;
use super::character::{LoadError, fail};

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
    /// beside the character, else a shipped one for its name, else inferred.
    pub fn find(character: &Character, explicit: Option<&Path>) -> Result<Self, LoadError> {
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
        Self::infer(character)
    }

    pub fn read(path: &Path) -> Result<Self, LoadError> {
        let text = std::fs::read_to_string(path).map_err(|e| fail(path, e.to_string()))?;
        Self::parse(&text, path)
    }

    pub fn parse(text: &str, path: &Path) -> Result<Self, LoadError> {
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

    /// Defaults from names: clips containing idle/walk/run, a hips or pelvis bone, bones
    /// named foot or ankle; no loose parts.
    pub fn infer(character: &Character) -> Result<Self, LoadError> {
        let clip = |word: &str| {
            character
                .clips
                .iter()
                .map(|c| c.name.as_str())
                .filter(|n| n.to_lowercase().contains(word))
                .min_by_key(|n| n.len())
                .map(str::to_string)
                .ok_or_else(|| {
                    fail(
                        &character.path,
                        format!(
                            "no clip name contains '{word}'; write a {}.avatar.json description",
                            character.name
                        ),
                    )
                })
        };
        let bones = |words: &[&str]| -> Vec<String> {
            character
                .rig
                .nodes
                .iter()
                .map(|n| n.name.clone())
                .filter(|n| words.iter().any(|w| n.to_lowercase().contains(w)))
                .collect()
        };
        let waist = bones(&["hips", "pelvis"]);
        let feet = bones(&["foot", "ankle"]);
        if waist.is_empty() || feet.is_empty() {
            return Err(fail(
                &character.path,
                format!(
                    "cannot tell the waist and feet bones; write a {}.avatar.json description",
                    character.name
                ),
            ));
        }
        Ok(Self {
            clips: ClipNames {
                idle: clip("idle")?,
                walk: clip("walk")?,
                run: clip("run")?,
            },
            waist_bones: waist.into_iter().take(1).collect(),
            feet: feet.into_iter().take(2).collect(),
            forward: default_forward(),
            walk_speed: None,
            run_speed: None,
            loose_parts: Vec::new(),
            colliders: Vec::new(),
            spring_chains: Vec::new(),
        })
    }
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
}
