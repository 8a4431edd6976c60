//! Real full disks (issue #51): `unica render`, `bake` and `export` write into a small
//! tmpfs that the test mounts (as root, as CI runs) until it is full. Each must stop with
//! one `unica: error:` line naming a path on that disk and a non-zero exit, and leave
//! nothing half-written: no `.tmp` file, every PNG decodes, every JSON file parses and
//! every safetensors file opens.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A tmpfs of `size` mounted on a fresh folder, unmounted when dropped.
struct SmallDisk {
    _parent: tempfile::TempDir,
    path: PathBuf,
}

impl SmallDisk {
    fn mount(size: &str) -> Self {
        let parent = tempfile::tempdir().unwrap();
        let path = parent.path().join("disk");
        std::fs::create_dir(&path).unwrap();
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(&path)
            .output()
            .expect("mount runs");
        assert!(
            out.status.success(),
            "these tests mount a small tmpfs and need root (CI runs as root): {}",
            String::from_utf8_lossy(&out.stderr)
        );
        Self {
            _parent: parent,
            path,
        }
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.path).status();
    }
}

fn unica(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_unica"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("the unica binary runs")
}

/// The run failed cleanly on the full disk: exit 1, one error line naming a path on it
/// and saying it is full.
fn assert_full_disk_error(out: &Output, disk: &Path) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "should fail cleanly: {err}");
    let line = common::error_line(out);
    assert!(
        line.contains(&disk.display().to_string()) && line.contains("No space left on device"),
        "the error should name a path on the full disk and say why: {line}"
    );
}

/// Every file under `dir` is whole: none is a temporary, and each PNG, JSON and
/// safetensors file reads. Returns how many files there are.
fn assert_all_whole(dir: &Path) -> usize {
    let mut count = 0;
    let mut folders = vec![dir.to_path_buf()];
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                folders.push(path);
                continue;
            }
            count += 1;
            let name = path.display().to_string();
            assert!(!name.ends_with(".tmp"), "a temporary was left: {name}");
            match path.extension().and_then(|e| e.to_str()) {
                Some("png") => {
                    image::open(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
                }
                Some("json") => {
                    let text = std::fs::read_to_string(&path).unwrap();
                    serde_json::from_str::<serde_json::Value>(&text)
                        .unwrap_or_else(|e| panic!("{name}: {e}"));
                }
                Some("safetensors") => {
                    unica::tensors::TensorFile::open(&path)
                        .unwrap_or_else(|e| panic!("{name}: {e}"));
                }
                Some("ply") => {
                    unica::splat::ply::read(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
                }
                _ => {}
            }
        }
    }
    count
}

#[test]
fn render_on_a_full_disk_stops_with_a_line_and_keeps_whole_frames() {
    // 2 views of 96² teacher frames, ~10 KB each: 48 frames fill 256 KB part-way.
    let disk = SmallDisk::mount("256k");
    let out_dir = disk.path.join("render");
    let out = unica(&[
        "render",
        "--teacher",
        "assets/witch/source/Witch.gltf",
        "--keys",
        "120W",
        "--size",
        "96",
        "--views",
        "2",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_full_disk_error(&out, &disk.path);
    let files = assert_all_whole(&out_dir);
    assert!(
        files > 2,
        "the disk should fill part-way through ({files} files)"
    );
}

#[test]
fn bake_on_a_full_disk_stops_with_a_line_and_keeps_whole_files() {
    // A quick bake writes about 4 MB (its reference alone 0.95 MB).
    let disk = SmallDisk::mount("2m");
    let out_dir = disk.path.join("data");
    let out = unica(&[
        "bake",
        "assets/witch/source/Witch.gltf",
        "--quick",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_full_disk_error(&out, &disk.path);
    let files = assert_all_whole(&out_dir);
    assert!(files > 0, "the disk should fill part-way through");
}

#[test]
fn export_on_a_full_disk_stops_with_a_line_and_leaves_no_file() {
    // A level-128 PLY of the Witch is several MB: it cannot fit 256 KB.
    let disk = SmallDisk::mount("256k");
    let file = disk.path.join("witch.ply");
    let out = unica(&[
        "export",
        "ply",
        "--bundle",
        "assets/witch/bundle",
        "--splat-level",
        "128",
        "--out",
        file.to_str().unwrap(),
    ]);
    assert_full_disk_error(&out, &disk.path);
    assert_eq!(assert_all_whole(&disk.path), 0, "nothing should be left");
}
