//! The teacher on characters unlike the Witch, with no hand-written description: four
//! small synthetic block humanoids written as .glb here — (a) a 16-joint rig of its own,
//! (b) one whose clips live in separate animation files (`--clips`), (c) a big head over
//! a low waist, (d) bones named Bone.000… with unnamed clips. Each renders with
//! `render --teacher` (the whole character in every frame), bakes and validates.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use glam::{Quat, Vec3};
use serde_json::Value;
use unica::autorig::gltf_out::{ClipOut, JointOut, RiggedMesh, write_glb};
use unica::avatar::rig::Transform;
use unica::mesh::Mesh;

fn unica(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_unica"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    err
}

/// Body proportions of a block humanoid (metres).
struct Body {
    /// Hips height above the ground (leg length).
    hips: f32,
    /// Spine length from the hips to the neck.
    torso: f32,
    /// Head cube edge.
    head: f32,
    /// Names: root, hips, spine, neck, head, thigh/shin/foot L and R, arm L and R,
    /// hand L and R, then (Witch-unlike) a tail — 16 joints.
    names: [&'static str; 16],
}

const CONVENTIONAL: [&str; 16] = [
    "root", "pelvis", "spine", "neck", "head", "thigh.L", "shin.L", "foot.L", "thigh.R", "shin.R",
    "foot.R", "arm.L", "hand.L", "arm.R", "hand.R", "tail",
];

fn bone_names() -> [&'static str; 16] {
    [
        "Bone.000", "Bone.001", "Bone.002", "Bone.003", "Bone.004", "Bone.005", "Bone.006",
        "Bone.007", "Bone.008", "Bone.009", "Bone.010", "Bone.011", "Bone.012", "Bone.013",
        "Bone.014", "Bone.015",
    ]
}

const PARENTS: [Option<usize>; 16] = [
    None,
    Some(0),
    Some(1),
    Some(2),
    Some(3),
    Some(1),
    Some(5),
    Some(6),
    Some(1),
    Some(8),
    Some(9),
    Some(3),
    Some(11),
    Some(3),
    Some(13),
    Some(1),
];

impl Body {
    /// World rest positions of the joints.
    fn positions(&self) -> [Vec3; 16] {
        let (h, t) = (self.hips, self.torso);
        let w = 0.12;
        let neck = h + t;
        [
            Vec3::ZERO,
            Vec3::new(0.0, h, 0.0),
            Vec3::new(0.0, h + 0.4 * t, 0.0),
            Vec3::new(0.0, neck, 0.0),
            Vec3::new(0.0, neck + 0.05, 0.0),
            Vec3::new(w, h, 0.0),
            Vec3::new(w, 0.5 * h, 0.0),
            Vec3::new(w, 0.02, 0.05),
            Vec3::new(-w, h, 0.0),
            Vec3::new(-w, 0.5 * h, 0.0),
            Vec3::new(-w, 0.02, 0.05),
            Vec3::new(0.2, neck - 0.05, 0.0),
            Vec3::new(0.25, neck - 0.4 * t, 0.0),
            Vec3::new(-0.2, neck - 0.05, 0.0),
            Vec3::new(-0.25, neck - 0.4 * t, 0.0),
            Vec3::new(0.0, h, -0.12),
        ]
    }

    /// Boxes skinned rigidly to one joint each: (joint, centre, half size).
    fn boxes(&self) -> Vec<(usize, Vec3, Vec3)> {
        let p = self.positions();
        let mid = |a: usize, b: usize| (p[a] + p[b]) * 0.5;
        let half_len = |a: usize, b: usize| (p[a] - p[b]).length() * 0.5;
        let limb = |a: usize, b: usize, r: f32| (a, mid(a, b), Vec3::new(r, half_len(a, b), r));
        let h = self.head * 0.5;
        vec![
            (
                1,
                p[1] + Vec3::new(0.0, 0.02, 0.0),
                Vec3::new(0.17, 0.1, 0.11),
            ),
            (2, mid(2, 3), Vec3::new(0.15, half_len(2, 3) + 0.02, 0.09)),
            limb(5, 6, 0.06),
            limb(6, 7, 0.05),
            (
                7,
                p[7] + Vec3::new(0.0, 0.01, 0.03),
                Vec3::new(0.05, 0.03, 0.09),
            ),
            limb(8, 9, 0.06),
            limb(9, 10, 0.05),
            (
                10,
                p[10] + Vec3::new(0.0, 0.01, 0.03),
                Vec3::new(0.05, 0.03, 0.09),
            ),
            limb(11, 12, 0.04),
            limb(13, 14, 0.04),
            (4, p[4] + Vec3::new(0.0, h, 0.0), Vec3::splat(h)),
            (
                15,
                p[15] + Vec3::new(0.0, -0.05, -0.05),
                Vec3::new(0.03, 0.03, 0.06),
            ),
        ]
    }
}

/// A clip: idle (breathing, feet still), walk or run (legs swinging in place: each foot
/// slides back at a steady speed while planted, then swings forward lifted by the knee).
fn clip(name: &str, kind: &str) -> ClipOut {
    const KEYS: usize = 24;
    let (amplitude, cycle) = match kind {
        "walk" => (0.35, 1.0),
        "run" => (0.55, 0.6),
        _ => (0.0, 2.0),
    };
    let times: Vec<f32> = (0..=KEYS).map(|k| cycle * k as f32 / KEYS as f32).collect();
    let mut rotations = vec![vec![Quat::IDENTITY; times.len()]; 16];
    for (k, &t) in times.iter().enumerate() {
        let phase = t / cycle;
        // Thigh angle about +x (positive swings the foot backward) and knee bend.
        let leg = |offset: f32| {
            let s = (phase + offset).rem_euclid(1.0);
            if s < 0.5 {
                (-amplitude + 4.0 * amplitude * s, 0.0)
            } else {
                let u = (s - 0.5) * 2.0;
                (
                    amplitude - 2.0 * amplitude * u,
                    1.2 * (std::f32::consts::PI * u).sin(),
                )
            }
        };
        if amplitude > 0.0 {
            for (thigh, shin, offset) in [(5, 6, 0.0), (8, 9, 0.5)] {
                let (angle, knee) = leg(offset);
                rotations[thigh][k] = Quat::from_rotation_x(angle);
                rotations[shin][k] = Quat::from_rotation_x(knee);
            }
            let swing = (std::f32::consts::TAU * phase).sin() * amplitude;
            rotations[11][k] = Quat::from_rotation_x(swing);
            rotations[13][k] = Quat::from_rotation_x(-swing);
        } else {
            let breath = 0.03 * (std::f32::consts::TAU * phase).sin();
            rotations[2][k] = Quat::from_rotation_x(breath);
            rotations[11][k] = Quat::from_rotation_z(breath);
        }
        rotations[15][k] = Quat::from_rotation_y(0.3 * (std::f32::consts::TAU * phase).sin());
    }
    ClipOut {
        name: name.into(),
        times,
        rotations,
        root_translations: Vec::new(),
    }
}

fn cube(mesh: &mut Mesh, centre: Vec3, half: Vec3, colour: Vec3) {
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut n = Vec3::ZERO;
            n[axis] = sign;
            let (u, v) = (Vec3::new(n.y, n.z, n.x), Vec3::new(n.z, n.x, n.y));
            let base = mesh.positions.len() as u32;
            for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                mesh.positions.push(centre + (n + u * a + v * b) * half);
                mesh.normals.push(n);
                mesh.colors.push(colour);
            }
            mesh.indices
                .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
}

/// Writes the block humanoid `body` with `clips` to `path`.
fn write_character(path: &Path, body: &Body, clips: &[ClipOut]) {
    let positions = body.positions();
    let joints: Vec<JointOut> = (0..16)
        .map(|j| JointOut {
            name: body.names[j].into(),
            parent: PARENTS[j],
            rest: Transform {
                translation: positions[j] - PARENTS[j].map_or(Vec3::ZERO, |p| positions[p]),
                rotation: Quat::IDENTITY,
                scale: Vec3::ONE,
            },
        })
        .collect();
    let mut mesh = Mesh::default();
    let mut skin_joints = Vec::new();
    for (joint, centre, half) in body.boxes() {
        // Bright red, so renders tell the character from the grey floor and background.
        cube(&mut mesh, centre, half, Vec3::new(0.9, 0.03, 0.03));
        skin_joints.resize(mesh.positions.len(), [joint as u16, 0, 0, 0]);
    }
    let skin_weights = vec![[1.0, 0.0, 0.0, 0.0]; mesh.positions.len()];
    let stem = path.file_stem().unwrap().to_str().unwrap();
    write_glb(
        path,
        &RiggedMesh {
            name: stem,
            mesh: &mesh,
            joints: &joints,
            skin_joints: &skin_joints,
            skin_weights: &skin_weights,
            clips,
            vrm: None,
        },
    )
    .unwrap();
}

/// Rewrites the JSON chunk of a .glb written by `write_glb`.
fn edit_glb(path: &Path, edit: impl FnOnce(&mut Value)) {
    let bytes = std::fs::read(path).unwrap();
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let mut json: Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
    let bin = &bytes[20 + json_len..];
    edit(&mut json);
    let mut text = json.to_string().into_bytes();
    text.resize(text.len().next_multiple_of(4), b' ');
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&((12 + 8 + text.len() + bin.len()) as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(bin);
    std::fs::write(path, out).unwrap();
}

/// Drops the mesh, skin and material (the mesh node is the last node): a skeleton with
/// clips only, as animation libraries ship.
fn strip_mesh(json: &mut Value) {
    let obj = json.as_object_mut().unwrap();
    for key in ["meshes", "skins", "materials"] {
        obj.remove(key);
    }
    let nodes = obj["nodes"].as_array_mut().unwrap();
    let mesh_node = nodes.len() - 1;
    nodes.pop();
    let roots = obj["scenes"][0]["nodes"].as_array_mut().unwrap();
    roots.retain(|n| n.as_u64() != Some(mesh_node as u64));
}

fn normal_body(names: [&'static str; 16]) -> Body {
    Body {
        hips: 0.9,
        torso: 0.6,
        head: 0.25,
        names,
    }
}

/// Bounding rows (top, bottom) of the pixels that are clearly the red character, and
/// their count.
fn red_rows(png: &Path) -> (u32, u32, usize) {
    let image = image::open(png).unwrap().to_rgba8();
    let (mut top, mut bottom, mut count) = (u32::MAX, 0, 0);
    for (_, y, p) in image.enumerate_pixels() {
        let [r, g, b, a] = p.0.map(i32::from);
        if a > 0 && r > 40 && r > 2 * (g + b) {
            top = top.min(y);
            bottom = bottom.max(y);
            count += 1;
        }
    }
    (top, bottom, count)
}

/// `render --teacher` a few frames of walking, turning and stopping: every view of every
/// frame shows the whole character, clear of the top and bottom borders.
fn renders_whole(character: &Path, clips: &[&Path], dir: &Path) {
    let out = dir.join("render");
    let mut args = vec![
        "render",
        "--teacher",
        character.to_str().unwrap(),
        "--keys",
        "6I 12W 8A 6I",
        "--size",
        "64",
        "--views",
        "2",
        "--out",
        out.to_str().unwrap(),
    ];
    if !clips.is_empty() {
        args.push("--clips");
        args.extend(clips.iter().map(|c| c.to_str().unwrap()));
    }
    ok(&unica(&args));
    let mut checked = 0;
    for entry in std::fs::read_dir(&out).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "png") {
            let (top, bottom, count) = red_rows(&path);
            assert!(
                count > 40,
                "{}: the character is not in view",
                path.display()
            );
            assert!(
                top > 0 && bottom < 63,
                "{}: the character touches the border (rows {top}..{bottom})",
                path.display()
            );
            checked += 1;
        }
    }
    assert_eq!(checked, 32 * 2);
}

/// `bake --quick` then `validate`; returns the bake's standard error (the inferred line)
/// and the validation report.
fn bakes_and_validates(
    character: &Path,
    clips: &[&Path],
    dir: &Path,
    renders: bool,
) -> (String, Value) {
    let data = dir.join("data");
    let mut args = vec![
        "bake",
        character.to_str().unwrap(),
        "--out",
        data.to_str().unwrap(),
        "--quick",
    ];
    if !renders {
        args.push("--no-renders");
    }
    if !clips.is_empty() {
        args.push("--clips");
        args.extend(clips.iter().map(|c| c.to_str().unwrap()));
    }
    let stderr = ok(&unica(&args));
    let report = unica(&["validate", data.to_str().unwrap()]);
    ok(&report);
    let report: Value = serde_json::from_slice(&report.stdout).unwrap();
    let (min, max) = (
        report["min"].as_f64().unwrap(),
        report["max"].as_f64().unwrap(),
    );
    assert!(min >= 0.04 && max <= 0.96, "margin kept: {report}");
    (stderr, report)
}

/// With `UNICA_KEEP_CHARACTERS=DIR`, copies the character files a test wrote into DIR
/// (the character of the full `unica make` in docs/make.md, and the block humanoids
/// measured in docs/autorig, were made this way).
fn keep_for_make(files: &[&Path]) {
    if let Some(dir) = std::env::var_os("UNICA_KEEP_CHARACTERS") {
        let dir = Path::new(&dir);
        std::fs::create_dir_all(dir).unwrap();
        for file in files {
            std::fs::copy(file, dir.join(file.file_name().unwrap())).unwrap();
        }
    }
}

fn inferred(stderr: &str) -> String {
    let lines: Vec<&str> = stderr.lines().filter(|l| l.contains("inferred:")).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    lines[0].to_string()
}

#[test]
fn a_rig_of_its_own_with_named_bones_and_clips() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("blocky.glb");
    let body = normal_body(CONVENTIONAL);
    let clips = [
        clip("Idle_Loop", "idle"),
        clip("Walk_Loop", "walk"),
        clip("Run_Fast", "run"),
    ];
    write_character(&path, &body, &clips);
    renders_whole(&path, &[], dir.path());
    let (stderr, _) = bakes_and_validates(&path, &[], dir.path(), false);
    let line = inferred(&stderr);
    assert!(
        line.contains("waist=pelvis feet=foot.L,foot.R idle=Idle_Loop walk=Walk_Loop run=Run_Fast")
            && line.contains("bones from names, clips from names"),
        "{line}"
    );
}

#[test]
fn clips_from_separate_animation_files() {
    let dir = tempfile::tempdir().unwrap();
    let body = normal_body(CONVENTIONAL);
    let path = dir.path().join("meshonly.glb");
    write_character(&path, &body, &[clip("Pose", "idle")]);
    edit_glb(&path, |json| {
        json.as_object_mut().unwrap().remove("animations");
    });
    // Two libraries, skeletons only: one with the idle, one with walk and run.
    let (idle_lib, move_lib) = (
        dir.path().join("anim_idle.glb"),
        dir.path().join("anim_move.glb"),
    );
    write_character(&idle_lib, &body, &[clip("Breathe", "idle")]);
    write_character(
        &move_lib,
        &body,
        &[clip("Stroll", "walk"), clip("Dash", "run")],
    );
    edit_glb(&idle_lib, strip_mesh);
    edit_glb(&move_lib, strip_mesh);

    // Without --clips: the file has no clips, and the error says where they go.
    let out = unica(&[
        "bake",
        path.to_str().unwrap(),
        "--out",
        dir.path().join("none").to_str().unwrap(),
        "--no-renders",
        "--quick",
    ]);
    assert!(!out.status.success());
    let err = common::error_line(&out);
    assert!(
        err.contains("meshonly.glb")
            && err.contains("no animation clips")
            && err.contains("--clips"),
        "{err}"
    );

    let libs = [idle_lib.as_path(), move_lib.as_path()];
    keep_for_make(&[&path, &idle_lib, &move_lib]);
    renders_whole(&path, &libs, dir.path());
    let (stderr, _) = bakes_and_validates(&path, &libs, dir.path(), false);
    let line = inferred(&stderr);
    // Names say nothing of Breathe/Stroll/Dash: the roles come from the feet.
    assert!(
        line.contains("idle=Breathe")
            && line.contains("walk=Stroll (")
            && line.contains("run=Dash (")
            && line.contains("clips from motion"),
        "{line}"
    );
    let manifest: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("data/manifest.json")).unwrap())
            .unwrap();
    assert_eq!(manifest["clip_files"].as_array().unwrap().len(), 2);
}

#[test]
fn a_big_head_over_a_low_waist_stays_in_the_unit_cube_and_in_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bighead.glb");
    let body = Body {
        hips: 0.35,
        torso: 0.3,
        head: 0.9,
        names: CONVENTIONAL,
    };
    let clips = [
        clip("idle", "idle"),
        clip("walk", "walk"),
        clip("run", "run"),
    ];
    write_character(&path, &body, &clips);
    keep_for_make(&[&path]);
    renders_whole(&path, &[], dir.path());
    let (_, report) = bakes_and_validates(&path, &[], dir.path(), true);
    assert!(report["renders"].as_u64().unwrap() > 50, "{report}");
    // The bake's own renders (transparent background) frame the whole character too.
    let data = dir.path().join("data/renders");
    for file in [
        "rest/cam_00.png",
        "rest/cam_25.png",
        "clip_001/f0010_front.png",
        "clip_003/f0020_left.png",
    ] {
        let image = image::open(data.join(file)).unwrap().to_rgba8();
        let rows: Vec<u32> = image
            .enumerate_pixels()
            .filter(|(_, _, p)| p.0[3] > 0)
            .map(|(_, y, _)| y)
            .collect();
        let (top, bottom) = (*rows.iter().min().unwrap(), *rows.iter().max().unwrap());
        assert!(
            top > 0 && bottom + 1 < image.height(),
            "{file}: rows {top}..{bottom}"
        );
    }
    // The head passes 1 at the extent's scale (0.7 / 1.55 m from a waist 0.35 m up):
    // the bake lowered the scale.
    let manifest: Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("data/manifest.json")).unwrap())
            .unwrap();
    let extent_scale = 0.7 / (0.35 + 0.3 + 0.05 + 0.9);
    assert!(manifest["norm_scale"].as_f64().unwrap() < extent_scale - 1e-3);
}

#[test]
fn bone_numbers_and_unnamed_clips_are_read_from_the_skeleton_and_the_motion() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("numbered.glb");
    let body = normal_body(bone_names());
    let clips = [clip("a", "run"), clip("b", "idle"), clip("c", "walk")];
    write_character(&path, &body, &clips);
    edit_glb(&path, |json| {
        for animation in json["animations"].as_array_mut().unwrap() {
            animation.as_object_mut().unwrap().remove("name");
        }
    });
    // A wrong bone in a description lists the rig's bones.
    let wrong = dir.path().join("wrong.avatar.json");
    std::fs::write(
        &wrong,
        r#"{"clips": {"idle": "clip1", "walk": "clip2", "run": "clip0"},
            "waist_bones": ["Hips"], "feet": ["Bone.007", "Bone.010"]}"#,
    )
    .unwrap();
    let out = unica(&[
        "bake",
        path.to_str().unwrap(),
        "--avatar",
        wrong.to_str().unwrap(),
        "--out",
        dir.path().join("wrong").to_str().unwrap(),
        "--no-renders",
        "--quick",
    ]);
    let err = common::error_line(&out);
    assert!(
        err.contains("bone 'Hips'")
            && err.contains("Bone.000, Bone.001")
            && err.contains("Bone.015"),
        "{err}"
    );

    renders_whole(&path, &[], dir.path());
    let (stderr, _) = bakes_and_validates(&path, &[], dir.path(), false);
    let line = inferred(&stderr);
    // Bone.001 is where the legs meet, Bone.007/Bone.010 their lowest leaves; clip0 runs,
    // clip1 stands, clip2 walks.
    assert!(
        line.contains("waist=Bone.001 feet=Bone.007,Bone.010 idle=clip1 (0.00 m/s) walk=clip2 (")
            && line.contains("run=clip0 (")
            && line.contains("bones from the skeleton, clips from motion"),
        "{line}"
    );
    // The planted foot slides back over 4 x amplitude radians of thigh swing per cycle on
    // a 0.88 m leg: about 0.88 * 4 * 0.35 / 1.0 s = 1.23 m/s walking and
    // 0.88 * 4 * 0.55 / 0.6 s = 3.23 m/s running (less a little for cos(angle)).
    let speed = |clip: &str| -> f32 {
        let rest = &line[line.find(&format!("={clip} (")).unwrap() + clip.len() + 3..];
        rest[..rest.find(' ').unwrap()].parse().unwrap()
    };
    assert!((1.1..1.3).contains(&speed("clip2")), "{line}");
    assert!((2.9..3.3).contains(&speed("clip0")), "{line}");
}

#[test]
fn one_walking_clip_is_walk_and_run_and_the_rest_pose_idles() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("onlywalk.glb");
    let body = normal_body(bone_names());
    write_character(&path, &body, &[clip("Take 001", "walk")]);
    let (stderr, _) = bakes_and_validates(&path, &[], dir.path(), false);
    let line = inferred(&stderr);
    assert!(
        line.contains("idle=- (the rest pose) walk=Take 001 (")
            && line.contains("run=- (the walk clip played faster)"),
        "{line}"
    );
}

#[test]
fn bad_clip_files_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let body = normal_body(CONVENTIONAL);
    let path = dir.path().join("c.glb");
    write_character(&path, &body, &[clip("Walk", "walk")]);
    edit_glb(&path, |json| {
        json.as_object_mut().unwrap().remove("animations");
    });
    // A library whose joints share no name with the character.
    let other = dir.path().join("other.glb");
    write_character(&other, &normal_body(bone_names()), &[clip("Walk", "walk")]);
    let missing = dir.path().join("missing.glb");
    for (clips, expect) in [
        (
            &other,
            "no animation moves a joint of the character by name",
        ),
        (&missing, "no such file"),
        (&path, "the file has no animations"),
    ] {
        let out = unica(&[
            "bake",
            path.to_str().unwrap(),
            "--clips",
            clips.to_str().unwrap(),
            "--out",
            dir.path().join("x").to_str().unwrap(),
            "--no-renders",
        ]);
        let err = common::error_line(&out);
        let name = clips.file_name().unwrap().to_str().unwrap();
        assert!(err.contains(name) && err.contains(expect), "{err}");
    }
}

/// A VRM 1.0 file (`.vrm`): numbered bones that only its `VRMC_vrm` map names, and a
/// spring on its tail (`VRMC_springBone`: the tail swings toward an end node, kept out of
/// a sphere on the hips) that the teacher uses as written.
#[test]
fn a_vrm_file_bakes_with_its_own_humanoid_map_and_springs() {
    use unica::action::Action;
    use unica::avatar::description::Description;
    use unica::avatar::teacher::Teacher;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("numbered.vrm");
    let body = normal_body(bone_names());
    let clips = [
        clip("idle", "idle"),
        clip("walk", "walk"),
        clip("run", "run"),
    ];
    write_character(&path, &body, &clips);
    edit_glb(&path, |json| {
        // An end node below the tail (node 15), 0.15 m further back.
        let nodes = json["nodes"].as_array_mut().unwrap();
        let end = nodes.len();
        nodes.push(serde_json::json!({"name": "tail_end", "translation": [0.0, 0.0, -0.15]}));
        nodes[15]["children"] = serde_json::json!([end]);
        // Bones by VRM name: the file's own map is the only thing that says which they are.
        let map = [
            ("hips", 1),
            ("spine", 2),
            ("neck", 3),
            ("head", 4),
            ("leftUpperLeg", 5),
            ("leftLowerLeg", 6),
            ("leftFoot", 7),
            ("rightUpperLeg", 8),
            ("rightLowerLeg", 9),
            ("rightFoot", 10),
            ("leftUpperArm", 11),
            ("leftHand", 12),
            ("rightUpperArm", 13),
            ("rightHand", 14),
        ];
        let bones: serde_json::Map<String, Value> = map
            .iter()
            .map(|(name, node)| (name.to_string(), serde_json::json!({"node": node})))
            .collect();
        json["extensionsUsed"] = serde_json::json!(["VRMC_vrm", "VRMC_springBone"]);
        json["extensions"] = serde_json::json!({
            "VRMC_vrm": {"specVersion": "1.0", "meta": {"name": "numbered", "authors": ["test"],
                "licenseUrl": "https://vrm.dev/licenses/1.0/"},
                "humanoid": {"humanBones": bones}},
            "VRMC_springBone": {"specVersion": "1.0",
                "colliders": [{"node": 1, "shape": {"sphere": {"offset": [0.0, 0.0, 0.0], "radius": 0.12}}}],
                "colliderGroups": [{"name": "hips", "colliders": [0]}],
                "springs": [{"name": "tail", "colliderGroups": [0], "joints": [
                    {"node": 15, "hitRadius": 0.02, "stiffness": 0.5, "gravityPower": 1.0,
                     "gravityDir": [0.0, -1.0, 0.0], "dragForce": 0.3},
                    {"node": end}]}]}
        });
    });
    let character = unica::avatar::load_character(&path).unwrap();
    let vrm = character.vrm.clone().expect("the VRM extensions are read");
    assert_eq!(vrm.bone("hips"), character.rig.find("Bone.001"));
    assert_eq!(vrm.springs.len(), 1);
    let description = Description::find(&character, None).unwrap();
    assert_eq!(description.waist_bones, ["Bone.001"]);
    assert_eq!(description.feet, ["Bone.007", "Bone.010"]);
    let mut teacher = Teacher::new(character, description).unwrap();
    // One chain: the tail swings (the end node is only its tail), kept out of the sphere.
    assert_eq!(teacher.springs.chains.len(), 1);
    assert_eq!(teacher.springs.colliders.len(), 1);
    assert_eq!(
        teacher.springs.chains[0].colliders.as_deref(),
        Some(&[0][..])
    );
    // The tail swings away from where its parent would hold it (0.15 m back from the
    // tail joint in the pelvis's frame), and the end node follows the simulated tail.
    let rig = &teacher.character.rig;
    let (pelvis, tail, end) = (
        rig.find("Bone.001").unwrap(),
        rig.find("Bone.015").unwrap(),
        rig.find("tail_end").unwrap(),
    );
    let mut swing: f32 = 0.0;
    for _ in 0..30 {
        teacher.step(Action::Forward);
        let world = teacher.world();
        let at = |n: usize| world[n].w_axis.truncate();
        assert!(at(end).distance(teacher.springs.chains[0].tails()[0]) < 1e-4);
        let held = world[pelvis].transform_vector3(Vec3::NEG_Z).normalize();
        swing = swing.max((at(end) - at(tail)).normalize().angle_between(held));
    }
    assert!(swing.to_degrees() > 5.0, "the tail swings ({swing} rad)");

    renders_whole(&path, &[], dir.path());
    let (stderr, _) = bakes_and_validates(&path, &[], dir.path(), false);
    let line = inferred(&stderr);
    assert!(
        line.contains("waist=Bone.001 feet=Bone.007,Bone.010")
            && line.contains("bones from VRMC_vrm"),
        "{line}"
    );
}

/// A VRM spring whose joints are not each below the one before, and a collider on a node
/// outside the scene: one-line errors naming the file and the field, nothing written.
#[test]
fn bad_vrm_springs_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let body = normal_body(CONVENTIONAL);
    let clips = [
        clip("idle", "idle"),
        clip("walk", "walk"),
        clip("run", "run"),
    ];
    for (name, extension, expect) in [
        (
            "upside.vrm",
            serde_json::json!({"VRMC_springBone": {"specVersion": "1.0",
                "springs": [{"joints": [{"node": 15}, {"node": 1}]}]}}),
            "VRMC_springBone.springs[0].joints[1]: node 'pelvis' is not below the joint before it, 'tail'",
        ),
        (
            "nowhere.vrm",
            serde_json::json!({"VRMC_springBone": {"specVersion": "1.0",
                "colliders": [{"node": 99, "shape": {"sphere": {"radius": 0.1}}}]}}),
            "VRMC_springBone.colliders[0].node: node 99 is not in the scene",
        ),
    ] {
        let path = dir.path().join(name);
        write_character(&path, &body, &clips);
        edit_glb(&path, |json| json["extensions"] = extension);
        let out = dir.path().join(format!("{name}.data"));
        let run = unica(&[
            "bake",
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-renders",
            "--quick",
        ]);
        assert!(!run.status.success());
        let err = common::error_line(&run);
        assert!(err.contains(name) && err.contains(expect), "{err}");
        assert!(!out.exists(), "nothing written");
    }
}

/// Every file below `dir`, relative to it.
fn files_below(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(
                files_below(&path)
                    .into_iter()
                    .map(|p| path.strip_prefix(dir).unwrap().join(p)),
            );
        } else {
            out.push(path.strip_prefix(dir).unwrap().to_path_buf());
        }
    }
    out
}

#[test]
fn names_from_the_file_write_nothing_outside_the_output_folder() {
    // Clip, joint, mesh, node, material and scene names holding `../`, `/` and `\`, deep
    // enough to climb from any output folder to /tmp: bake and render write only below
    // their output folders, and no written file is named after them.
    let dir = tempfile::tempdir().unwrap();
    let tag = format!("unica_escape_{}", std::process::id());
    let climb = |what: &str| format!("../../../../../../../../../../tmp/{tag}_{what}");
    let input = dir.path().join("in");
    std::fs::create_dir(&input).unwrap();
    let path = input.join("blocky.glb");
    let mut names = CONVENTIONAL;
    let tail: &'static str = Box::leak(climb("tail").into_boxed_str());
    names[15] = tail;
    let clips = [
        clip(&climb("Idle"), "idle"),
        clip(&format!("/tmp/{tag}_Walk"), "walk"),
        clip(&format!("..\\..\\..\\..\\{tag}_Run"), "run"),
    ];
    write_character(&path, &normal_body(names), &clips);
    edit_glb(&path, |json| {
        for key in ["meshes", "scenes", "materials"] {
            for item in json[key].as_array_mut().into_iter().flatten() {
                item["name"] = Value::from(climb(key));
            }
        }
        for node in json["nodes"].as_array_mut().unwrap() {
            if node.get("mesh").is_some() {
                node["name"] = Value::from(climb("node"));
            }
        }
    });
    let out = dir.path().join("out");
    ok(&unica(&[
        "bake",
        path.to_str().unwrap(),
        "--out",
        out.join("data").to_str().unwrap(),
        "--quick",
        "--no-renders",
    ]));
    ok(&unica(&[
        "render",
        "--teacher",
        path.to_str().unwrap(),
        "--keys",
        "3W",
        "--size",
        "64",
        "--views",
        "1",
        "--out",
        out.join("render").to_str().unwrap(),
    ]));
    for file in files_below(dir.path()) {
        assert!(
            file.starts_with("in") || file.starts_with("out"),
            "{} was written outside the output folders",
            file.display()
        );
        assert!(
            !file.to_string_lossy().contains("escape"),
            "{} is named after a name from the file",
            file.display()
        );
    }
    assert!(files_below(&out.join("data")).len() > 2);
    assert!(files_below(&out.join("render")).len() > 2);
    let leaked: Vec<_> = std::fs::read_dir("/tmp")
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with(&tag))
        .map(|e| e.path())
        .collect();
    assert!(leaked.is_empty(), "written outside: {leaked:?}");
}
