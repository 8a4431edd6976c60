//! Helpers shared by the integration tests: the shared Witch, whole-folder snapshots and
//! the one-line error of a failed run.

#![allow(dead_code)] // each test binary uses its own subset

use std::path::{Path, PathBuf};

/// The default avatar's source, shipped in assets/witch/source (CC0).
pub fn witch() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/witch/source/Witch.gltf")
}

/// Every file under `dir` with its path relative to `dir`, sorted.
pub fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<(PathBuf, Vec<u8>)>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.push((
                    path.strip_prefix(root).unwrap().to_path_buf(),
                    std::fs::read(&path).unwrap(),
                ));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
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
