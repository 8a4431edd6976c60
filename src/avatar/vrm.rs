//! VRM 1.0: the `VRMC_vrm` humanoid bone map and the `VRMC_springBone` springs, joints
//! and colliders, read from a glTF's root extensions (node indices mapped to rig nodes)
//! and written into one (`unica rig`'s output). Written from the published specification
//! (vrm-specification, VRMC_vrm-1.0 and VRMC_springBone-1.0). Not read: `center` spaces
//! (joints are evaluated in world space), expressions, look-at, first-person, meta beyond
//! what a writer must give. A humanoid map is taken as it is, without the bones VRM
//! requires (a file missing some still gives the ones it has). VRM expects +Z forward
//! and metres; `unica rig` writes the mesh's own axes and units.

use glam::Vec3;
use serde_json::{Value, json};

/// A spring joint's settings (VRM defaults where the file is silent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VrmJoint {
    /// Rig node (file node index when writing).
    pub node: usize,
    pub hit_radius: f32,
    pub stiffness: f32,
    pub gravity_power: f32,
    pub gravity_dir: Vec3,
    pub drag: f32,
}

impl VrmJoint {
    /// A joint with the specification's defaults.
    pub fn new(node: usize) -> Self {
        Self {
            node,
            hit_radius: 0.0,
            stiffness: 1.0,
            gravity_power: 0.0,
            gravity_dir: Vec3::NEG_Y,
            drag: 0.5,
        }
    }
}

/// One spring: joints from the root to the tail (the last joint is only a tail), and the
/// collider groups it is kept out of.
#[derive(Clone, Debug, PartialEq)]
pub struct VrmSpring {
    pub name: String,
    pub joints: Vec<VrmJoint>,
    pub collider_groups: Vec<usize>,
}

/// A sphere (`tail == None`) or capsule, in the node's local space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VrmCollider {
    pub node: usize,
    pub offset: Vec3,
    pub radius: f32,
    pub tail: Option<Vec3>,
}

/// What a file says in VRM 1.0's terms.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Vrm {
    /// VRM humanoid bone name (`hips`, `leftFoot`…) and its node.
    pub humanoid: Vec<(String, usize)>,
    pub springs: Vec<VrmSpring>,
    pub colliders: Vec<VrmCollider>,
    /// Collider indices per group.
    pub collider_groups: Vec<Vec<usize>>,
}

/// The humanoid bones VRM 1.0 requires.
pub const REQUIRED_BONES: [&str; 15] = [
    "hips",
    "spine",
    "head",
    "leftUpperLeg",
    "leftLowerLeg",
    "leftFoot",
    "rightUpperLeg",
    "rightLowerLeg",
    "rightFoot",
    "leftUpperArm",
    "leftLowerArm",
    "leftHand",
    "rightUpperArm",
    "rightLowerArm",
    "rightHand",
];

impl Vrm {
    /// The node of VRM humanoid bone `bone`.
    pub fn bone(&self, bone: &str) -> Option<usize> {
        self.humanoid
            .iter()
            .find(|(name, _)| name == bone)
            .map(|&(_, node)| node)
    }

    /// Reads `VRMC_vrm` and `VRMC_springBone` from a glTF's root `extensions` object;
    /// `node(i)` maps file node `i` to a rig node (`None`: not in the scene). `Ok(None)`
    /// when neither extension is there; errors name the field.
    pub fn read(
        extensions: Option<&serde_json::Map<String, Value>>,
        node: &dyn Fn(usize) -> Option<usize>,
    ) -> Result<Option<Self>, String> {
        let Some(extensions) = extensions else {
            return Ok(None);
        };
        let (vrm, springs) = (
            extensions.get("VRMC_vrm"),
            extensions.get("VRMC_springBone"),
        );
        if vrm.is_none() && springs.is_none() {
            return Ok(None);
        }
        let node_at = |value: &Value, field: &str| -> Result<usize, String> {
            let index = value
                .as_u64()
                .ok_or_else(|| format!("{field} is not a node index"))?;
            node(index as usize).ok_or_else(|| format!("{field}: node {index} is not in the scene"))
        };
        let mut out = Vrm::default();
        if let Some(vrm) = vrm {
            let bones = vrm
                .pointer("/humanoid/humanBones")
                .and_then(Value::as_object)
                .ok_or("VRMC_vrm.humanoid.humanBones is missing")?;
            for (name, bone) in bones {
                let field = format!("VRMC_vrm.humanoid.humanBones.{name}.node");
                out.humanoid
                    .push((name.clone(), node_at(&bone["node"], &field)?));
            }
        }
        let Some(springs) = springs else {
            return Ok(Some(out));
        };
        let float = |value: &Value, field: &str, default: f32| -> Result<f32, String> {
            match value {
                Value::Null => Ok(default),
                v => v
                    .as_f64()
                    .map(|x| x as f32)
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("{field} is not a number")),
            }
        };
        // The specification's ranges: stiffness, radii and gravity power at least 0, drag
        // in [0, 1].
        let within = |value: &Value, field: &str, default: f32, hi: f32| -> Result<f32, String> {
            let x = float(value, field, default)?;
            if (0.0..=hi).contains(&x) {
                Ok(x)
            } else if hi.is_finite() {
                Err(format!("{field} {x} is outside [0, {hi}]"))
            } else {
                Err(format!("{field} {x} is negative"))
            }
        };
        let vec3 = |value: &Value, field: &str, default: Vec3| -> Result<Vec3, String> {
            match value {
                Value::Null => Ok(default),
                v => {
                    let xs: Vec<f32> = v
                        .as_array()
                        .filter(|a| a.len() == 3)
                        .map(|a| {
                            a.iter()
                                .filter_map(Value::as_f64)
                                .map(|x| x as f32)
                                .collect()
                        })
                        .unwrap_or_default();
                    if xs.len() != 3 || xs.iter().any(|x| !x.is_finite()) {
                        return Err(format!("{field} is not three numbers"));
                    }
                    Ok(Vec3::new(xs[0], xs[1], xs[2]))
                }
            }
        };
        let list = |value: &Value, field: &str| -> Result<Vec<Value>, String> {
            match value {
                Value::Null => Ok(Vec::new()),
                Value::Array(items) => Ok(items.clone()),
                _ => Err(format!("{field} is not a list")),
            }
        };
        for (i, c) in list(&springs["colliders"], "VRMC_springBone.colliders")?
            .iter()
            .enumerate()
        {
            let field = format!("VRMC_springBone.colliders[{i}]");
            let node = node_at(&c["node"], &format!("{field}.node"))?;
            let (shape, capsule) = match (&c["shape"]["sphere"], &c["shape"]["capsule"]) {
                (Value::Null, Value::Null) => {
                    return Err(format!("{field}.shape is neither a sphere nor a capsule"));
                }
                (Value::Null, capsule) => (capsule, true),
                (sphere, _) => (sphere, false),
            };
            let kind = if capsule { "capsule" } else { "sphere" };
            let at = |key: &str| format!("{field}.shape.{kind}.{key}");
            out.colliders.push(VrmCollider {
                node,
                offset: vec3(&shape["offset"], &at("offset"), Vec3::ZERO)?,
                radius: within(&shape["radius"], &at("radius"), 0.0, f32::INFINITY)?,
                tail: capsule
                    .then(|| vec3(&shape["tail"], &at("tail"), Vec3::ZERO))
                    .transpose()?,
            });
        }
        let colliders = out.colliders.len();
        for (g, group) in list(&springs["colliderGroups"], "VRMC_springBone.colliderGroups")?
            .iter()
            .enumerate()
        {
            let field = format!("VRMC_springBone.colliderGroups[{g}].colliders");
            let members = list(&group["colliders"], &field)?
                .iter()
                .map(|c| {
                    c.as_u64()
                        .map(|c| c as usize)
                        .filter(|&c| c < colliders)
                        .ok_or_else(|| format!("{field}: {c} is not a collider index"))
                })
                .collect::<Result<_, _>>()?;
            out.collider_groups.push(members);
        }
        for (s, spring) in list(&springs["springs"], "VRMC_springBone.springs")?
            .iter()
            .enumerate()
        {
            let field = format!("VRMC_springBone.springs[{s}]");
            let mut joints = Vec::new();
            for (j, joint) in list(&spring["joints"], &format!("{field}.joints"))?
                .iter()
                .enumerate()
            {
                let at = |key: &str| format!("{field}.joints[{j}].{key}");
                let defaults = VrmJoint::new(0);
                joints.push(VrmJoint {
                    node: node_at(&joint["node"], &at("node"))?,
                    hit_radius: within(
                        &joint["hitRadius"],
                        &at("hitRadius"),
                        defaults.hit_radius,
                        f32::INFINITY,
                    )?,
                    stiffness: within(
                        &joint["stiffness"],
                        &at("stiffness"),
                        defaults.stiffness,
                        f32::INFINITY,
                    )?,
                    gravity_power: within(
                        &joint["gravityPower"],
                        &at("gravityPower"),
                        defaults.gravity_power,
                        f32::INFINITY,
                    )?,
                    gravity_dir: vec3(
                        &joint["gravityDir"],
                        &at("gravityDir"),
                        defaults.gravity_dir,
                    )?,
                    drag: within(&joint["dragForce"], &at("dragForce"), defaults.drag, 1.0)?,
                });
            }
            if joints.is_empty() {
                return Err(format!("{field}.joints is empty"));
            }
            let groups = list(
                &spring["colliderGroups"],
                &format!("{field}.colliderGroups"),
            )?
            .iter()
            .map(|g| {
                g.as_u64()
                    .map(|g| g as usize)
                    .filter(|&g| g < out.collider_groups.len())
                    .ok_or_else(|| {
                        format!("{field}.colliderGroups: {g} is not a collider group index")
                    })
            })
            .collect::<Result<_, _>>()?;
            out.springs.push(VrmSpring {
                name: spring["name"].as_str().unwrap_or_default().to_string(),
                joints,
                collider_groups: groups,
            });
        }
        Ok(Some(out))
    }

    /// The root `extensions` entries (`VRMC_vrm`, and `VRMC_springBone` when there are
    /// springs) for a file whose node indices are this `Vrm`'s nodes; `name` goes into
    /// the meta. The meta's required fields are filled; its permissions are VRM's most
    /// restrictive, and its copyright line points to the source mesh's own licence,
    /// which `unica rig` cannot know.
    pub fn to_json(&self, name: &str) -> serde_json::Map<String, Value> {
        let mut bones = serde_json::Map::new();
        for (bone, node) in &self.humanoid {
            bones.insert(bone.clone(), json!({ "node": node }));
        }
        let mut out = serde_json::Map::new();
        out.insert(
            "VRMC_vrm".into(),
            json!({
                "specVersion": "1.0",
                "meta": {
                    "name": name,
                    "version": env!("CARGO_PKG_VERSION"),
                    "authors": ["unica rig (auto-rigged)"],
                    "copyrightInformation": format!(
                        "auto-rigged by unica rig from the mesh of {name}; the mesh's own licence applies"
                    ),
                    "licenseUrl": "https://vrm.dev/licenses/1.0/",
                    "avatarPermission": "onlyAuthor",
                    "commercialUsage": "personalNonProfit",
                    "allowExcessivelyViolentUsage": false,
                    "allowExcessivelySexualUsage": false,
                    "allowPoliticalOrReligiousUsage": false,
                    "allowAntisocialOrHateUsage": false,
                    "creditNotation": "required",
                    "allowRedistribution": false,
                    "modification": "prohibited"
                },
                "humanoid": { "humanBones": bones }
            }),
        );
        if self.springs.is_empty() && self.colliders.is_empty() {
            return out;
        }
        let colliders: Vec<Value> = self
            .colliders
            .iter()
            .map(|c| {
                let shape = match c.tail {
                    None => json!({"sphere": {"offset": c.offset.to_array(), "radius": c.radius}}),
                    Some(tail) => json!({"capsule": {
                        "offset": c.offset.to_array(), "radius": c.radius, "tail": tail.to_array()
                    }}),
                };
                json!({"node": c.node, "shape": shape})
            })
            .collect();
        let groups: Vec<Value> = self
            .collider_groups
            .iter()
            .enumerate()
            .map(|(g, members)| json!({"name": format!("group{g}"), "colliders": members}))
            .collect();
        let springs: Vec<Value> = self
            .springs
            .iter()
            .map(|s| {
                let joints: Vec<Value> = s
                    .joints
                    .iter()
                    .map(|j| {
                        json!({
                            "node": j.node,
                            "hitRadius": j.hit_radius,
                            "stiffness": j.stiffness,
                            "gravityPower": j.gravity_power,
                            "gravityDir": j.gravity_dir.to_array(),
                            "dragForce": j.drag
                        })
                    })
                    .collect();
                json!({"name": s.name, "joints": joints, "colliderGroups": s.collider_groups})
            })
            .collect();
        out.insert(
            "VRMC_springBone".into(),
            json!({
                "specVersion": "1.0",
                "colliders": colliders,
                "colliderGroups": groups,
                "springs": springs
            }),
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<Option<Vrm>, String> {
        let value: Value = serde_json::from_str(text).unwrap();
        // File node i is rig node i + 1 (a scene root before them); node 9 is not in it.
        Vrm::read(value.as_object(), &|i| (i < 9).then_some(i + 1))
    }

    #[test]
    fn the_specification_example_reads_with_its_defaults() {
        let vrm = read(
            r#"{"VRMC_springBone": {"specVersion": "1.0",
                "colliders": [
                    {"node": 2, "shape": {"sphere": {"offset": [0, 0, 0], "radius": 1}}},
                    {"node": 2, "shape": {"capsule": {"offset": [0, 0, 0], "radius": 1, "tail": [0, 0, 1]}}}],
                "colliderGroups": [{"name": "group0", "colliders": [0, 1]}],
                "springs": [{"joints": [{"node": 0, "hitRadius": 0.1, "stiffness": 0.5,
                    "gravityPower": 1.0, "gravityDir": [0, -1, 0], "dragForce": 0.5}, {"node": 1}],
                    "colliderGroups": [0]}]}}"#,
        )
        .unwrap()
        .unwrap();
        assert!(vrm.humanoid.is_empty());
        assert_eq!(vrm.colliders.len(), 2);
        assert_eq!(vrm.colliders[0].tail, None);
        assert_eq!(vrm.colliders[1].tail, Some(Vec3::Z));
        assert_eq!(vrm.colliders[1].node, 3);
        assert_eq!(vrm.collider_groups, vec![vec![0, 1]]);
        let spring = &vrm.springs[0];
        assert_eq!(spring.collider_groups, vec![0]);
        assert_eq!(
            spring.joints[0],
            VrmJoint {
                node: 1,
                hit_radius: 0.1,
                stiffness: 0.5,
                gravity_power: 1.0,
                gravity_dir: Vec3::NEG_Y,
                drag: 0.5
            }
        );
        // The tail joint says only its node: the specification's defaults.
        assert_eq!(spring.joints[1], VrmJoint::new(2));
    }

    #[test]
    fn written_extensions_read_back_the_same() {
        let vrm = Vrm {
            humanoid: vec![("hips".into(), 0), ("leftFoot".into(), 3)],
            springs: vec![VrmSpring {
                name: "tail".into(),
                joints: vec![
                    VrmJoint {
                        stiffness: 1.5,
                        gravity_power: 0.3,
                        ..VrmJoint::new(4)
                    },
                    VrmJoint::new(5),
                ],
                collider_groups: vec![0],
            }],
            colliders: vec![
                VrmCollider {
                    node: 0,
                    offset: Vec3::new(0.0, 0.1, 0.0),
                    radius: 0.2,
                    tail: None,
                },
                VrmCollider {
                    node: 1,
                    offset: Vec3::ZERO,
                    radius: 0.1,
                    tail: Some(Vec3::new(0.0, -0.4, 0.0)),
                },
            ],
            collider_groups: vec![vec![0, 1]],
        };
        let written = Value::Object(vrm.to_json("blocky"));
        let back = Vrm::read(written.as_object(), &|i| Some(i))
            .unwrap()
            .unwrap();
        assert_eq!(back, vrm);
        let meta = &written["VRMC_vrm"]["meta"];
        for key in ["name", "authors", "licenseUrl"] {
            assert!(!meta[key].is_null(), "meta.{key} is required");
        }
        assert_eq!(written["VRMC_springBone"]["specVersion"], "1.0");
    }

    #[test]
    fn bad_fields_are_named() {
        for (text, expect) in [
            (
                r#"{"VRMC_vrm": {"humanoid": {"humanBones": {"hips": {"node": 9}}}}}"#,
                "humanBones.hips.node: node 9 is not in the scene",
            ),
            (
                r#"{"VRMC_vrm": {}}"#,
                "VRMC_vrm.humanoid.humanBones is missing",
            ),
            (
                r#"{"VRMC_springBone": {"springs": [{"joints": []}]}}"#,
                "springs[0].joints is empty",
            ),
            (
                r#"{"VRMC_springBone": {"colliders": [{"node": 0, "shape": {}}]}}"#,
                "colliders[0].shape is neither a sphere nor a capsule",
            ),
            (
                r#"{"VRMC_springBone": {"springs": [{"joints": [{"node": 0, "stiffness": "x"}]}]}}"#,
                "springs[0].joints[0].stiffness is not a number",
            ),
            (
                r#"{"VRMC_springBone": {"colliderGroups": [{"colliders": [3]}]}}"#,
                "3 is not a collider index",
            ),
            (
                r#"{"VRMC_springBone": {"springs": [{"joints": [{"node": 0, "dragForce": 1.5}]}]}}"#,
                "springs[0].joints[0].dragForce 1.5 is outside [0, 1]",
            ),
            (
                r#"{"VRMC_springBone": {"colliders": [{"node": 0, "shape": {"sphere": {"radius": -1}}}]}}"#,
                "colliders[0].shape.sphere.radius -1 is negative",
            ),
        ] {
            let err = read(text).unwrap_err();
            assert!(err.contains(expect), "{err}");
        }
        assert_eq!(read(r#"{"KHR_other": {}}"#).unwrap(), None);
    }
}
