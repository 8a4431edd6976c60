//! Helpers shared by the integration tests: the shared Witch, whole-folder snapshots and
//! the one-line error of a failed run.

#![allow(dead_code)] // each test binary uses its own subset

use std::path::{Path, PathBuf};

/// The default avatar's source, shipped in assets/witch/source (CC0).
pub fn witch() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/witch/source/Witch.gltf")
}

/// The unica binary with `args`, run from the repository without a display (so a
/// command that would open a window fails instead).
pub fn unica_command(args: &[&str]) -> std::process::Command {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_unica"));
    cmd.args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY");
    cmd
}

/// A neural avatar's bundle shipped in assets/ (`witch`, `knight`).
pub fn shipped_bundle(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("assets/{name}/bundle"))
}

/// Every file under `dir` (in its subfolders too), sorted.
pub fn paths(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut folders = vec![dir.to_path_buf()];
    while let Some(folder) = folders.pop() {
        for entry in std::fs::read_dir(&folder).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                folders.push(path);
            } else {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// Every file under `dir` with its path relative to `dir`, sorted.
pub fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    paths(dir)
        .into_iter()
        .map(|path| {
            let bytes = std::fs::read(&path).unwrap();
            (path.strip_prefix(dir).unwrap().to_path_buf(), bytes)
        })
        .collect()
}

/// The single `unica: error:` line of a failed run's stderr, asserting that nothing
/// panicked and that there is exactly one such line.
pub fn error_line(out: &std::process::Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    let ours: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("unica: error:"))
        .collect();
    assert_eq!(ours.len(), 1, "{err}");
    ours[0].to_string()
}

/// A tmpfs of `size` mounted on a fresh folder, unmounted when dropped.
pub struct SmallDisk {
    _parent: tempfile::TempDir,
    pub path: PathBuf,
}

impl SmallDisk {
    pub fn mount(size: &str) -> Self {
        let parent = tempfile::tempdir().unwrap();
        let path = parent.path().join("disk");
        std::fs::create_dir(&path).unwrap();
        let out = std::process::Command::new("mount")
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
        let _ = std::process::Command::new("umount")
            .arg(&self.path)
            .status();
    }
}

/// Every file under `dir` is whole: none is a temporary, and each PNG, JSON and
/// safetensors file reads. Returns how many files there are.
pub fn assert_all_whole(dir: &Path) -> usize {
    let paths = paths(dir);
    for path in &paths {
        let name = path.display().to_string();
        assert!(!name.ends_with(".tmp"), "a temporary was left: {name}");
        match path.extension().and_then(|e| e.to_str()) {
            Some("png") => {
                image::open(path).unwrap_or_else(|e| panic!("{name}: {e}"));
            }
            Some("json") => {
                let text = std::fs::read_to_string(path).unwrap();
                serde_json::from_str::<serde_json::Value>(&text)
                    .unwrap_or_else(|e| panic!("{name}: {e}"));
            }
            Some("safetensors") => {
                unica::tensors::TensorFile::open(path).unwrap_or_else(|e| panic!("{name}: {e}"));
            }
            Some("ply") => {
                unica::splat::ply::read(path).unwrap_or_else(|e| panic!("{name}: {e}"));
            }
            _ => {}
        }
    }
    paths.len()
}

/// A compressed PLY (SuperSplat's layout) header with `chunks` chunks of the 12 bound
/// floats and `vertices` packed vertices, with a zero body of the size it declares.
pub fn compressed_ply(chunks: usize, vertices: usize) -> Vec<u8> {
    let mut header = "ply\nformat binary_little_endian 1.0\n".to_string();
    if chunks > 0 {
        header += &format!("element chunk {chunks}\n");
        for axis in ["x", "y", "z", "scale_x", "scale_y", "scale_z"] {
            header += &format!("property float min_{axis}\n");
        }
        for axis in ["x", "y", "z", "scale_x", "scale_y", "scale_z"] {
            header += &format!("property float max_{axis}\n");
        }
    }
    header += &format!("element vertex {vertices}\n");
    for name in ["position", "rotation", "scale", "color"] {
        header += &format!("property uint packed_{name}\n");
    }
    header += "end_header\n";
    let mut bytes = header.into_bytes();
    bytes.resize(bytes.len() + 48 * chunks + 16 * vertices, 0);
    bytes
}

/// A GLB file: JSON chunk and binary chunk.
pub fn glb(json: &serde_json::Value, bin: &[u8]) -> Vec<u8> {
    let mut text = serde_json::to_vec(json).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut data = bin.to_vec();
    while !data.len().is_multiple_of(4) {
        data.push(0);
    }
    let total = 12 + 8 + text.len() + 8 + data.len();
    let mut out = Vec::new();
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((text.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(text);
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(data);
    out
}
