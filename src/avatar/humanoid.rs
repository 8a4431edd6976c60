//! Humanoid bone names: the template's names (those of the Witch's rig, which `unica rig`
//! writes) with their VRM 1.0, Mixamo and Unreal equivalents, and finding a template bone
//! in any rig by them — a file's own `VRMC_vrm` map first, then the name itself, then the
//! other conventions (case-insensitive, any `prefix:` such as `mixamorig:` dropped).

use super::rig::Rig;
use super::vrm::Vrm;

/// The body: (template, VRM, Mixamo, Unreal) with `{s}` the side: `L`/`R` in the
/// template, `left`/`right` in VRM, `Left`/`Right` in Mixamo, `l`/`r` in Unreal.
const BODY: [(&str, &str, &str, &str); 13] = [
    ("Hips", "hips", "Hips", "pelvis"),
    ("Abdomen", "spine", "Spine", "spine_01"),
    ("Torso", "chest", "Spine1", "spine_02"),
    ("Chest", "upperChest", "Spine2", "spine_03"),
    ("Neck", "neck", "Neck", "neck_01"),
    ("Head", "head", "Head", "head"),
    ("Shoulder.{s}", "{s}Shoulder", "{s}Shoulder", "clavicle_{s}"),
    ("UpperArm.{s}", "{s}UpperArm", "{s}Arm", "upperarm_{s}"),
    ("LowerArm.{s}", "{s}LowerArm", "{s}ForeArm", "lowerarm_{s}"),
    ("Wrist.{s}", "{s}Hand", "{s}Hand", "hand_{s}"),
    ("UpperLeg.{s}", "{s}UpperLeg", "{s}UpLeg", "thigh_{s}"),
    ("LowerLeg.{s}", "{s}LowerLeg", "{s}Leg", "calf_{s}"),
    ("Foot.{s}", "{s}Foot", "{s}Foot", "foot_{s}"),
];

/// Fingers: (template stem, VRM stem, Mixamo stem, Unreal stem, VRM names of joints
/// 1, 2, 3). The template's fourth joint (a tip) has no VRM or Unreal bone.
#[rustfmt::skip]
const FINGERS: [(&str, &str, &str, &str, [&str; 3]); 5] = [
    ("Thumb", "Thumb", "Thumb", "thumb", ["Metacarpal", "Proximal", "Distal"]),
    ("Index", "Index", "Index", "index", ["Proximal", "Intermediate", "Distal"]),
    ("Middle", "Middle", "Middle", "middle", ["Proximal", "Intermediate", "Distal"]),
    ("Ring", "Ring", "Ring", "ring", ["Proximal", "Intermediate", "Distal"]),
    ("Pinky", "Little", "Pinky", "pinky", ["Proximal", "Intermediate", "Distal"]),
];

/// One template bone's names in the other conventions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Names {
    pub template: String,
    pub vrm: Option<String>,
    pub mixamo: String,
    pub unreal: Option<String>,
}

/// Every template bone with its names: the body, then both hands' fingers.
pub fn table() -> Vec<Names> {
    let mut out = Vec::new();
    for (t, v, m, u) in BODY {
        let sides: &[(&str, &str, &str, &str)] = if t.contains("{s}") {
            &[("L", "left", "Left", "l"), ("R", "right", "Right", "r")]
        } else {
            &[("", "", "", "")]
        };
        for (st, sv, sm, su) in sides {
            out.push(Names {
                template: t.replace("{s}", st),
                vrm: Some(v.replace("{s}", sv)),
                mixamo: m.replace("{s}", sm),
                unreal: Some(u.replace("{s}", su)),
            });
        }
    }
    for (st, sv, sm, su) in [("L", "left", "Left", "l"), ("R", "right", "Right", "r")] {
        for (t, v, m, u, vrm_joints) in FINGERS {
            let count = if t == "Thumb" { 3 } else { 4 };
            for k in 1..=count {
                out.push(Names {
                    template: format!("{t}{k}.{st}"),
                    vrm: (k <= 3).then(|| format!("{sv}{v}{}", vrm_joints[k - 1])),
                    mixamo: format!("{sm}Hand{m}{k}"),
                    unreal: (k <= 3).then(|| format!("{u}_0{k}_{su}")),
                });
            }
        }
    }
    out
}

/// The VRM humanoid bone name of template bone `template`.
pub fn vrm_name(template: &str) -> Option<String> {
    table()
        .into_iter()
        .find(|n| n.template == template)
        .and_then(|n| n.vrm)
}

/// A node name as compared across conventions: lower case, without any `prefix:`.
fn plain(name: &str) -> String {
    name.rsplit(':').next().unwrap_or(name).to_lowercase()
}

/// The rig node of each template bone in `templates`: first the file's VRM humanoid map
/// and the exact names for all of them, then the VRM, Mixamo and Unreal names for the
/// rest, never a node already taken (a rig's `Chest` is the template's `Chest`, not
/// also VRM's `chest`, which is the template's `Torso`). An empty name finds nothing.
pub fn find_all(rig: &Rig, vrm: Option<&Vrm>, templates: &[&str]) -> Vec<Option<usize>> {
    let table = table();
    let names: Vec<Option<&Names>> = templates
        .iter()
        .map(|t| table.iter().find(|n| n.template == *t))
        .collect();
    let mut found: Vec<Option<usize>> = templates
        .iter()
        .zip(&names)
        .map(|(template, names)| {
            let from_map = vrm.zip(names.and_then(|n| n.vrm.as_deref()));
            from_map
                .and_then(|(vrm, bone)| vrm.bone(bone))
                .or_else(|| rig.find(template).filter(|_| !template.is_empty()))
        })
        .collect();
    for (i, names) in names.iter().enumerate() {
        let Some(names) = names.filter(|_| found[i].is_none()) else {
            continue;
        };
        let others = [
            names.vrm.as_deref(),
            Some(&names.mixamo),
            names.unreal.as_deref(),
        ];
        found[i] = others.iter().flatten().find_map(|alias| {
            let alias = plain(alias);
            (0..rig.nodes.len())
                .find(|&n| plain(&rig.nodes[n].name) == alias && !found.contains(&Some(n)))
        });
    }
    found
}

/// The rig node of template bone `template` (see [`find_all`]).
pub fn find(rig: &Rig, vrm: Option<&Vrm>, template: &str) -> Option<usize> {
    find_all(rig, vrm, &[template])[0]
}

/// As [`find`], then, where that finds nothing, the first node whose name equals one of
/// the bone's names with `.`, `-` and spaces read as `_` (a Rigify-style `hand.l` is
/// Unreal's `hand_l`). For lookups that only place something, such as a crop.
pub fn find_loosely(rig: &Rig, vrm: Option<&Vrm>, template: &str) -> Option<usize> {
    let loose = |name: &str| plain(name).replace(['.', '-', ' '], "_");
    find(rig, vrm, template).or_else(|| {
        let names = table().into_iter().find(|n| n.template == template)?;
        let wanted: Vec<String> = [
            Some(names.template),
            names.vrm,
            Some(names.mixamo),
            names.unreal,
        ]
        .iter()
        .flatten()
        .map(|n| loose(n))
        .collect();
        (0..rig.nodes.len()).find(|&n| wanted.contains(&loose(&rig.nodes[n].name)))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::avatar::rig::Node;

    fn rig(names: &[&str]) -> Rig {
        Rig {
            nodes: names
                .iter()
                .enumerate()
                .map(|(i, n)| Node {
                    name: n.to_string(),
                    parent: i.checked_sub(1),
                    rest: Default::default(),
                })
                .collect(),
            bones: Vec::new(),
        }
    }

    #[test]
    fn a_loose_lookup_reads_dots_as_underscores() {
        // Rigify-style names: `wrist.l` is the template's `Wrist.L` and `hand.l` is
        // Unreal's `hand_l`, read loosely; the template's own name comes first.
        let r = rig(&["root", "hips", "wrist.l", "hand.l", "head"]);
        assert_eq!(find(&r, None, "Wrist.L"), None);
        assert_eq!(find_loosely(&r, None, "Wrist.L"), Some(2));
        let r = rig(&["root", "hips", "hand.l", "head"]);
        assert_eq!(find_loosely(&r, None, "Wrist.L"), Some(2));
        assert_eq!(find_loosely(&r, None, "Head"), Some(3));
        assert_eq!(find_loosely(&r, None, "Wrist.R"), None);
    }

    #[test]
    fn the_table_names_each_bone_once_per_convention() {
        let table = table();
        // 13 body rows, 7 of them sided; 19 finger joints per hand.
        assert_eq!(table.len(), 6 + 2 * 7 + 2 * 19);
        for pick in [
            |n: &Names| Some(n.template.clone()),
            |n: &Names| n.vrm.clone(),
            |n: &Names| Some(n.mixamo.clone()),
            |n: &Names| n.unreal.clone(),
        ] {
            let mut names: Vec<String> = table.iter().filter_map(pick).collect();
            let count = names.len();
            names.sort();
            names.dedup();
            assert_eq!(names.len(), count);
        }
        let template: Vec<String> = table.iter().map(|n| n.template.clone()).collect();
        for (name, _) in crate::autorig::skeleton::template_joints(true) {
            assert!(template.contains(&name), "{name}");
        }
        // Every bone VRM 1.0 requires has a template bone.
        for bone in super::super::vrm::REQUIRED_BONES {
            assert!(
                table.iter().any(|n| n.vrm.as_deref() == Some(bone)),
                "{bone}"
            );
        }
    }

    #[test]
    fn known_names_in_each_convention() {
        let names = |t: &str| table().into_iter().find(|n| n.template == t).unwrap();
        let arm = names("LowerArm.R");
        assert_eq!(arm.vrm.as_deref(), Some("rightLowerArm"));
        assert_eq!(arm.mixamo, "RightForeArm");
        assert_eq!(arm.unreal.as_deref(), Some("lowerarm_r"));
        let pinky = names("Pinky2.L");
        assert_eq!(pinky.vrm.as_deref(), Some("leftLittleIntermediate"));
        assert_eq!(pinky.mixamo, "LeftHandPinky2");
        assert_eq!(pinky.unreal.as_deref(), Some("pinky_02_l"));
        assert_eq!(names("Index4.R").vrm, None);
        assert_eq!(vrm_name("Thumb1.L").as_deref(), Some("leftThumbMetacarpal"));
    }

    #[test]
    fn bones_are_found_by_any_convention() {
        let mixamo = rig(&["Armature", "mixamorig:Hips", "mixamorig:LeftUpLeg"]);
        assert_eq!(find(&mixamo, None, "Hips"), Some(1));
        assert_eq!(find(&mixamo, None, "UpperLeg.L"), Some(2));
        assert_eq!(find(&mixamo, None, "UpperLeg.R"), None);
        let unreal = rig(&["root", "pelvis", "thigh_l", "calf_l"]);
        assert_eq!(find(&unreal, None, "Hips"), Some(1));
        assert_eq!(find(&unreal, None, "LowerLeg.L"), Some(3));
        let vrm_names = rig(&["Root", "J_Bip_C_Hips", "leftUpperLeg"]);
        assert_eq!(find(&vrm_names, None, "UpperLeg.L"), Some(2));
        // The file's own map wins over names.
        let map = Vrm {
            humanoid: vec![("hips".into(), 1)],
            ..Default::default()
        };
        assert_eq!(find(&vrm_names, None, "Hips"), None);
        assert_eq!(find(&vrm_names, Some(&map), "Hips"), Some(1));
        // The template's own names.
        let own = rig(&["Hips", "Abdomen"]);
        assert_eq!(find(&own, None, "Abdomen"), Some(1));
        // A rig's Chest is the template's Chest and not also Torso (VRM's chest).
        let chest = rig(&["Hips", "Spine", "Chest"]);
        assert_eq!(
            find_all(&chest, None, &["Hips", "Abdomen", "Torso", "Chest"]),
            vec![Some(0), Some(1), None, Some(2)]
        );
    }
}
