//! `unica bake` on the Witch: the full transition table bakes, validates and is
//! byte-for-byte reproducible; broken inputs and datasets fail with named errors.

mod common;

use common::{files, witch};

use std::path::PathBuf;
use std::process::Command;

fn unica(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_unica"))
        .args(args)
        .output()
        .unwrap()
}

/// Bakes the Witch twice with `options` into folders `a` and `b` of a temporary folder
/// (kept alive by the first value); returns each run's standard output too.
fn bake_twice(options: &[&str]) -> (tempfile::TempDir, PathBuf, PathBuf, Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let witch = witch();
    let mut outputs = Vec::new();
    for out in [&a, &b] {
        let mut args = vec![
            "bake",
            witch.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(options);
        let run = unica(&args);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        outputs.push(String::from_utf8_lossy(&run.stdout).into_owned());
    }
    (dir, a, b, outputs)
}

#[test]
fn the_witch_bakes_validates_and_rebakes_identically() {
    let (_dir, a, b, outputs) = bake_twice(&[]);
    for stdout in outputs {
        assert!(stdout.contains("baked 21 clips, 5520 frames of Witch"));
    }
    assert_eq!(files(&a), files(&b), "the same inputs give the same bytes");
    let report = unica::dataset::validate(&a).unwrap();
    assert_eq!(
        (report.clips, report.frames, report.switches),
        (21, 5520, 20)
    );
    assert!(report.min > 0.0 && report.max < 1.0, "{report:?}");
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(a.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["clips"][1]["switch_frame"], 120);
    assert_eq!(manifest["bones"], 107);
}

#[test]
fn ground_truth_renders_are_written_listed_and_reproducible() {
    let (_dir, a, b, _) = bake_twice(&["--quick", "--preview"]);
    assert_eq!(
        files(&a),
        files(&b),
        "renders and preview are deterministic too"
    );
    let report = unica::dataset::validate(&a).unwrap();
    // 50 rest cameras + 4 views of every 5th frame of the quick clips (8, 18, 24, 26 frames).
    assert_eq!(report.renders, 50 + 4 * (2 + 4 + 5 + 6));
    let front = image::open(a.join("renders/clip_002/f0010_front.png"))
        .unwrap()
        .to_rgba8();
    let covered = front.pixels().filter(|p| p.0[3] == 255).count() as f64 / (512.0 * 512.0);
    assert!(
        (0.02..0.5).contains(&covered),
        "the character covers {covered} of a render"
    );
    assert_eq!(
        front.get_pixel(0, 0).0[3],
        0,
        "the background is transparent"
    );
    assert!(a.join("preview.png").is_file());
}

#[test]
fn every_frame_is_rendered_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("all");
    let witch = witch();
    let args = [
        "bake",
        witch.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quick",
    ];
    let run = unica(&[&args[..], &["--render-every", "1"]].concat());
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report = unica::dataset::validate(&out).unwrap();
    // 50 rest cameras + 4 views of every frame of the quick clips (8, 18, 24, 26 frames).
    assert_eq!(report.renders, 50 + 4 * (8 + 18 + 24 + 26));
    assert!(out.join("renders/clip_002/f0013_left.png").is_file());
    let listing: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("renders/cameras.json")).unwrap()).unwrap();
    assert_eq!(listing["every"], 1);
    let zero = unica(&[&args[..], &["--render-every", "0"]].concat());
    let err = String::from_utf8_lossy(&zero.stderr);
    assert!(
        !zero.status.success() && err.contains("--render-every"),
        "{err}"
    );
}

#[test]
fn bad_inputs_and_broken_datasets_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let run = unica(&[
        "bake",
        "/nonexistent/hero.glb",
        "--out",
        dir.path().join("x").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("hero.glb") && err.contains("no such file"),
        "{err}"
    );

    let out = dir.path().join("quick");
    let witch = witch();
    assert!(
        unica(&[
            "bake",
            witch.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quick"
        ])
        .status
        .success()
    );
    assert!(unica(&["validate", out.to_str().unwrap()]).status.success());
    // A clip file that lost its bytes: validation names it.
    std::fs::write(out.join("clips/clip_002.safetensors"), b"truncated").unwrap();
    let run = unica(&["validate", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("clip_002.safetensors"),
        "{err}"
    );
    // A manifest that disagrees with the clip's actions.
    let manifest_path = out.join("manifest.json");
    let text = std::fs::read_to_string(&manifest_path)
        .unwrap()
        .replace("\"switch_frame\": 6", "\"switch_frame\": 5");
    std::fs::write(&manifest_path, text).unwrap();
    std::fs::remove_file(out.join("clips/clip_002.safetensors")).unwrap();
    let run = unica(&["validate", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && err.contains("clip_001.safetensors") && err.contains("frame 5"),
        "{err}"
    );
}
