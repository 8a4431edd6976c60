//! The WGSL engine against the PyTorch trainer's fixtures (tests/fixtures/nn, written by
//! `python -m unica_train.fixtures`), in f32 and (where the adapter has SHADER_F16) in
//! f16 storage, and every fused kernel against the ops it fuses. One file per part:
//! `layers` (every layer kind, one table), `conv`, `attention`, `linear` and `layout`
//! (the fused kernels of each op), `models` (UNet, schedule, DDIM), `bundles` (the
//! shipped Witch, bad bundles) and `refiner`; this file holds the shared harness.
//!
//! Error measure: max |GPU - PyTorch| / max(1, max |PyTorch|) over the output.
//! - f32: the same products summed in another order differ by a few ulps per layer
//!   (~1e-7 relative); 1e-4 leaves room for a UNet's ~60 kernels in a row and still
//!   catches any indexing error (errors of O(1); `a_wrong_index_would_be_caught`).
//!   Measured on lavapipe: 6e-8 to 3e-7 for layers, up to 1.2e-6 for whole models.
//! - f16: every stored activation and weight is rounded to 11 bits (4.9e-4 relative)
//!   while arithmetic stays f32, so one layer is off by about one rounding and a whole
//!   UNet or VAE (25-60 kernels, errors partly averaging out) by a few: measured 4e-4 to
//!   6e-4 for layers, up to 1.5e-3 for the models and the sampler. 2e-3 for layers and
//!   5e-3 for models leave about 3x margin and stay 100x below an indexing error.

mod attention;
mod bundles;
mod conv;
mod layers;
mod layout;
mod linear;
mod models;
mod refiner;

use std::path::Path;

use unica::gpu::kernel::{PipelineCache, Precision};

use unica::gpu::{GpuContext, GpuOptions};

use unica::nn::layers::{
    Conv, CrossAttention, Frames, ResBlock, SpatialAttention, TemporalAttention, UpBlock,
};

use unica::nn::ops::{AttentionParams, Broadcast};

use unica::nn::refiner::{Refiner, RefinerConfig};

use unica::nn::sampler::{self, Sampling, Schedule};

use unica::nn::unet::{UNet, UNetConfig};

use unica::nn::vae::{Decoder, Encoder, VaeConfig};

use unica::engine::bundle::Bundle;
use unica::nn::{Kernels, Recorder, Tensor, Weights};

use unica::tensors::TensorFile;

/// Tolerances of the error measure above: (layers, whole models).
fn tolerances(precision: Precision) -> (f32, f32) {
    match precision {
        Precision::F32 => (1e-4, 1e-4),
        Precision::F16 => (2e-3, 5e-3),
    }
}

/// The largest absolute difference.
fn worst_difference(got: &[f32], want: &[f32]) -> f32 {
    got.iter()
        .zip(want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max)
}

/// The error measure of the module header: worst difference / max(1, max |want|).
fn relative_error(got: &[f32], want: &[f32]) -> f32 {
    worst_difference(got, want) / want.iter().fold(1.0f32, |m, v| m.max(v.abs()))
}

/// One fixture file, a device and a pipeline cache.
struct Fixture {
    file: TensorFile,
    gpu: GpuContext,
    pipelines: PipelineCache,
    precision: Precision,
}

impl Fixture {
    fn open(name: &str, precision: Precision) -> Self {
        let path = repo().join(format!("tests/fixtures/nn/{name}.safetensors"));
        let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
        Self {
            file: TensorFile::open(&path).unwrap(),
            gpu,
            pipelines: PipelineCache::default(),
            precision,
        }
    }

    fn recorder(&mut self) -> (Recorder<'_>, Weights<'_>) {
        (
            Recorder::new(&self.gpu, &mut self.pipelines, self.precision),
            Weights::new(&self.file, &self.gpu, self.precision),
        )
    }

    /// A stored tensor's values and shape (ranks 1 to 5 tried).
    fn stored(&self, name: &str) -> (Vec<f32>, Vec<usize>) {
        (1..=5)
            .find_map(|rank| self.file.f32(name, &vec![None; rank]).ok())
            .unwrap_or_else(|| panic!("{name}: no f32 tensor of rank 1-5"))
    }

    fn input(&self, name: &str) -> Tensor {
        let (values, shape) = self.stored(name);
        Tensor::upload(&self.gpu, name, &shape, &values, self.precision).unwrap()
    }

    /// A tensor of `shape` holding [`wave`] values in the fixture's precision.
    fn wave(&self, name: &str, shape: &[usize], k: f32) -> Tensor {
        wave_tensor(&self.gpu, name, shape, k, self.precision)
    }

    fn scalar(&self, name: &str) -> f32 {
        self.stored(name).0[0]
    }

    /// The error measure of `got` (run and read back) against the stored `name`.
    fn error(&self, got: &Tensor, name: &str) -> f32 {
        let (want, shape) = self.stored(name);
        assert_eq!(
            got.len(),
            want.len(),
            "{name}: {:?} vs {shape:?}",
            got.shape
        );
        relative_error(&got.read(&self.gpu).unwrap(), &want)
    }

    fn assert_close(&self, got: &Tensor, name: &str, tolerance: f32) {
        let error = self.error(got, name);
        println!(
            "{name} ({:?}): error {error:.2e} (tolerance {tolerance:.0e})",
            self.precision
        );
        assert!(
            error <= tolerance,
            "{name} ({:?}): error {error} > {tolerance}",
            self.precision
        );
    }
}

/// The precisions to test: f32, and f16 unless the adapter lacks SHADER_F16 and the
/// fallback was asked for (UNICA_FORCE_FALLBACK: f32 only, by design).
fn precisions() -> Vec<Precision> {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    if gpu.caps.shader_f16 {
        vec![Precision::F32, Precision::F16]
    } else {
        assert!(
            GpuOptions::from_env().force_fallback,
            "{} has no SHADER_F16: the f16 path cannot be tested here",
            gpu.adapter_label()
        );
        eprintln!("f16 path not tested: UNICA_FORCE_FALLBACK is set");
        vec![Precision::F32]
    }
}

/// Which tolerance of [`tolerances`] a check uses.
#[derive(Clone, Copy)]
enum Scope {
    Layer,
    Model,
}

/// Smooth deterministic test values: sin(k·i).
fn wave(n: usize, k: f32) -> Vec<f32> {
    (0..n).map(|i| (i as f32 * k).sin()).collect()
}

/// A tensor of `shape` holding [`wave`] values in `precision`.
fn wave_tensor(
    gpu: &GpuContext,
    name: &str,
    shape: &[usize],
    k: f32,
    precision: Precision,
) -> Tensor {
    let n = shape.iter().product();
    Tensor::upload(gpu, name, shape, &wave(n, k), precision).unwrap()
}

/// A fused kernel against the ops it fuses: every value of `a` within four units in the
/// last place of the storage precision (f32 or f16) at the tensor's largest magnitude of
/// `b`'s. A driver may contract a multiply and an add into one fused multiply-add in one
/// shader and not in the other, which moves a rounding by one unit (and a later add
/// that cancels keeps that absolute difference on a smaller value). lavapipe never does
/// (the two agree bit for bit there); an NVIDIA H200 did, up to 0.0078 in f16 and
/// 9.5e-7 in f32 on values up to 16 (docs/gpu). A fusion that drops or repeats a term
/// misses by the size of the term, orders of magnitude more.
fn assert_same_bits(precision: Precision, a: &[f32], b: &[f32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    let largest = b.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    // One unit in the last place at `largest`: 2^(exponent - mantissa bits), at least
    // the precision's smallest subnormal.
    let (bits, tiniest) = match precision {
        Precision::F32 => (23, -149),
        Precision::F16 => (10, -24),
    };
    let unit = 2f32
        .powi(largest.log2().floor() as i32 - bits)
        .max(2f32.powi(tiniest));
    let worst = worst_difference(a, b);
    // Compared value by value, so that a NaN fails.
    assert!(
        a.iter().zip(b).all(|(p, q)| (p - q).abs() <= 4.0 * unit),
        "{what}: worst difference {worst} ({} units in the last place at the largest \
         magnitude {largest}; at most 4)",
        worst / unit
    );
}

/// Every kernel variant (simple, CPU, GPU) in every precision to test.
fn variants() -> Vec<(Precision, Kernels)> {
    precisions()
        .into_iter()
        .flat_map(|p| Kernels::ALL.map(|k| (p, k)))
        .collect()
}

/// Runs `module` on the fixture's `inputs` (recording with its weights) in every
/// variant and precision and compares its result with the stored `output` at `scope`'s
/// tolerance.
fn check(
    name: &str,
    inputs: &[&str],
    output: &str,
    scope: Scope,
    module: impl Fn(&mut Recorder, &Weights, &[Tensor]) -> Tensor,
) {
    for (precision, kernels) in variants() {
        let mut f = Fixture::open(name, precision);
        let inputs: Vec<Tensor> = inputs.iter().map(|n| f.input(n)).collect();
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let y = module(&mut r, &w, &inputs);
        r.submit();
        let (layer, model) = tolerances(precision);
        let tolerance = match scope {
            Scope::Layer => layer,
            Scope::Model => model,
        };
        f.assert_close(&y, output, tolerance);
    }
}

/// The action id stored in a fixture.
fn action(f: &Fixture) -> usize {
    f.scalar("io.in.action") as usize
}

fn witch_bundle() -> std::path::PathBuf {
    repo().join("assets/witch/bundle")
}

/// The repository whose fixtures and bundle the tests read: `UNICA_REPO` where set (a
/// prebuilt test binary run on another machine, as scripts/gpu-bench.sh does), else the
/// one this binary was built from.
fn repo() -> std::path::PathBuf {
    std::env::var_os("UNICA_REPO")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).to_path_buf())
}

/// One kernel variant in one precision, for the tests of a fused kernel against the ops
/// it fuses: a device, its pipelines, and recorders that use the variant.
struct Variant {
    gpu: GpuContext,
    pipelines: PipelineCache,
    precision: Precision,
    kernels: Kernels,
}

impl Variant {
    /// Every variant in every precision to test (see [`variants`]).
    fn all() -> Vec<Variant> {
        let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
        variants()
            .into_iter()
            .map(|(precision, kernels)| Variant {
                gpu: gpu.clone(),
                pipelines: PipelineCache::default(),
                precision,
                kernels,
            })
            .collect()
    }

    /// A recorder that uses this variant's kernels.
    fn recorder(&mut self) -> Recorder<'_> {
        let mut r = Recorder::new(&self.gpu, &mut self.pipelines, self.precision);
        r.set_kernels(self.kernels);
        r
    }

    /// A tensor of `shape` holding [`wave`] values in this precision.
    fn wave(&self, name: &str, shape: &[usize], k: f32) -> Tensor {
        wave_tensor(&self.gpu, name, shape, k, self.precision)
    }

    fn read(&self, t: &Tensor) -> Vec<f32> {
        t.read(&self.gpu).unwrap()
    }

    /// "precision kernels", for messages.
    fn name(&self) -> String {
        format!("{:?} {:?}", self.precision, self.kernels)
    }
}
