//! `unica render --teacher`: a scripted headless session writes every view of every frame
//! and a manifest whose root path follows the keys (W toward +Z, then D turns it to -X).

use std::path::Path;
use std::process::Command;

#[test]
fn the_teacher_session_follows_the_keys() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("session");
    let witch = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets/witch/Witch.gltf");
    let run = Command::new(env!("CARGO_BIN_EXE_unica"))
        .args([
            "render",
            "--teacher",
            witch.to_str().unwrap(),
            "--keys",
            "30W 30D",
            "--out",
            out.to_str().unwrap(),
            "--size",
            "64",
            "--views",
            "2",
        ])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json")).unwrap()).unwrap();
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
