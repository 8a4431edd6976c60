//! The auto-rig models' CPU inference against the PyTorch trainer's fixtures
//! (tests/fixtures/autorig, written by `python -m unica_train.rig fixtures`; tiny configs
//! with random weights): skeleton logits, the KV-cache path, grammar-complete predictions,
//! skin weights and the geodesic baseline, and named load errors.
//!
//! Error measure: max |Rust - PyTorch| / max(1, max |PyTorch|). Both sides compute in f32
//! on a CPU; only the summation order (8-lane dot products here, blocked BLAS kernels
//! there) and the math library's sin/cos/exp/tanh differ, by a few ulps (~1e-7 relative)
//! per operation. Through the ~20 layers of the skeleton model that stays around 1e-6;
//! 1e-4 leaves a wide margin and still catches any indexing, layout or mask error, which
//! moves outputs by O(0.1-1).

use std::path::{Path, PathBuf};

use glam::Vec3;
use unica::autorig::model::{ModelError, SkeletonModel, SkinModel, baseline_weights, top4};
use unica::autorig::skeleton::Class;
use unica::autorig::tokens::{self, EOS, VOCAB};
use unica::tensors::TensorFile;

const TOLERANCE: f32 = 1e-4;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/autorig")
}

fn io(kind: &str) -> TensorFile {
    TensorFile::open(&fixtures().join(format!("{kind}_io.safetensors"))).unwrap()
}

fn floats(file: &TensorFile, name: &str, dims: usize) -> Vec<f32> {
    file.f32(name, &vec![None; dims]).unwrap().0
}

fn vec3s(file: &TensorFile, name: &str) -> Vec<Vec3> {
    floats(file, name, 2)
        .chunks_exact(3)
        .map(Vec3::from_slice)
        .collect()
}

/// The error measure of the module header.
fn relative_error(got: &[f32], want: &[f32]) -> f32 {
    assert_eq!(got.len(), want.len());
    let worst = got
        .iter()
        .zip(want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    worst / want.iter().fold(1.0f32, |m, v| m.max(v.abs()))
}

struct SkeletonCase {
    model: SkeletonModel,
    points: Vec<Vec3>,
    normals: Vec<Vec3>,
    tokens: Vec<u32>,
    logits: Vec<f32>,
}

fn skeleton_case() -> SkeletonCase {
    let file = io("skeleton");
    SkeletonCase {
        model: SkeletonModel::load(&fixtures()).unwrap(),
        points: vec3s(&file, "points"),
        normals: vec3s(&file, "normals"),
        tokens: file
            .i32("tokens", &[None])
            .unwrap()
            .0
            .iter()
            .map(|&t| t as u32)
            .collect(),
        logits: floats(&file, "logits", 2),
    }
}

#[test]
fn skeleton_logits_match_pytorch() {
    let c = skeleton_case();
    let logits = c.model.logits(&c.points, &c.normals, &c.tokens).unwrap();
    assert_eq!(logits.len(), c.tokens.len());
    let error = relative_error(logits.as_flattened(), &c.logits);
    eprintln!("skeleton logits: relative error {error:.2e}");
    assert!(error < TOLERANCE, "{error}");
}

#[test]
fn cached_decoding_matches_the_full_forward() {
    let c = skeleton_case();
    let full = c.model.logits(&c.points, &c.normals, &c.tokens).unwrap();
    let mut decoding = c.model.start(&c.points, &c.normals);
    let mut worst = 0.0f32;
    for (&token, want) in c.tokens.iter().zip(&full) {
        let got = decoding.step(token).unwrap();
        worst = worst.max(relative_error(&got, want));
    }
    eprintln!("cached vs full forward: relative error {worst:.2e}");
    assert!(worst < 1e-5, "{worst}");
    // The cache ends at max_len, as the full forward does.
    let max_len = c.model.config().max_len;
    for _ in c.tokens.len()..max_len {
        decoding.step(EOS).unwrap();
    }
    assert!(matches!(
        decoding.step(EOS),
        Err(ModelError::TooLong { .. })
    ));
    let long = vec![EOS; max_len + 1];
    assert!(c.model.logits(&c.points, &c.normals, &long).is_err());
    assert!(matches!(
        c.model.logits(&c.points, &c.normals, &[VOCAB as u32]),
        Err(ModelError::OutOfVocabulary(265))
    ));
}

#[test]
fn predictions_are_complete_skeletons_within_max_len() {
    let c = skeleton_case();
    let max_len = c.model.config().max_len;
    let mut longest = 0;
    for (temperature, seed) in [(0.0, 0), (1.0, 1), (1.0, 2), (2.0, 3), (4.0, 4), (8.0, 5)] {
        let tokens = c
            .model
            .predict_tokens(&c.points, &c.normals, None, temperature, seed)
            .unwrap();
        assert!(
            tokens.len() <= max_len && tokens.last() == Some(&EOS),
            "{tokens:?}"
        );
        let skeleton = tokens::decode(&tokens).unwrap();
        assert!(!skeleton.is_empty());
        let again = c
            .model
            .predict(&c.points, &c.normals, None, temperature, seed)
            .unwrap();
        assert_eq!(again, skeleton, "a seed gives one skeleton");
        longest = longest.max(tokens.len());
    }
    // Random weights seldom pick eos: the runs end because the remaining room forces it.
    assert!(longest >= max_len - 3, "{longest}");
    // A requested class is the one decoded, whatever the model prefers.
    for class in [Class::Quadruped, Class::Other] {
        let skeleton = c
            .model
            .predict(&c.points, &c.normals, Some(class), 1.0, 7)
            .unwrap();
        assert_eq!(skeleton.class, class);
    }
}

#[test]
fn skin_weights_match_pytorch() {
    let model = SkinModel::load(&fixtures()).unwrap();
    let file = io("skin");
    let joints = vec3s(&file, "joints");
    let geodesic = floats(&file, "geodesic", 2);
    let weights = model.weights(
        &vec3s(&file, "vertices"),
        &vec3s(&file, "vertex_normals"),
        &joints,
        &vec3s(&file, "bone_tails"),
        &geodesic,
    );
    let error = relative_error(&weights.concat(), &floats(&file, "weights", 2));
    let beta = floats(&file, "beta", 1)[0];
    let baseline = baseline_weights(beta, &geodesic, joints.len());
    let baseline_error = relative_error(&baseline.concat(), &floats(&file, "baseline", 2));
    eprintln!("skin weights: relative error {error:.2e}; baseline {baseline_error:.2e}");
    assert!(
        error < TOLERANCE && baseline_error < TOLERANCE,
        "{error} {baseline_error}"
    );
    for row in &weights {
        let (bones, kept) = top4(row);
        assert!((kept.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        let mut sorted = row.clone();
        sorted.sort_by(|a, b| b.total_cmp(a));
        assert_eq!(row[bones[0] as usize], sorted[0]);
        assert_eq!(row[bones[3] as usize], sorted[3]);
        assert!(kept.windows(2).all(|w| w[0] >= w[1]));
    }
    assert_eq!(top4(&[0.25, 0.75]), ([1, 0, 0, 0], [0.75, 0.25, 0.0, 0.0]));
}

#[test]
fn bad_weights_and_configs_are_named_errors() {
    let dir = tempfile::tempdir().unwrap();
    let copy = |name: &str| std::fs::copy(fixtures().join(name), dir.path().join(name)).unwrap();
    copy("skeleton.safetensors");
    let message = |e: ModelError| e.to_string();
    let e = message(SkeletonModel::load(dir.path()).err().unwrap());
    assert!(e.contains("skeleton_config.json"), "{e}");
    let config =
        |text: &str| std::fs::write(dir.path().join("skeleton_config.json"), text).unwrap();
    config(r#"{"d": 32, "heads": 2, "latents": 4, "layers": 2, "max_len": 64}"#);
    let e = message(SkeletonModel::load(dir.path()).err().unwrap());
    assert!(
        e.contains("skeleton.safetensors")
            && e.contains("encoder.embed.0.weight")
            && e.contains("expected [32, 42]"),
        "{e}"
    );
    config(r#"{"d": 24, "heads": 2, "latents": 4, "layers": 3, "max_len": 64}"#);
    let e = message(SkeletonModel::load(dir.path()).err().unwrap());
    assert!(
        e.contains("'decoder.blocks.2.attn.ln.weight' is missing"),
        "{e}"
    );
    config(r#"{"d": 24, "heads": 5, "latents": 4, "layers": 2, "max_len": 64}"#);
    let e = message(SkeletonModel::load(dir.path()).err().unwrap());
    assert!(e.contains("does not split into 5 heads"), "{e}");
    copy("skin_config.json");
    std::fs::write(dir.path().join("skin.safetensors"), b"junk").unwrap();
    let e = message(SkinModel::load(dir.path()).err().unwrap());
    assert!(
        e.contains("skin.safetensors") && e.contains("not a safetensors file"),
        "{e}"
    );
}
