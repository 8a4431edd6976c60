//! `unica render --teacher`: a scripted headless session writes every view of every frame
//! and a manifest whose root path follows the keys (W toward +Z, then D turns it to -X).

mod common;

use std::process::Command;

#[test]
fn the_teacher_session_follows_the_keys() {
    let witch = common::witch();
    let (dir, manifest) = render(&[
        "--teacher",
        witch.to_str().unwrap(),
        "--keys",
        "30W 30D",
        "--size",
        "64",
        "--views",
        "2",
    ]);
    let out = dir.path();
    let frames = manifest["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 60);
    for frame in frames {
        for file in frame["files"].as_array().unwrap() {
            let image = image::open(out.join(file.as_str().unwrap())).unwrap();
            assert_eq!((image.width(), image.height()), (64, 64));
        }
    }
    let root = |i: usize| {
        let r = frames[i]["root"].as_array().unwrap();
        glam::Vec3::new(
            r[0].as_f64().unwrap() as f32,
            r[1].as_f64().unwrap() as f32,
            r[2].as_f64().unwrap() as f32,
        )
    };
    let w_leg = root(29) - root(0);
    let d_leg = root(59) - root(40);
    assert!(w_leg.z > 1.0 && w_leg.x.abs() < 0.1, "W: {w_leg}");
    // After the turn D runs along -X: the heading changed by about 90 degrees.
    let turn = w_leg.x.atan2(w_leg.z) - d_leg.x.atan2(d_leg.z);
    assert!(
        (turn.to_degrees() - 90.0).abs() < 10.0,
        "turned {} degrees",
        turn.to_degrees()
    );
    assert_eq!(frames[45]["action"], "Right");
}

#[test]
fn render_needs_exactly_one_source() {
    let run = Command::new(env!("CARGO_BIN_EXE_unica"))
        .args([
            "render",
            "--keys",
            "5W",
            "--out",
            "/tmp/unused-unica-render",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("--teacher CHARACTER"),
        "{err}"
    );
}

/// Runs `unica render` with `args` into a new folder; returns the folder and its
/// manifest.
fn render(args: &[&str]) -> (tempfile::TempDir, serde_json::Value) {
    let dir = tempfile::tempdir().unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_unica"))
        .args(["render", "--out"])
        .arg(dir.path())
        .args(args)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let manifest =
        serde_json::from_slice(&std::fs::read(dir.path().join("manifest.json")).unwrap()).unwrap();
    (dir, manifest)
}

/// `render` of the shipped Witch bundle.
fn render_bundle(args: &[&str]) -> (tempfile::TempDir, serde_json::Value) {
    let bundle = common::shipped_bundle("witch");
    render(&[&["--bundle", bundle.to_str().unwrap()], args].concat())
}

#[test]
fn the_neural_avatar_session_follows_the_keys() {
    // The shipped Witch bundle with 4 DDIM steps (a fraction of the cost of the default
    // 10 on lavapipe): W runs toward +Z, then D turns the path toward -X. The teacher
    // turns 90° in 6 frames; the D leg is measured after that.
    let (dir, manifest) = render_bundle(&[
        "--keys", "12W 12D", "--steps", "4", "--size", "32", "--views", "1", "--points",
    ]);
    let frames = manifest["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 24);
    assert_eq!(manifest["source"]["ddim_steps"], 4);
    let root = |i: usize| {
        let r: Vec<f32> = frames[i]["root"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap() as f32)
            .collect();
        glam::Vec3::from_slice(&r)
    };
    for frame in frames {
        let files: Vec<&str> = frame["files"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f.as_str().unwrap())
            .collect();
        assert_eq!(files.len(), 2, "a view and the points");
        let image = image::open(dir.path().join(files[0])).unwrap();
        assert_eq!((image.width(), image.height()), (32, 32));
        let ply = std::fs::read(dir.path().join(files[1])).unwrap();
        let header = String::from_utf8_lossy(&ply[..200.min(ply.len())]).into_owned();
        assert!(header.contains("element vertex 4414"), "{header}");
        assert_eq!(
            ply.len(),
            header.find("end_header\n").unwrap() + 11 + 4414 * 12
        );
    }
    let w_leg = root(11) - root(0);
    let d_leg = root(23) - root(17);
    assert!(w_leg.z > 0.3 && w_leg.x.abs() < 0.1 * w_leg.z, "W: {w_leg}");
    assert!(d_leg.length() > 0.15, "D: {d_leg}");
    let turn = (w_leg.x.atan2(w_leg.z) - d_leg.x.atan2(d_leg.z)).to_degrees();
    assert!((turn - 90.0).abs() < 25.0, "turned {turn} degrees");
}

#[test]
fn the_same_seed_gives_the_same_frames() {
    let args = [
        "--keys", "3W", "--steps", "2", "--size", "32", "--views", "1", "--seed", "5",
    ];
    let (a, manifest_a) = render_bundle(&args);
    let (b, manifest_b) = render_bundle(&args);
    assert_eq!(manifest_a["frames"], manifest_b["frames"]);
    for frame in manifest_a["frames"].as_array().unwrap() {
        let file = frame["files"][0].as_str().unwrap();
        assert_eq!(
            std::fs::read(a.path().join(file)).unwrap(),
            std::fs::read(b.path().join(file)).unwrap(),
            "{file}"
        );
    }
    let (_, other) = render_bundle(&[
        "--keys", "3W", "--steps", "2", "--size", "32", "--views", "1", "--seed", "6",
    ]);
    assert_ne!(
        manifest_a["frames"], other["frames"],
        "another seed, another path"
    );
}
