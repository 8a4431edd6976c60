//! The auto-rigger's glTF writer against the crate's own loader: a bent, branching
//! cylinder rig with two clips is written as .glb and read back with `load_character`.

use glam::{Mat4, Quat, Vec3};
use unica::autorig::gltf_out::{ClipOut, GlbError, JointOut, RiggedMesh, write_glb};
use unica::avatar::load_character;
use unica::avatar::rig::Transform;
use unica::mesh::Mesh;

/// The inputs of one rigged mesh, owned.
struct Fixture {
    mesh: Mesh,
    joints: Vec<JointOut>,
    skin_joints: Vec<[u16; 4]>,
    skin_weights: Vec<[f32; 4]>,
    clips: Vec<ClipOut>,
}

impl Fixture {
    fn rigged(&self) -> RiggedMesh<'_> {
        RiggedMesh {
            name: "tube",
            mesh: &self.mesh,
            joints: &self.joints,
            skin_joints: &self.skin_joints,
            skin_weights: &self.skin_weights,
            clips: &self.clips,
            vrm: None,
        }
    }

    /// World matrices of the joints for local transforms `local`.
    fn world(&self, local: &[Transform]) -> Vec<Mat4> {
        let mut world: Vec<Mat4> = Vec::new();
        for (joint, transform) in self.joints.iter().zip(local) {
            let parent = joint.parent.map_or(Mat4::IDENTITY, |p| world[p]);
            world.push(parent * transform.matrix());
        }
        world
    }

    /// The mesh posed by clip `clip` at time `t`, sampled from the written keys directly:
    /// slerp between rotation keys, lerp between root translations, linear blend skinning.
    fn posed(&self, clip: &ClipOut, t: f32) -> Vec<Vec3> {
        let times = &clip.times;
        let k = times.partition_point(|&x| x <= t).clamp(1, times.len() - 1) - 1;
        let s = ((t - times[k]) / (times[k + 1] - times[k])).clamp(0.0, 1.0);
        let mut local: Vec<Transform> = self.joints.iter().map(|j| j.rest).collect();
        for (transform, keys) in local.iter_mut().zip(&clip.rotations) {
            transform.rotation = keys[k].slerp(keys[k + 1], s);
        }
        if !clip.root_translations.is_empty() {
            local[0].translation = clip.root_translations[k].lerp(clip.root_translations[k + 1], s);
        }
        let rest: Vec<Transform> = self.joints.iter().map(|j| j.rest).collect();
        let bind = self.world(&rest);
        let skin: Vec<Mat4> = self
            .world(&local)
            .iter()
            .zip(&bind)
            .map(|(w, b)| *w * b.inverse())
            .collect();
        self.mesh
            .positions
            .iter()
            .enumerate()
            .map(|(v, &p)| {
                (0..4)
                    .map(|i| {
                        let j = self.skin_joints[v][i] as usize;
                        skin[j].transform_point3(p) * self.skin_weights[v][i]
                    })
                    .sum()
            })
            .collect()
    }
}

fn joint(name: &str, parent: Option<usize>, translation: Vec3, rotation: Quat) -> JointOut {
    JointOut {
        name: name.into(),
        parent,
        rest: Transform {
            translation,
            rotation,
            scale: Vec3::ONE,
        },
    }
}

const RINGS: usize = 9;
const SIDES: usize = 8;

/// A cylinder along y from 0 to 2 skinned to hips → spine → neck, with a tail branching
/// from the hips, and two clips (one with root motion, one without).
fn tube() -> Fixture {
    let joints = vec![
        joint(
            "hips",
            None,
            Vec3::new(0.1, 0.0, -0.2),
            Quat::from_rotation_y(0.2),
        ),
        joint("spine", Some(0), Vec3::Y, Quat::from_rotation_z(0.3)),
        joint("neck", Some(1), Vec3::Y, Quat::from_rotation_x(-0.2)),
        joint(
            "tail",
            Some(0),
            Vec3::new(0.0, 0.2, -0.3),
            Quat::from_rotation_x(1.2),
        ),
    ];
    let mut mesh = Mesh::default();
    let mut skin_joints = Vec::new();
    let mut skin_weights = Vec::new();
    for ring in 0..RINGS {
        let h = 2.0 * ring as f32 / (RINGS - 1) as f32;
        for side in 0..SIDES {
            let angle = std::f32::consts::TAU * side as f32 / SIDES as f32;
            let radial = Vec3::new(angle.cos(), 0.0, angle.sin());
            mesh.positions.push(radial * 0.2 + Vec3::Y * h);
            mesh.normals.push(radial);
            mesh.colors.push(Vec3::new(
                side as f32 / SIDES as f32,
                ring as f32 / RINGS as f32,
                0.25,
            ));
            // The tail pulls a little on the back of the lowest rings.
            let tail = if h < 0.5 && angle.sin() < 0.0 {
                0.2
            } else {
                0.0
            };
            let (lower, upper, s) = if h < 1.0 { (0, 1, h) } else { (1, 2, h - 1.0) };
            skin_joints.push([lower, upper, 3, 0]);
            skin_weights.push([(1.0 - s) * (1.0 - tail), s * (1.0 - tail), tail, 0.0]);
        }
    }
    for ring in 0..RINGS - 1 {
        for side in 0..SIDES {
            let at = |r: usize, s: usize| (r * SIDES + s % SIDES) as u32;
            let (a, b) = (at(ring, side), at(ring, side + 1));
            let (c, d) = (at(ring + 1, side + 1), at(ring + 1, side));
            mesh.indices.extend([a, c, b, a, d, c]);
        }
    }
    let rest: Vec<Quat> = joints.iter().map(|j| j.rest.rotation).collect();
    let wave = ClipOut {
        name: "wave".into(),
        times: vec![0.0, 0.5, 1.25],
        rotations: rest
            .iter()
            .enumerate()
            .map(|(j, &r)| {
                let a = 0.4 + 0.1 * j as f32;
                vec![
                    r,
                    Quat::from_rotation_z(a) * r,
                    Quat::from_rotation_x(-a) * Quat::from_rotation_z(a) * r,
                ]
            })
            .collect(),
        root_translations: vec![
            Vec3::new(0.1, 0.0, -0.2),
            Vec3::new(0.3, 0.1, -0.2),
            Vec3::new(0.6, 0.0, 0.1),
        ],
    };
    let turn = ClipOut {
        name: "turn".into(),
        times: vec![0.25, 2.0],
        rotations: rest
            .iter()
            .map(|&r| vec![r, Quat::from_rotation_y(1.5) * r])
            .collect(),
        root_translations: Vec::new(),
    };
    Fixture {
        mesh,
        joints,
        skin_joints,
        skin_weights,
        clips: vec![wave, turn],
    }
}

fn assert_close(got: &[Vec3], want: &[Vec3], tolerance: f32, what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(g.abs_diff_eq(*w, tolerance), "{what} {i}: {g} vs {w}");
    }
}

#[test]
fn a_written_rig_loads_back_as_written() {
    let fixture = tube();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tube.glb");
    write_glb(&path, &fixture.rigged()).unwrap();
    let character = load_character(&path).unwrap();

    // The bind mesh, vertex for vertex.
    let bind = &character.skinned.bind;
    assert_close(&bind.positions, &fixture.mesh.positions, 1e-6, "position");
    assert_close(&bind.normals, &fixture.mesh.normals, 1e-6, "normal");
    assert_close(&bind.colors, &fixture.mesh.colors, 1e-6, "colour");
    assert_eq!(bind.indices, fixture.mesh.indices);

    // Every joint by name, with its parent and rest transform; the mesh node is a root.
    let rig = &character.rig;
    assert_eq!(rig.nodes.len(), fixture.joints.len() + 1);
    for joint in &fixture.joints {
        let node = &rig.nodes[rig.find(&joint.name).expect("joint is loaded")];
        let parent = node.parent.map(|p| rig.nodes[p].name.as_str());
        let want = joint.parent.map(|p| fixture.joints[p].name.as_str());
        assert_eq!(parent, want, "parent of {}", joint.name);
        assert!(
            node.rest
                .translation
                .abs_diff_eq(joint.rest.translation, 1e-6)
        );
        assert!(node.rest.rotation.abs_diff_eq(joint.rest.rotation, 1e-6));
        assert!(node.rest.scale.abs_diff_eq(joint.rest.scale, 1e-6));
    }
    assert_eq!(rig.nodes[rig.find("tube").unwrap()].parent, None);

    // Skin weights per vertex as sets of (joint name, weight).
    let influences = |joints: [u16; 4], weights: [f32; 4], name: &dyn Fn(u16) -> String| {
        let mut set: Vec<(String, f32)> = joints
            .iter()
            .zip(weights)
            .filter(|&(_, w)| w > 0.0)
            .map(|(&j, w)| (name(j), w))
            .collect();
        set.sort_by(|a, b| a.0.cmp(&b.0));
        set
    };
    let loaded_name = |bone: u16| rig.nodes[rig.bones[bone as usize].node].name.clone();
    let written_name = |joint: u16| fixture.joints[joint as usize].name.clone();
    for v in 0..fixture.mesh.positions.len() {
        let got = influences(
            character.skinned.joints[v],
            character.skinned.weights[v],
            &loaded_name,
        );
        let want = influences(
            fixture.skin_joints[v],
            fixture.skin_weights[v],
            &written_name,
        );
        assert_eq!(got.len(), want.len(), "vertex {v}: {got:?} vs {want:?}");
        for ((gn, gw), (wn, ww)) in got.iter().zip(&want) {
            assert_eq!(gn, wn, "vertex {v}");
            assert!((gw - ww).abs() < 1e-6, "vertex {v}: {got:?} vs {want:?}");
        }
    }

    // The rest pose reproduces the bind mesh.
    let rest = character.rest_mesh();
    assert_close(
        &rest.positions,
        &fixture.mesh.positions,
        1e-5,
        "rest position",
    );
    assert_close(&rest.normals, &fixture.mesh.normals, 1e-5, "rest normal");
    assert_close(&rest.colors, &fixture.mesh.colors, 1e-6, "rest colour");

    // Each clip, sampled between and on keys, poses the mesh as its keys say.
    let names: Vec<&str> = character.clips.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["wave", "turn"]);
    for written in &fixture.clips {
        let clip = character.clip(&written.name).unwrap();
        assert_eq!(clip.duration, *written.times.last().unwrap());
        for t in [0.0, 0.3, 0.5, 0.9, 1.25, 1.7, 2.0] {
            let mut pose = rig.rest_pose();
            clip.sample(t, &mut pose);
            let got = character.pose_mesh(&pose, Mat4::IDENTITY);
            let what = format!("{} at {t}", written.name);
            assert_close(&got.positions, &fixture.posed(written, t), 1e-5, &what);
        }
    }
    // The clips really move the mesh.
    let moved = fixture.posed(&fixture.clips[0], 0.9);
    assert!(moved[RINGS * SIDES - 1].distance(fixture.mesh.positions[RINGS * SIDES - 1]) > 0.3);
}

#[test]
fn the_file_is_a_well_formed_glb() {
    let fixture = tube();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tube.glb");
    write_glb(&path, &fixture.rigged()).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    assert_eq!(&bytes[0..4], b"glTF");
    assert_eq!(word(4), 2);
    assert_eq!(word(8), bytes.len());
    let json_len = word(12);
    assert_eq!(&bytes[16..20], b"JSON");
    assert_eq!(json_len % 4, 0);
    assert_eq!(&bytes[20 + json_len + 4..20 + json_len + 8], b"BIN\0");
    assert_eq!(word(20 + json_len) % 4, 0);

    // POSITION carries the bounds the spec requires.
    let gltf = gltf::Gltf::from_slice(&bytes).unwrap();
    let primitive = gltf.meshes().next().unwrap().primitives().next().unwrap();
    let positions = primitive.get(&gltf::Semantic::Positions).unwrap();
    let (lo, hi) = fixture.mesh.bounds().unwrap();
    let bound = |v: Option<gltf::json::Value>| -> Vec<f32> {
        serde_json::from_value(v.expect("bound present")).unwrap()
    };
    assert_eq!(bound(positions.min()), lo.to_array());
    assert_eq!(bound(positions.max()), hi.to_array());
    let material = primitive.material().pbr_metallic_roughness();
    assert_eq!(material.base_color_factor(), [1.0; 4]);
}

#[test]
fn inconsistent_input_is_an_error_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.glb");
    let problem = |fixture: &Fixture| match write_glb(&path, &fixture.rigged()) {
        Err(GlbError::Invalid(problem)) => problem,
        other => panic!("expected an invalid-input error, got {other:?}"),
    };
    let expect = |edit: &dyn Fn(&mut Fixture), words: &str| {
        let mut fixture = tube();
        edit(&mut fixture);
        let problem = problem(&fixture);
        assert!(
            problem.contains(words),
            "'{problem}' should mention '{words}'"
        );
    };
    expect(
        &|f| {
            f.skin_weights.pop();
        },
        "72 positions but 71 skin weight sets",
    );
    expect(&|f| f.mesh.colors.truncate(3), "72 positions but 3 colours");
    expect(
        &|f| f.skin_joints[5][2] = 9,
        "vertex 5: joint index 9 is past the 4 joints",
    );
    expect(&|f| f.skin_weights[7][0] = f32::NAN, "vertex 7: weights");
    expect(&|f| f.skin_weights[7][0] += 0.5, "summing to 1");
    expect(&|f| f.joints[1].parent = Some(2), "does not come before it");
    expect(
        &|f| f.joints[3].name = "hips".into(),
        "two joints are named 'hips'",
    );
    expect(
        &|f| f.mesh.indices.push(1000),
        "whole, non-zero number of triangles",
    );
    expect(
        &|f| f.mesh.indices[4] = 1000,
        "triangle index 1000 is past the 72 vertices",
    );
    expect(&|f| f.joints[2].rest.scale = Vec3::ZERO, "joint 'neck'");
    expect(
        &|f| {
            f.clips[0].rotations.pop();
        },
        "rotations for 3 joints",
    );
    expect(
        &|f| f.clips[1].rotations[2].push(Quat::IDENTITY),
        "joint 'neck' has 3 rotations for 2 key times",
    );
    expect(&|f| f.clips[0].times[1] = 2.0, "strictly increasing");
    expect(
        &|f| {
            f.clips[0].root_translations.pop();
        },
        "2 root translations",
    );
    expect(
        &|f| f.clips[1].name = "wave".into(),
        "two clips are named 'wave'",
    );
    assert!(!path.exists(), "nothing is written for invalid input");
}
