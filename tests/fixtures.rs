//! The shared fixtures that pin the trainer's Python to this crate: a quick bake of the
//! Witch and the positions and group normalisation the Rust code computes from it. The
//! test fails if the committed files differ from what the code makes now; regenerate with
//! `UNICA_REGENERATE_FIXTURES=1 cargo test --release --test fixtures`.

mod common;

use common::files;

use std::path::{Path, PathBuf};

use unica::dataset::bake::{BakeOptions, bake};
use unica::dataset::{ANCHOR, Dataset, GROUP};
use unica::posmap::GroupNorm;
use unica::tensors::{self, TensorData};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

/// Bakes the quick dataset into `dir/dataset_quick` and writes `dir/dataset_expected.safetensors`.
fn generate(dir: &Path) {
    let witch = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/witch/source/Witch.gltf");
    let data_dir = dir.join("dataset_quick");
    let options = BakeOptions {
        quick: true,
        no_renders: true,
        ..Default::default()
    };
    bake(&witch, &data_dir, &options, &|_, _| {}).unwrap();
    // The manifest names the character as given; keep it machine-independent.
    let manifest = data_dir.join("manifest.json");
    let text = std::fs::read_to_string(&manifest)
        .unwrap()
        .replace(&witch.display().to_string(), "Witch.gltf");
    std::fs::write(&manifest, text).unwrap();
    let data = Dataset::open(&data_dir).unwrap();
    let clip = data.clip(2).unwrap();
    let frames: Vec<Vec<glam::Vec3>> = (0..GROUP).map(|f| data.positions(&clip, 4 + f)).collect();
    let (unit, root) = data
        .norm()
        .normalise(&frames, &data.reference.waist, ANCHOR)
        .unwrap();
    let n = frames[0].len();
    let flat = |v: &[Vec<glam::Vec3>]| {
        v.iter()
            .flatten()
            .flat_map(|p| p.to_array())
            .collect::<Vec<f32>>()
    };
    tensors::write(
        &dir.join("dataset_expected.safetensors"),
        &[
            (
                "clip2_frames4to7_positions",
                TensorData::f32(&[GROUP, n, 3], &flat(&frames)),
            ),
            (
                "clip2_frames4to7_normalised",
                TensorData::f32(&[GROUP, n, 3], &flat(&unit)),
            ),
            (
                "clip2_frames4to7_root",
                TensorData::f32(&[3], &root.to_array()),
            ),
            (
                "clip2_frames4to7_roots",
                TensorData::f32(
                    &[GROUP, 3],
                    &frames
                        .iter()
                        .flat_map(|f| GroupNorm::root(f, &data.reference.waist).to_array())
                        .collect::<Vec<_>>(),
                ),
            ),
        ],
    )
    .unwrap();
}

#[test]
fn the_committed_dataset_fixtures_are_what_the_code_makes() {
    if std::env::var_os("UNICA_REGENERATE_FIXTURES").is_some() {
        for stale in ["dataset_quick", "dataset_expected.safetensors"] {
            let _ = std::fs::remove_dir_all(fixtures().join(stale));
            let _ = std::fs::remove_file(fixtures().join(stale));
        }
        generate(&fixtures());
    }
    let fresh = tempfile::tempdir().unwrap();
    generate(fresh.path());
    let committed: Vec<_> = files(&fixtures())
        .into_iter()
        .filter(|(p, _)| {
            p.starts_with("dataset_quick") || p.starts_with("dataset_expected.safetensors")
        })
        .collect();
    assert_eq!(
        committed.len(),
        files(fresh.path()).len(),
        "fixture files missing; regenerate (see the module header)"
    );
    assert!(
        committed == files(fresh.path()),
        "fixtures are stale; regenerate (see the module header)"
    );
}
