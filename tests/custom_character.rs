//! Nothing is Witch-specific: a small character built here, with its own bone names, clip
//! names and proportions, is driven and baked with only its description file.

mod common;

use std::path::Path;

use unica::action::Action;
use unica::avatar::description::Description;
use unica::avatar::load_character;
use unica::avatar::teacher::Teacher;
use unica::dataset::bake::{BakeOptions, bake};

/// Binary buffer with accessors appended as they are added.
#[derive(Default)]
struct Buffer {
    bin: Vec<u8>,
    views: Vec<serde_json::Value>,
    accessors: Vec<serde_json::Value>,
}

impl Buffer {
    fn add(
        &mut self,
        bytes: &[u8],
        component: u32,
        kind: &str,
        count: usize,
        extra: serde_json::Value,
    ) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.views.push(serde_json::json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()}));
        self.bin.extend(bytes);
        let mut accessor = serde_json::json!({"bufferView": self.views.len() - 1, "componentType": component, "type": kind, "count": count});
        if let (Some(a), Some(e)) = (accessor.as_object_mut(), extra.as_object()) {
            a.extend(e.clone());
        }
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    fn floats(
        &mut self,
        values: &[f32],
        kind: &str,
        count: usize,
        extra: serde_json::Value,
    ) -> usize {
        self.add(bytemuck::cast_slice(values), 5126, kind, count, extra)
    }
}

/// (name, parent, rest translation, box half size, colour)
type Bone = (&'static str, Option<usize>, [f32; 3], [f32; 3], [f32; 3]);

/// A little robot: pelvis, two legs with feet, a chest with an antenna; clips named
/// Stand / Stroll / Sprint that swing the legs (lifting each foot as it swings forward).
fn write_robot(path: &Path) {
    let bones: [Bone; 7] = [
        (
            "pelvis_j",
            None,
            [0.0, 1.0, 0.0],
            [0.2, 0.1, 0.12],
            [0.2, 0.3, 0.8],
        ),
        (
            "thigh_l",
            Some(0),
            [0.12, -0.1, 0.0],
            [0.06, 0.25, 0.06],
            [0.8, 0.3, 0.2],
        ),
        (
            "foot_l",
            Some(1),
            [0.0, -0.8, 0.0],
            [0.06, 0.05, 0.1],
            [0.1, 0.1, 0.1],
        ),
        (
            "thigh_r",
            Some(0),
            [-0.12, -0.1, 0.0],
            [0.06, 0.25, 0.06],
            [0.8, 0.3, 0.2],
        ),
        (
            "foot_r",
            Some(3),
            [0.0, -0.8, 0.0],
            [0.06, 0.05, 0.1],
            [0.1, 0.1, 0.1],
        ),
        (
            "chest_j",
            Some(0),
            [0.0, 0.45, 0.0],
            [0.22, 0.3, 0.14],
            [0.3, 0.7, 0.3],
        ),
        (
            "antenna_j",
            Some(5),
            [0.0, 0.35, 0.0],
            [0.02, 0.2, 0.02],
            [0.9, 0.9, 0.2],
        ),
    ];
    let world: Vec<[f32; 3]> = {
        let mut w: Vec<[f32; 3]> = Vec::new();
        for (_, parent, t, _, _) in &bones {
            let base = parent.map_or([0.0; 3], |p| w[p]);
            w.push([base[0] + t[0], base[1] + t[1], base[2] + t[2]]);
        }
        w
    };
    let mut buffer = Buffer::default();
    let (mut positions, mut joints, mut weights, mut indices) =
        (Vec::new(), Vec::<u16>::new(), Vec::new(), Vec::<u32>::new());
    let mut primitives = Vec::new();
    let mut materials = Vec::new();
    for (b, (name, _, _, half, colour)) in bones.iter().enumerate() {
        // The box hangs below its joint (legs) or sits above it (chest, antenna).
        let c = world[b];
        let centre = if name.starts_with("thigh") {
            [c[0], c[1] - 0.4, c[2]]
        } else if *name == "antenna_j" {
            [c[0], c[1] + 0.2, c[2]]
        } else {
            c
        };
        let first = positions.len() / 3;
        let first_index = indices.len();
        for corner in 0..8 {
            let s = |bit: usize, k: usize| {
                if corner & bit == 0 {
                    centre[k] - half[k]
                } else {
                    centre[k] + half[k]
                }
            };
            positions.extend([s(1, 0), s(2, 1), s(4, 2)]);
            joints.extend([b as u16, 0, 0, 0]);
            weights.extend([1.0f32, 0.0, 0.0, 0.0]);
        }
        for face in [
            [0, 1, 3, 2],
            [4, 6, 7, 5],
            [0, 4, 5, 1],
            [2, 3, 7, 6],
            [0, 2, 6, 4],
            [1, 5, 7, 3],
        ] {
            let q = face.map(|i| (first + i) as u32);
            indices.extend([q[0], q[1], q[2], q[0], q[2], q[3]]);
        }
        materials.push(serde_json::json!({"name": name.replace("_j", ""), "pbrMetallicRoughness": {"baseColorFactor": [colour[0], colour[1], colour[2], 1.0]}}));
        primitives.push((first_index, indices.len() - first_index, b));
    }
    let n = positions.len() / 3;
    let (lo, hi) = positions
        .chunks_exact(3)
        .fold(([f32::MAX; 3], [f32::MIN; 3]), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
            )
        });
    let position = buffer.floats(
        &positions,
        "VEC3",
        n,
        serde_json::json!({"min": lo, "max": hi}),
    );
    let joint = buffer.add(
        bytemuck::cast_slice(&joints),
        5123,
        "VEC4",
        n,
        serde_json::json!({}),
    );
    let weight = buffer.floats(&weights, "VEC4", n, serde_json::json!({}));
    let prims: Vec<serde_json::Value> = primitives
        .iter()
        .map(|&(start, count, material)| {
            let idx = buffer.add(bytemuck::cast_slice(&indices[start..start + count]), 5125, "SCALAR", count, serde_json::json!({}));
            serde_json::json!({"attributes": {"POSITION": position, "JOINTS_0": joint, "WEIGHTS_0": weight}, "indices": idx, "material": material})
        })
        .collect();
    let inverse_bind: Vec<f32> = world
        .iter()
        .flat_map(|w| {
            [
                1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -w[0], -w[1], -w[2],
                1.0,
            ]
        })
        .collect();
    let ibm = buffer.floats(&inverse_bind, "MAT4", bones.len(), serde_json::json!({}));
    // Clips: leg swing about X with amplitude `a` and period `period`, feet lifted in swing.
    let mut animations = Vec::new();
    for (clip, a, period) in [
        ("Stand", 0.0f32, 2.0f32),
        ("Stroll", 0.3, 1.0),
        ("Sprint", 0.6, 0.6),
    ] {
        let keys = 17;
        let times: Vec<f32> = (0..keys)
            .map(|k| period * k as f32 / (keys - 1) as f32)
            .collect();
        let time = buffer.floats(
            &times,
            "SCALAR",
            keys,
            serde_json::json!({"min": [0.0], "max": [period]}),
        );
        let mut channels = Vec::new();
        let mut samplers = Vec::new();
        for (thigh, foot, phase) in [(1usize, 2usize, 0.0f32), (3, 4, std::f32::consts::PI)] {
            let angle = |t: f32| a * (std::f32::consts::TAU * t / period + phase).sin();
            let rotations: Vec<f32> = times
                .iter()
                .flat_map(|&t| [(angle(t) / 2.0).sin(), 0.0, 0.0, (angle(t) / 2.0).cos()])
                .collect();
            let lifts: Vec<f32> = times
                .iter()
                .flat_map(|&t| {
                    let swing = -(std::f32::consts::TAU * t / period + phase).cos();
                    [
                        0.0,
                        -0.8 + 0.15 * swing.max(0.0) * (a > 0.0) as u8 as f32,
                        0.0,
                    ]
                })
                .collect();
            let rot = buffer.floats(&rotations, "VEC4", keys, serde_json::json!({}));
            let lift = buffer.floats(&lifts, "VEC3", keys, serde_json::json!({}));
            samplers
                .push(serde_json::json!({"input": time, "output": rot, "interpolation": "LINEAR"}));
            channels.push(serde_json::json!({"sampler": samplers.len() - 1, "target": {"node": thigh, "path": "rotation"}}));
            samplers.push(
                serde_json::json!({"input": time, "output": lift, "interpolation": "LINEAR"}),
            );
            channels.push(serde_json::json!({"sampler": samplers.len() - 1, "target": {"node": foot, "path": "translation"}}));
        }
        animations
            .push(serde_json::json!({"name": clip, "channels": channels, "samplers": samplers}));
    }
    let mut nodes: Vec<serde_json::Value> = bones
        .iter()
        .enumerate()
        .map(|(b, (name, _, t, _, _))| {
            let children: Vec<usize> = (0..bones.len())
                .filter(|&c| bones[c].1 == Some(b))
                .collect();
            let mut node = serde_json::json!({"name": name, "translation": t});
            if !children.is_empty() {
                node["children"] = serde_json::json!(children);
            }
            node
        })
        .collect();
    nodes.push(serde_json::json!({"name": "robot_mesh", "mesh": 0, "skin": 0}));
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, bones.len()]}],
        "nodes": nodes,
        "meshes": [{"name": "robot", "primitives": prims}],
        "materials": materials,
        "skins": [{"joints": (0..bones.len()).collect::<Vec<_>>(), "inverseBindMatrices": ibm}],
        "animations": animations,
        "buffers": [{"byteLength": buffer.bin.len()}],
        "bufferViews": buffer.views,
        "accessors": buffer.accessors,
    });
    std::fs::write(path, common::glb(&json, &buffer.bin)).unwrap();
}

const DESCRIPTION: &str = r#"{
  "clips": { "idle": "Stand", "walk": "Stroll", "run": "Sprint" },
  "waist_bones": ["pelvis_j"],
  "feet": ["foot_l", "foot_r"],
  "loose_parts": [
    { "name": "antenna", "kind": "tip", "materials": ["antenna"], "parent_bone": "chest_j",
      "chains": 1, "segments": 2, "stiffness": 3.0 }
  ],
  "colliders": [{ "bone": "chest_j", "radius": 0.2 }]
}"#;

#[test]
fn a_character_with_its_own_names_needs_only_its_description() {
    let dir = tempfile::tempdir().unwrap();
    let robot = dir.path().join("robot.glb");
    write_robot(&robot);

    // Without a description its clip names say nothing: the roles come from the motion
    // (Stand still, Stroll slower than Sprint), the waist and feet from bone names.
    let inferred = Description::infer(&load_character(&robot).unwrap()).unwrap();
    assert_eq!(
        (
            inferred.clips.idle.as_str(),
            inferred.clips.walk.as_str(),
            inferred.clips.run.as_str()
        ),
        ("Stand", "Stroll", "Sprint"),
        "{:?}",
        inferred.inferred
    );
    assert_eq!(inferred.waist_bones, ["pelvis_j"]);
    assert!(inferred.inferred.unwrap().contains("clips from motion"));

    std::fs::write(dir.path().join("robot.avatar.json"), DESCRIPTION).unwrap();
    let character = load_character(&robot).unwrap();
    assert_eq!(character.clips.len(), 3);
    let description = Description::find(&character, None).unwrap();
    let mut teacher = Teacher::new(character, description).unwrap();
    let p = teacher.locomotion.params;
    assert!(
        p.walk_speed > 0.1 && p.run_speed > p.walk_speed,
        "walk {} run {}",
        p.walk_speed,
        p.run_speed
    );
    assert_eq!(teacher.springs.chains.len(), 1);
    let start = teacher.root();
    for _ in 0..45 {
        teacher.step(Action::Right);
    }
    let end = teacher.root();
    assert!(start.x - end.x > 0.3, "D moves toward -X: {start} -> {end}");

    let out = dir.path().join("data");
    let manifest = bake(
        &robot,
        &out,
        &BakeOptions {
            quick: true,
            preview: true,
            ..Default::default()
        },
        &|_, _| {},
    )
    .unwrap();
    assert_eq!(manifest.avatar, "robot");
    let report = unica::dataset::validate(&out).unwrap();
    assert_eq!(report.clips, manifest.clips.len());
    assert!(report.min >= 0.0 && report.max <= 1.0);
    assert!(out.join("preview.png").is_file());
}

#[test]
fn base_colour_textures_are_sampled_at_the_vertex_uvs() {
    // A quad with a 2x2 texture (red, green / blue, white) and a grey factor; each vertex's
    // UV sits in a different texel.
    let mut png = Vec::new();
    let texels = image::RgbaImage::from_fn(2, 2, |x, y| match (x, y) {
        (0, 0) => image::Rgba([255, 0, 0, 255]),
        (1, 0) => image::Rgba([0, 255, 0, 255]),
        (0, 1) => image::Rgba([0, 0, 255, 255]),
        _ => image::Rgba([255, 255, 255, 255]),
    });
    texels
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let mut buffer = Buffer::default();
    let positions = [
        0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0,
    ];
    let uvs = [0.25f32, 0.25, 0.75, 0.25, 0.75, 0.75, 0.25, 0.75];
    let position = buffer.floats(
        &positions,
        "VEC3",
        4,
        serde_json::json!({"min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}),
    );
    let uv = buffer.floats(&uvs, "VEC2", 4, serde_json::json!({}));
    let index = buffer.add(
        bytemuck::cast_slice(&[0u32, 1, 2, 0, 2, 3]),
        5125,
        "SCALAR",
        6,
        serde_json::json!({}),
    );
    while !buffer.bin.len().is_multiple_of(4) {
        buffer.bin.push(0);
    }
    buffer.views.push(
        serde_json::json!({"buffer": 0, "byteOffset": buffer.bin.len(), "byteLength": png.len()}),
    );
    buffer.bin.extend(&png);
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "quad", "mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": position, "TEXCOORD_0": uv}, "indices": index, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0], "baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}],
        "images": [{"bufferView": buffer.views.len() - 1, "mimeType": "image/png"}],
        "buffers": [{"byteLength": buffer.bin.len()}],
        "bufferViews": buffer.views,
        "accessors": buffer.accessors,
    });
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("quad.glb");
    std::fs::write(&path, common::glb(&json, &buffer.bin)).unwrap();
    let colours = load_character(&path).unwrap().rest_mesh().colors;
    // Linear colour = factor × sRGB-decoded texel (255 -> 1.0).
    let expected = [
        [0.5, 0.0, 0.0],
        [0.0, 0.5, 0.0],
        [0.5, 0.5, 0.5],
        [0.0, 0.0, 0.5],
    ];
    for (got, want) in colours.iter().zip(expected) {
        assert!(
            got.abs_diff_eq(glam::Vec3::from(want), 1e-6),
            "{got} vs {want:?}"
        );
    }
}
