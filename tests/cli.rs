//! The binary's contract: help and version, one-line errors with non-zero exit for bad
//! input and for a machine without any GPU adapter.

mod common;

use std::path::Path;
use std::process::Output;

fn unica(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = common::unica_command(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().expect("the unica binary runs")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A failure: exit status non-zero, no panic, and a single `unica: error:` line.
fn assert_one_line_error(out: &Output, needle: &str) {
    let err = stderr(out);
    assert!(!out.status.success(), "should fail: {err}");
    let line = common::error_line(out);
    assert!(line.contains(needle), "expected '{needle}' in: {line}");
}

#[test]
fn help_explains_the_commands_and_the_gpu_choice() {
    let out = unica(&["--help"], &[]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in [
        "bake",
        "render",
        "eval",
        "export",
        "view",
        "bench",
        "adapters",
        "--keys",
        "--screenshot",
        "--exit-after",
        "WGPU_BACKEND",
        "mesa-vulkan-drivers",
    ] {
        assert!(text.contains(needle), "--help lacks {needle}:\n{text}");
    }
    let out = unica(&["--version"], &[]);
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        format!("unica {}", env!("CARGO_PKG_VERSION"))
    );
}

#[test]
fn view_and_export_help_explain_the_formats_and_the_up_axis() {
    let out = unica(&["view", "--help"], &[]);
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in ["--up", "compressed", ".splat", "+Z becomes +Y"] {
        assert!(text.contains(needle), "view --help lacks {needle}:\n{text}");
    }
    let out = unica(&["export", "--help"], &[]);
    let text = String::from_utf8_lossy(&out.stdout);
    for needle in ["--up", "splat", "antimatter15", "32 bytes"] {
        assert!(
            text.contains(needle),
            "export --help lacks {needle}:\n{text}"
        );
    }
}

#[test]
fn eval_names_a_missing_dataset_or_character() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("report");
    let out = out.to_str().unwrap();
    let bundle = "assets/witch/bundle";
    let eval = |data: &str| {
        unica(
            &["eval", "--bundle", bundle, "--data", data, "--out", out],
            &[],
        )
    };
    let missing = dir.path().join("nothing");
    let missing = missing.to_str().unwrap();
    assert_one_line_error(&eval(missing), &format!("{missing}/manifest.json"));
    // A dataset whose character file has gone: named, with the way out.
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    let manifest = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/dataset_quick/manifest.json"),
    )
    .unwrap();
    let mut value: serde_json::Value = serde_json::from_str(&manifest).unwrap();
    value["character"] = "/no/such/Witch.gltf".into();
    std::fs::write(data.join("manifest.json"), value.to_string()).unwrap();
    assert_one_line_error(
        &eval(data.to_str().unwrap()),
        "/no/such/Witch.gltf: the dataset's character file is not there; give it with --character",
    );
}

#[test]
fn no_adapter_means_one_line_on_how_to_get_one() {
    // A Vulkan loader with no driver: the machine has no adapter at all.
    let no_driver = [
        ("WGPU_BACKEND", "vulkan"),
        ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
        ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
    ];
    assert_one_line_error(&unica(&["adapters"], &no_driver), "mesa-vulkan-drivers");
    assert_one_line_error(&unica(&["bench"], &no_driver), "mesa-vulkan-drivers");
}

#[test]
fn an_unknown_adapter_name_lists_the_available_ones() {
    assert_one_line_error(
        &unica(&["adapters"], &[("WGPU_ADAPTER_NAME", "no-such-gpu-9000")]),
        "no-such-gpu-9000",
    );
}

#[test]
fn bad_arguments_fail_before_any_window_opens() {
    assert_one_line_error(&unica(&["--keys", "30W 5Q"], &[]), "'5Q'");
    assert_one_line_error(&unica(&["--exit-after", "0"], &[]), "at least 1");
    for bad in ["0", "NaN", "inf"] {
        assert_one_line_error(
            &unica(&["--exit-after-seconds", bad], &[]),
            "positive number of seconds",
        );
    }
    assert_one_line_error(
        &unica(&["--bundle", "nowhere.bundle"], &[]),
        "nowhere.bundle",
    );
    let out = unica(&["--record-fps", "0"], &[]);
    assert!(
        !out.status.success() && stderr(&out).contains("between 1 and 120"),
        "{}",
        stderr(&out)
    );
    let out = unica(&["--screenshot", "x.png"], &[]);
    assert!(
        !out.status.success() && stderr(&out).contains("--exit-after"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn adapters_lists_the_one_in_use() {
    let out = unica(&["adapters"], &[]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        text.lines().filter(|l| l.starts_with('*')).count(),
        2,
        "{text}"
    ); // the adapter + legend
}

#[test]
fn bench_live_counts_the_unet_passes_of_a_frame() {
    // The shipped bundle runs its distilled student by default: one pass a frame; its
    // teacher at 2 DDIM steps with guidance: two passes a step.
    let bundle = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/witch/bundle");
    for (extra, passes, sampler) in [
        (
            &[][..],
            "unet_passes=1 ",
            "one UNet pass (distilled student)",
        ),
        (
            &["--steps", "2"][..],
            "unet_passes=4 ",
            "2 DDIM steps, CFG 2",
        ),
    ] {
        let mut args = vec![
            "bench",
            "--bundle",
            bundle,
            "--live",
            "1",
            "--splat-level",
            "128",
        ];
        args.extend_from_slice(extra);
        let out = unica(&args, &[]);
        assert!(out.status.success(), "{}", stderr(&out));
        let text = String::from_utf8_lossy(&out.stdout);
        let line = text
            .lines()
            .find(|l| l.starts_with("per generated frame:"))
            .unwrap_or_else(|| panic!("no per-frame line: {text}"));
        assert!(line.contains(passes), "{line}");
        assert!(text.contains(&format!("live: {sampler},")), "{text}");
        // Each stage's wall time and, lavapipe having timestamp queries, its GPU time:
        // a number no larger than the wall clock around the same submission.
        let stage = text
            .lines()
            .find(|l| l.starts_with("stage unet-target: dispatches="))
            .unwrap_or_else(|| panic!("no unet-target stage line: {text}"));
        let field = |name: &str| -> f64 {
            let value = stage
                .split(&format!(" {name}="))
                .nth(1)
                .unwrap_or_else(|| panic!("{stage}"));
            value
                .split(' ')
                .next()
                .unwrap()
                .parse()
                .unwrap_or_else(|_| panic!("{stage}"))
        };
        let (wall, gpu) = (field("ms"), field("gpu_ms"));
        assert!(gpu > 0.0 && gpu <= wall + 0.05, "{stage}");
        // The profile ends with the slowest single steps, each with its place in the
        // frame and its workgroup grid.
        let slowest = text
            .lines()
            .skip_while(|l| !l.starts_with("the 24 slowest steps of that frame"))
            .skip(1)
            .take_while(|l| l.starts_with("  #"))
            .collect::<Vec<_>>();
        assert_eq!(slowest.len(), 24, "{text}");
        assert!(
            slowest
                .iter()
                .any(|l| l.contains(".wgsl") && l.contains('x')),
            "{text}"
        );
    }
}

#[test]
fn bench_prints_its_table() {
    let args = [
        "bench", "--models", "tiny", "--repeat", "1", "--steps", "2", "--splats", "2000",
    ];
    let out = unica(&args, &[("UNICA_FORCE_FALLBACK", "1")]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("adapter:") && text.contains("scale_add F32"),
        "{text}"
    );
    // The model rows: the FLOPs the engine runs (tiny UNet, batch 2 for CFG): the
    // trainer's count less the cross-attention, tabled at load, and the timestep
    // embedding's projections, made once per recording (see tests/nn/):
    // 2 × (121,053,184 − 3,293,184 − 57,344).
    let group = text
        .lines()
        .find(|l| l.starts_with("tiny") && l.contains("4-frame group x2"))
        .unwrap_or_else(|| panic!("no UNet row: {text}"));
    let gflop: f64 = group
        .split_whitespace()
        .rev()
        .nth(2)
        .unwrap()
        .parse()
        .unwrap();
    assert!((gflop - 0.2354).abs() < 1e-3, "{group}");
    assert!(text.contains("generated frame: 2 steps + decode"), "{text}");
    assert!(
        text.contains("splat rasterizer: 2000 splats") && text.contains("1920x1080"),
        "{text}"
    );
    assert!(
        text.contains("f16 false"),
        "forced fallback shows no f16: {text}"
    );
}

#[test]
fn export_writes_the_neural_avatars_splats_and_view_refuses_bad_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("witch.ply");
    let bundle = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/witch/bundle");
    // One frame of the shipped bundle, exported as `format` to `to` with `extra`.
    let export = |format: &str, to: &Path, extra: &[&str]| {
        let head = [
            "export", format, "--bundle", bundle, "--keys", "1W", "--steps", "1",
        ];
        let tail = ["--splat-level", "128", "--out", to.to_str().unwrap()];
        let run = unica(&[&head[..], &tail, extra].concat(), &[]);
        assert!(run.status.success(), "{}", stderr(&run));
    };
    export("ply", &out, &[]);
    let splats = unica::splat::ply::read(&out).unwrap();
    assert_eq!(splats.len(), 4414, "one splat per pixel of the 128² map");
    let (lo, hi) = splats.iter().fold(
        (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
        |(lo, hi), s| (lo.min(s.position), hi.max(s.position)),
    );
    let height = hi.y - lo.y;
    assert!(
        (1.5..2.5).contains(&height),
        "a person-sized avatar: {height} m"
    );
    // The same frame as an antimatter15 .splat, Z-up: read back Z-up it is the PLY's
    // splats (largest size × opacity first). Positions and scales are f32 (turned twice:
    // 1e-5); colour (clamped to 0..1) and opacity 8-bit truncated (within 1/255);
    // rotations 8-bit per component (|q·q'| > 1 − 2e-4).
    let splat_out = dir.path().join("witch.splat");
    export("splat", &splat_out, &["--up", "z"]);
    use unica::splat::files::{Up, read};
    let z_up = read(&splat_out, Up::Y).unwrap().splats;
    let (lo_z, hi_z) = z_up.iter().fold(
        (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
        |(lo, hi), s| (lo.min(s.position), hi.max(s.position)),
    );
    assert!(
        ((hi_z.z - lo_z.z) - height).abs() < 1e-3,
        "the file stands along Z: {lo_z} {hi_z}"
    );
    let back = read(&splat_out, Up::Z).unwrap().splats;
    assert_eq!(back.len(), splats.len());
    let weight = |s: &unica::splat::ply::Splat| s.scale.x * s.scale.y * s.scale.z * s.opacity;
    let mut unmatched = 0;
    let mut previous = f32::INFINITY;
    for b in &back {
        let close = |a: &&unica::splat::ply::Splat| {
            a.position.distance(b.position) < 1e-5
                && (a.scale - b.scale).abs().max_element() < 1e-5
                && (a.color().clamp(glam::Vec3::ZERO, glam::Vec3::ONE) - b.color())
                    .abs()
                    .max_element()
                    < 1.0 / 255.0 + 1e-6
                && (a.opacity - b.opacity).abs() < 1.0 / 255.0 + 1e-6
                && a.rotation.dot(b.rotation).abs() > 1.0 - 2e-4
        };
        match splats.iter().find(close) {
            Some(a) => {
                // Largest first (1 %: a near-twin at the same point may be matched).
                assert!(weight(a) <= previous * 1.01, "sorted largest first");
                previous = weight(a);
            }
            None => unmatched += 1,
        }
    }
    assert_eq!(unmatched, 0, "every .splat splat is one of the PLY's");
    // A malformed file is refused before any window opens, naming the file.
    let bad = dir.path().join("bad.ply");
    std::fs::write(
        &bad,
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n",
    )
    .unwrap();
    assert_one_line_error(&unica(&["view", bad.to_str().unwrap()], &[]), "bad.ply");
}

#[test]
fn rig_errors_name_the_file_and_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let glb = dir.path().join("out.glb");
    let glb = glb.to_str().unwrap();
    let missing = dir.path().join("missing.obj");
    assert_one_line_error(
        &unica(&["rig", missing.to_str().unwrap(), "--out", glb], &[]),
        "missing.obj",
    );
    assert_one_line_error(
        &unica(&["rig", "any.obj", "--out", "rigged.gltf"], &[]),
        "rigged.gltf: the rigged output must be a .glb file",
    );
    let broken = dir.path().join("broken.obj");
    std::fs::write(&broken, "v 0 0 0\nf 1 2 3\n").unwrap();
    assert_one_line_error(
        &unica(
            &["rig", broken.to_str().unwrap(), "--out", glb, "--baseline"],
            &[],
        ),
        "broken.obj",
    );
    assert!(
        !dir.path().join("out.glb").exists(),
        "nothing is written on failure"
    );
    let here = dir.path().to_str().unwrap();
    assert_one_line_error(
        &unica(&["rig-eval", "--data", here, "--out", here], &[]),
        "manifest.json",
    );
}

/// The command that rewrites docs/cli.md from the binary's help texts.
const CLI_REFERENCE_BLESS: &str =
    "UNICA_BLESS=1 cargo test --release --test cli the_cli_reference_matches_the_help";

/// docs/cli.md is `unica --help` and every subcommand's `--help`, as this test builds it:
/// it fails when the two differ, and with UNICA_BLESS=1 it writes the file instead.
#[test]
fn the_cli_reference_matches_the_help() {
    let help = |args: &[&str]| {
        let out = unica(args, &[]);
        assert!(
            out.status.success(),
            "unica {} failed: {}",
            args.join(" "),
            stderr(&out)
        );
        String::from_utf8(out.stdout).expect("the help text is UTF-8")
    };
    let root = help(&["--help"]);
    // The subcommands in the order `unica --help` lists them: the lines under "Commands:"
    // indented by two spaces (clap does not wrap in this build, one line a command).
    let subcommands: Vec<String> = root
        .lines()
        .skip_while(|line| line.trim_end() != "Commands:")
        .skip(1)
        .take_while(|line| !line.trim().is_empty())
        .filter(|line| line.starts_with("  ") && !line.starts_with("   "))
        .filter_map(|line| line.split_whitespace().next().map(str::to_owned))
        .filter(|name| name != "help")
        .collect();
    assert!(
        subcommands.len() >= 10,
        "expected the subcommands under \"Commands:\" in:\n{root}"
    );

    let section = |title: &str, text: &str| {
        let body: Vec<&str> = text.trim_end().lines().map(str::trim_end).collect();
        format!("## {title}\n\n```text\n{}\n```\n", body.join("\n"))
    };
    let mut doc = format!(
        "# unica command line\n\n\
         This file is generated from the binary's `--help` texts by the test \
         `the_cli_reference_matches_the_help` in tests/cli.rs, which fails when the two \
         differ; do not edit it by hand. After changing the command line, refresh it with \
         `{CLI_REFERENCE_BLESS}`.\n\n{}",
        section("unica", &root)
    );
    for sub in &subcommands {
        doc.push('\n');
        doc.push_str(&section(&format!("unica {sub}"), &help(&[sub, "--help"])));
    }

    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/cli.md");
    if std::env::var("UNICA_BLESS").as_deref() == Ok("1") {
        std::fs::write(&path, &doc).expect("writing docs/cli.md");
        return;
    }
    let current = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        current == doc,
        "docs/cli.md is out of date: refresh it with `{CLI_REFERENCE_BLESS}`"
    );
}
