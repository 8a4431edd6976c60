//! Character loading: the shared Witch loads with the counts its SOURCE.md states, and bad
//! files fail with errors that name the file and the problem.

mod common;

use common::witch;

use std::path::Path;

use unica::avatar::load_character;

#[test]
fn the_witch_loads_in_its_rest_pose() {
    let character =
        load_character(&witch()).expect("the shipped Witch (assets/witch/source) loads");
    assert_eq!(character.name, "Witch");
    let mesh = &character.rest_mesh();
    // SOURCE.md: 4 skinned meshes, 13,884 vertices, about 6.9k triangles.
    assert_eq!(mesh.positions.len(), 13_884);
    let triangles = mesh.indices.len() / 3;
    assert!((6_500..7_500).contains(&triangles), "{triangles} triangles");
    let (lo, hi) = mesh.bounds().unwrap();
    let height = hi.y - lo.y;
    assert!(
        (1.8..2.2).contains(&height),
        "height {height} (about 2.0 with the hat)"
    );
    assert!(lo.y.abs() < 0.05, "feet on the ground: min y {}", lo.y);
    // Six flat materials: a handful of distinct colours, none black-and-missing.
    let mut colours: Vec<[u32; 3]> = mesh
        .colors
        .iter()
        .map(|c| (*c * 1000.0).as_uvec3().to_array())
        .collect();
    colours.sort();
    colours.dedup();
    assert!((4..=6).contains(&colours.len()), "{colours:?}");
    assert!(mesh.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-3));
    // One skin of 62 joints (SOURCE.md), the locomotion clips with their durations.
    assert_eq!(character.rig.bones.len(), 62);
    for (name, seconds) in [
        ("Idle", 2.083),
        ("Walk", 1.667),
        ("Run", 1.0),
        ("Run_Back", 1.042),
    ] {
        let clip = character.clip(name).unwrap();
        assert!(
            (clip.duration - seconds).abs() < 1e-3,
            "{name}: {}",
            clip.duration
        );
    }
    assert_eq!(character.clips.len(), 24);
    let err = character.clip("Moonwalk").unwrap_err().to_string();
    assert!(
        err.contains("Witch.gltf")
            && err.contains("'Moonwalk' not found")
            && err.contains("Run_Left"),
        "{err}"
    );
}

#[test]
fn missing_and_unsupported_files_are_named() {
    let err = load_character(Path::new("/nonexistent/hero.glb")).unwrap_err();
    assert!(
        err.to_string().contains("/nonexistent/hero.glb")
            && err.to_string().contains("no such file"),
        "{err}"
    );
    let dir = tempfile::tempdir().unwrap();
    let fbx = dir.path().join("hero.fbx");
    std::fs::write(&fbx, b"x").unwrap();
    let err = load_character(&fbx).unwrap_err().to_string();
    assert!(
        err.contains("hero.fbx") && err.contains("unsupported file type"),
        "{err}"
    );
}

#[test]
fn corrupt_files_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let gltf = dir.path().join("broken.gltf");
    std::fs::write(&gltf, b"{ \"asset\": ").unwrap();
    let err = load_character(&gltf).unwrap_err().to_string();
    assert!(err.contains("broken.gltf"), "{err}");
    // A truncated copy of the Witch (buffers cut off mid data URI).
    let bytes = std::fs::read(witch()).unwrap();
    let truncated = dir.path().join("truncated.gltf");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    assert!(
        load_character(&truncated)
            .unwrap_err()
            .to_string()
            .contains("truncated.gltf")
    );
    let obj = dir.path().join("empty.obj");
    std::fs::write(&obj, b"# nothing\n").unwrap();
    let err = load_character(&obj).unwrap_err().to_string();
    assert!(err.contains("empty.obj"), "{err}");
}

#[test]
fn an_obj_without_materials_loads_grey_with_normals() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("quad.obj");
    std::fs::write(
        &obj,
        "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    )
    .unwrap();
    let mesh = load_character(&obj).unwrap().rest_mesh();
    assert_eq!(mesh.indices.len(), 6, "the quad is triangulated");
    for n in &mesh.normals {
        assert!(n.abs_diff_eq(glam::Vec3::Z, 1e-6), "{n}");
    }
    let grey = glam::Vec3::splat(0.7);
    assert!(mesh.colors.iter().all(|c| c.abs_diff_eq(grey, 1e-6)));
}

#[test]
fn the_witch_teacher_runs_where_the_keys_say() {
    use unica::action::Action;
    use unica::avatar::description::Description;
    use unica::avatar::teacher::Teacher;
    let character = load_character(&witch()).unwrap();
    let description = Description::find(&character, None).unwrap();
    let mut teacher = Teacher::new(character, description).unwrap();
    let p = teacher.locomotion.params;
    eprintln!(
        "measured walk {:.2} m/s, run {:.2} m/s",
        p.walk_speed, p.run_speed
    );
    assert!((0.5..3.0).contains(&p.walk_speed), "walk {}", p.walk_speed);
    assert!(
        (1.5..8.0).contains(&p.run_speed) && p.run_speed > p.walk_speed,
        "run {}",
        p.run_speed
    );
    let start = teacher.root();
    for _ in 0..60 {
        teacher.step(Action::Forward);
    }
    let after_w = teacher.root();
    assert!(
        after_w.z - start.z > 1.0 && (after_w.x - start.x).abs() < 0.2,
        "{start} -> {after_w}"
    );
    for _ in 0..60 {
        teacher.step(Action::Left);
    }
    let after_a = teacher.root();
    assert!(
        after_a.x - after_w.x > 1.0,
        "A goes +X: {after_w} -> {after_a}"
    );
    // The posed mesh follows the root.
    let (lo, hi) = teacher.mesh().bounds().unwrap();
    let centre = (lo + hi) * 0.5;
    assert!((centre.x - after_a.x).abs() < 0.5 && (centre.z - after_a.z).abs() < 0.5);
}

#[test]
fn spring_chains_leave_the_rest_pose_alone_and_swing_in_motion() {
    use unica::action::Action;
    use unica::avatar::description::Description;
    use unica::avatar::loose::add_spring_chains;
    use unica::avatar::teacher::Teacher;
    let plain = load_character(&witch()).unwrap();
    let description = Description::find(&plain, None).unwrap();
    let mut sprung = plain.clone();
    let springs = add_spring_chains(&mut sprung, &description).unwrap();
    assert_eq!(
        springs.chains.len(),
        10 + 4 + 1,
        "skirt, hair and hat chains"
    );
    assert_eq!(sprung.rig.bones.len(), 62 + 10 * 3 + 4 * 3 + 3);
    // At rest the new bones reproduce the old skinning exactly.
    let (a, b) = (plain.rest_mesh(), sprung.rest_mesh());
    let worst = a
        .positions
        .iter()
        .zip(&b.positions)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "rest pose moved by {worst}");
    // Running then stopping: the skirt and hair swing (differ from the same clip pose
    // without springs) and nothing becomes NaN.
    let mut with = Teacher::new(plain.clone(), description.clone()).unwrap();
    let mut without = Teacher::new(
        plain,
        Description {
            loose_parts: vec![],
            ..description
        },
    )
    .unwrap();
    for action in
        std::iter::repeat_n(Action::Forward, 30).chain(std::iter::repeat_n(Action::Idle, 4))
    {
        with.step(action);
        without.step(action);
    }
    let (m1, m2) = (with.mesh(), without.mesh());
    assert!(m1.positions.iter().all(|p| p.is_finite()));
    let swing = m1
        .positions
        .iter()
        .zip(&m2.positions)
        .map(|(p, q)| p.distance(*q))
        .fold(0.0f32, f32::max);
    assert!(
        (0.01..0.5).contains(&swing),
        "largest spring displacement {swing} m"
    );
}

/// The shipped KayKit Knight: its rig also holds IK and control helpers (some named after
/// the foot) that deform nothing, and its cape is a mesh parented to the chest, not skinned.
#[test]
fn the_knight_infers_feet_that_deform_and_a_cape_that_swings() {
    use unica::action::Action;
    use unica::avatar::description::{ChainLayout, Description};
    use unica::avatar::teacher::Teacher;
    let knight = load_character(Path::new("assets/knight/source/Knight.glb")).unwrap();
    let description = Description::infer(&knight).unwrap();
    assert_eq!(description.waist_bones, ["hips"]);
    assert_eq!(description.feet, ["foot.l", "foot.r"]);
    assert_eq!(
        [
            &description.clips.idle,
            &description.clips.walk,
            &description.clips.run
        ],
        ["Idle", "Walking_A", "Running_A"]
    );
    // The cape hangs; the helmet (parented to the head, above it) does not.
    assert_eq!(description.loose_parts.len(), 1);
    let cape = &description.loose_parts[0];
    assert_eq!(
        (cape.name.as_str(), cape.kind, cape.parent_bone.as_str()),
        ("Knight_Cape", ChainLayout::Sheet, "Knight_Cape")
    );
    assert_eq!(
        description.colliders.len(),
        1 + 2 * 2,
        "the waist, each thigh and shin"
    );

    let rigid = Description {
        loose_parts: vec![],
        ..description.clone()
    };
    let mut with = Teacher::new(knight.clone(), description).unwrap();
    let mut without = Teacher::new(knight.clone(), rigid).unwrap();
    let cape_vertices = knight.skinned.select(Some("Knight_Cape"), &[]);
    let displacement = |a: &Teacher, b: &Teacher| {
        let (m1, m2) = (a.mesh(), b.mesh());
        cape_vertices
            .iter()
            .map(|&v| m1.positions[v].distance(m2.positions[v]))
            .fold(0.0f32, f32::max)
    };
    assert!(displacement(&with, &without) < 1e-4, "the rest pose moved");
    let mut run = 0.0f32;
    for _ in 0..30 {
        with.step(Action::Forward);
        without.step(Action::Forward);
        run = run.max(displacement(&with, &without));
    }
    // After the stop: the last second of a 4-second idle.
    let mut last_second = Vec::new();
    for frame in 0..120 {
        with.step(Action::Idle);
        without.step(Action::Idle);
        if frame >= 90 {
            last_second.push(displacement(&with, &without));
        }
    }
    let low = last_second.iter().copied().fold(f32::MAX, f32::min);
    let high = last_second.iter().copied().fold(0.0f32, f32::max);
    eprintln!("cape swing: walking up to {run:.3} m; idle, last second {low:.3}-{high:.3} m");
    assert!(with.mesh().positions.iter().all(|p| p.is_finite()));
    // The cape (1.1 m long) swings back while walking, and comes to rest after the stop:
    // it then hangs straight down where the rigid cape follows the idle's leaning chest
    // (measured: 0.155-0.163 m apart; 0.32 m at most while walking).
    assert!(
        (0.1..0.8).contains(&run),
        "largest swing while walking {run} m"
    );
    assert!(
        high - low < 0.1 * run,
        "still swinging {low}-{high} m in the last second of idle"
    );
}
