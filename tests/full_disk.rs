//! Real full disks (issue #51): `unica render`, `bake` and `export` write into a small
//! tmpfs that the test mounts (as root, as CI runs) until it is full. Each must stop with
//! one `unica: error:` line naming a path on that disk and a non-zero exit, and leave
//! nothing half-written: no `.tmp` file, every PNG decodes, every JSON file parses and
//! every safetensors file opens.

mod common;

use std::process::Output;

use common::{SmallDisk, assert_all_whole};

fn unica(args: &[&str]) -> Output {
    common::unica_command(args)
        .output()
        .expect("the unica binary runs")
}

/// Runs unica with `args` and `--out DISK/out` on a fresh tmpfs of `size`, which fills
/// part-way: asserts that it failed cleanly (exit 1, one error line naming a path on the
/// disk and saying it is full) and that every file left reads whole; returns how many.
fn run_until_full(size: &str, args: &[&str]) -> usize {
    let disk = SmallDisk::mount(size);
    let out_path = disk.path.join("out");
    let out = unica(&[args, &["--out", out_path.to_str().unwrap()]].concat());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "should fail cleanly: {err}");
    let line = common::error_line(&out);
    assert!(
        line.contains(&disk.path.display().to_string()) && line.contains("No space left on device"),
        "the error should name a path on the full disk and say why: {line}"
    );
    assert_all_whole(&disk.path)
}

#[test]
fn render_on_a_full_disk_stops_with_a_line_and_keeps_whole_frames() {
    // 2 views of 96² teacher frames, ~10 KB each: 48 frames fill 256 KB part-way.
    let files = run_until_full(
        "256k",
        &[
            "render",
            "--teacher",
            "assets/witch/source/Witch.gltf",
            "--keys",
            "120W",
            "--size",
            "96",
            "--views",
            "2",
        ],
    );
    assert!(
        files > 2,
        "the disk should fill part-way through ({files} files)"
    );
}

#[test]
fn bake_on_a_full_disk_stops_with_a_line_and_keeps_whole_files() {
    // A quick bake writes about 4 MB (its reference alone 0.95 MB).
    let files = run_until_full("2m", &["bake", "assets/witch/source/Witch.gltf", "--quick"]);
    assert!(files > 0, "the disk should fill part-way through");
}

#[test]
fn export_on_a_full_disk_stops_with_a_line_and_leaves_no_file() {
    // A level-128 PLY of the Witch is several MB: it cannot fit 256 KB.
    let files = run_until_full(
        "256k",
        &[
            "export",
            "ply",
            "--bundle",
            "assets/witch/bundle",
            "--splat-level",
            "128",
        ],
    );
    assert_eq!(files, 0, "nothing should be left");
}
