//! The WGSL engine against the PyTorch trainer's fixtures (tests/fixtures/nn, written by
//! `python -m unica_train.fixtures`): every layer kind, the VAE encoder and decoder, a
//! whole UNet step, the cached context path, a DDIM step with CFG and a 4-step DDIM
//! sample, in f32 and (where the adapter has SHADER_F16) in f16 storage.
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
use unica::nn::{Bundle, Kernels, Recorder, Tensor, Weights};
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
        let n = shape.iter().product();
        Tensor::upload(&self.gpu, name, shape, &wave(n, k), self.precision).unwrap()
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

/// Runs `module` on the fixture's `inputs` (recording with its weights) in every
/// precision and compares its result with the stored `output` at `scope`'s tolerance.
/// Every kernel variant (simple, CPU, GPU) in every precision to test.
/// Smooth deterministic test values: sin(k·i).
fn wave(n: usize, k: f32) -> Vec<f32> {
    (0..n).map(|i| (i as f32 * k).sin()).collect()
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

fn variants() -> Vec<(Precision, Kernels)> {
    precisions()
        .into_iter()
        .flat_map(|p| Kernels::ALL.map(|k| (p, k)))
        .collect()
}

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

fn check_layer(
    name: &str,
    inputs: &[&str],
    layer: impl Fn(&mut Recorder, &Weights, &[Tensor]) -> Tensor,
) {
    check(name, inputs, "io.out.y", Scope::Layer, layer);
}

#[test]
fn stride_two_convolution_matches_pytorch() {
    check_layer("down", &["io.in.x"], |r, w, x| {
        let conv = Conv::load(&w.at("conv"), 8, 12, 3, 2).unwrap();
        conv.forward(r, &x[0]).unwrap()
    });
}

#[test]
fn nearest_upsampling_then_convolution_matches_pytorch() {
    check_layer("up", &["io.in.x"], |r, w, x| {
        let up = UpBlock::load(w, 8, 12).unwrap();
        up.forward(r, &x[0]).unwrap()
    });
}

#[test]
fn a_wrong_index_would_be_caught() {
    // The check is only as good as its tolerance: a convolution without its bias (one
    // missing term) must fail it by far.
    let mut f = Fixture::open("down", Precision::F32);
    let x = f.input("io.in.x");
    let (mut r, w) = f.recorder();
    let weight = w.at("conv").tensor("weight", &[12, 8, 3, 3]).unwrap();
    let y = r.conv2d(&x, &weight, None, 2, 1).unwrap();
    r.submit();
    let error = f.error(&y, "io.out.y");
    assert!(error > 10.0 * tolerances(Precision::F16).1, "{error}");
}

#[test]
fn a_residual_block_matches_pytorch() {
    check_layer("resblock", &["io.in.x", "io.in.emb"], |r, w, x| {
        let block = ResBlock::load(w, 8, 16, Some(32)).unwrap();
        block.forward(r, &x[0], Some(&x[1])).unwrap()
    });
}

#[test]
fn a_residual_block_over_a_concatenation_equals_the_block_over_the_concatenated_tensor() {
    // The UNet's skip connections: the block over two tensors concatenated along the
    // channels (on CPU drivers only texels copied from the two, read by the first norm
    // and the 1×1 skip) must equal the concatenation kernel then the block, bit for bit,
    // in every variant and precision: the fixture's 8 input channels split 3 + 5.
    for (precision, kernels) in variants() {
        let mut f = Fixture::open("resblock", precision);
        let x = f.input("io.in.x");
        let emb = f.input("io.in.emb");
        let [n, _, h, wd] = x.shape[..] else {
            panic!("NCHW fixture")
        };
        let values = x.read(&f.gpu).unwrap();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for image in values.chunks(8 * h * wd) {
            a.extend_from_slice(&image[..3 * h * wd]);
            b.extend_from_slice(&image[3 * h * wd..]);
        }
        let a = Tensor::upload(&f.gpu, "a", &[n, 3, h, wd], &a, precision).unwrap();
        let b = Tensor::upload(&f.gpu, "b", &[n, 5, h, wd], &b, precision).unwrap();
        let gpu = f.gpu.clone();
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let block = ResBlock::load(&w, 8, 16, Some(32)).unwrap();
        let projected = block.project(&mut r, &emb).unwrap();
        let split = block
            .forward_concat(&mut r, &a, &b, projected.as_ref())
            .unwrap();
        let whole = block
            .forward_projected(&mut r, &x, projected.as_ref())
            .unwrap();
        r.submit();
        let what = format!("{precision:?} {kernels:?}");
        assert_same_bits(
            precision,
            &split.read(&gpu).unwrap(),
            &whole.read(&gpu).unwrap(),
            &what,
        );
    }
}

#[test]
fn spatial_self_attention_matches_pytorch() {
    check_layer("spatial_attention", &["io.in.x"], |r, w, x| {
        let layer = SpatialAttention::load(w, 16, 2).unwrap();
        layer.forward(r, &x[0]).unwrap()
    });
}

#[test]
fn cross_attention_to_the_action_token_matches_pytorch() {
    check_layer("cross_attention", &["io.in.x", "io.in.ctx"], |r, w, x| {
        let layer = CrossAttention::load(w, 16, 32, 2).unwrap();
        layer.forward(r, &x[0], &x[1]).unwrap()
    });
}

#[test]
fn causal_temporal_attention_with_frame_positions_matches_pytorch() {
    check_layer("temporal_attention", &["io.in.x"], |r, w, x| {
        let layer = TemporalAttention::load(w, 16, 4, 2).unwrap();
        let frames = Frames::First {
            count: 4,
            keep: None,
        };
        layer.forward(r, &x[0], frames).unwrap()
    });
}

#[test]
fn the_last_frame_from_cached_rows_equals_the_whole_group() {
    // Causality: frames 0-2 run alone (rows kept), then frame 3 alone against the kept
    // rows, must give the whole group's frame 3. x [8, 16, 4, 4] = 2 groups × 4 frames.
    let mut f = Fixture::open("temporal_attention", Precision::F32);
    let (values, _) = f.stored("io.in.x");
    let frame = 16 * 4 * 4;
    let pick = |frames: std::ops::Range<usize>| -> Vec<f32> {
        (0..2)
            .flat_map(|g| {
                values[(4 * g + frames.start) * frame..(4 * g + frames.end) * frame].to_vec()
            })
            .collect()
    };
    let context = Tensor::upload(
        &f.gpu,
        "context",
        &[6, 16, 4, 4],
        &pick(0..3),
        Precision::F32,
    )
    .unwrap();
    let last = Tensor::upload(&f.gpu, "last", &[2, 16, 4, 4], &pick(3..4), Precision::F32).unwrap();
    let (mut r, w) = f.recorder();
    let layer = TemporalAttention::load(&w, 16, 4, 2).unwrap();
    let mut kept = Vec::new();
    let frames = Frames::First {
        count: 3,
        keep: Some(&mut kept),
    };
    layer.forward(&mut r, &context, frames).unwrap();
    let y = layer
        .forward(&mut r, &last, Frames::Next { cached: &kept[0] })
        .unwrap();
    r.submit();
    let got = y.read(&f.gpu).unwrap();
    let want: Vec<f32> = {
        let (out, _) = f.stored("io.out.y");
        (0..2)
            .flat_map(|g| out[(4 * g + 3) * frame..(4 * g + 4) * frame].to_vec())
            .collect()
    };
    let worst = worst_difference(&got, &want);
    assert!(worst <= 1e-4, "{worst}");
}

#[test]
fn the_timestep_embedding_matches_pytorch() {
    // Arguments reach 999 rad, whose f32 spacing is 6.1e-5; sin/cos of the same rounded
    // argument may then differ by that much plus a few ulps of the GPU's approximations.
    let mut f = Fixture::open("timestep_embedding", Precision::F32);
    let t = f.input("io.in.t");
    let (mut r, _) = f.recorder();
    let y = r.timestep_embedding(&t, 32).unwrap();
    r.submit();
    assert_eq!(y.shape, [4, 32]);
    f.assert_close(&y, "io.out.y", 5e-4);
}

#[test]
fn the_vae_encoder_mean_matches_pytorch() {
    check(
        "vae_encoder",
        &["io.in.x"],
        "io.out.mean",
        Scope::Model,
        |r, w, x| {
            let mean = Encoder::load(w, &VaeConfig::TINY)
                .unwrap()
                .forward(r, &x[0])
                .unwrap();
            assert_eq!(mean.shape, [1, 4, 16, 16]);
            mean
        },
    );
}

#[test]
fn the_vae_decoder_matches_pytorch() {
    check(
        "vae_decoder",
        &["io.in.z"],
        "io.out.y",
        Scope::Model,
        |r, w, z| {
            let y = Decoder::load(w, &VaeConfig::TINY)
                .unwrap()
                .forward(r, &z[0])
                .unwrap();
            assert_eq!(y.shape, [1, 3, 128, 128]);
            y
        },
    );
}

#[test]
fn the_pca_head_vae_decoder_matches_pytorch() {
    // Two latents, so each sample's rows of the gather table are checked.
    check(
        "vae_pca_decoder",
        &["io.in.z"],
        "io.out.y",
        Scope::Model,
        |r, w, z| {
            let y = Decoder::load(w, &VaeConfig::TINY_PCA)
                .unwrap()
                .forward(r, &z[0])
                .unwrap();
            assert_eq!(y.shape, [2, 3, 128, 128]);
            y
        },
    );
}

#[test]
fn index_tensors_out_of_order_or_out_of_range_are_refused_by_name() {
    use unica::tensors::{TensorData as Stored, write};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.safetensors");
    let tensors = [
        ("pixels", Stored::i32(&[3], &[5, 2, 9])),
        ("far", Stored::i32(&[2], &[1, 99])),
        ("good", Stored::i32(&[2], &[1, 15])),
    ];
    write(&path, &tensors).unwrap();
    let file = TensorFile::open(&path).unwrap();
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let w = Weights::new(&file, &gpu, Precision::F32);
    let error = w.indices("pixels", 3, 16).unwrap_err().to_string();
    assert!(
        error.contains("bad.safetensors")
            && error.contains("'pixels' is not increasing at index 1 (5 then 2)"),
        "{error}"
    );
    let error = w.indices("far", 2, 16).unwrap_err().to_string();
    assert!(error.contains("'far' holds 99, outside 0..16"), "{error}");
    assert_eq!(w.indices("good", 2, 16).unwrap(), [1, 15]);
}

/// The action id stored in a fixture.
fn action(f: &Fixture) -> usize {
    f.scalar("io.in.action") as usize
}

#[test]
fn a_whole_unet_step_matches_pytorch() {
    for precision in precisions() {
        let mut f = Fixture::open("tiny_unet", precision);
        let (x, t, a) = (f.input("io.in.x"), f.stored("io.in.t").0, action(&f));
        let (mut r, w) = f.recorder();
        let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
        let eps = unet.groups(&mut r, &x, &t, &[a]).unwrap();
        r.submit();
        assert_eq!(eps.shape, [1, 4, 4, 16, 16]);
        f.assert_close(&eps, "io.out.eps", tolerances(precision).1);
    }
}

#[test]
fn the_cached_context_path_gives_the_whole_groups_target_noise() {
    // Context frames once, then the target alone, against PyTorch's full 4-frame pass.
    let mut f = Fixture::open("tiny_unet", Precision::F32);
    let (x, shape) = f.stored("io.in.x");
    let frame = x.len() / 4;
    let context = Tensor::upload(
        &f.gpu,
        "context",
        &[1, 3, 4, 16, 16],
        &x[..3 * frame],
        Precision::F32,
    )
    .unwrap();
    let target = Tensor::upload(
        &f.gpu,
        "target",
        &[1, 4, 16, 16],
        &x[3 * frame..],
        Precision::F32,
    )
    .unwrap();
    assert_eq!(shape, [1, 4, 4, 16, 16]);
    let (t, a) = (f.stored("io.in.t").0, action(&f));
    let (mut r, w) = f.recorder();
    let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
    let cache = unet.context(&mut r, &context, &[a]).unwrap();
    let eps = unet.next(&mut r, &target, t[3], &cache).unwrap();
    r.submit();
    let got = eps.read(&f.gpu).unwrap();
    let want = &f.stored("io.out.eps").0[3 * frame..];
    let error = relative_error(&got, want);
    assert!(error <= 1e-4, "{error}");
}

fn schedule() -> Schedule {
    Schedule::scaled_linear(1000, 0.00085, 0.012)
}

#[test]
fn the_schedule_matches_pytorch() {
    let f = Fixture::open("alphas_cumprod", Precision::F32);
    let want = f.stored("io.out.alphas_cumprod").0;
    let s = schedule();
    assert_eq!(s.steps(), want.len());
    for (t, w) in want.iter().enumerate() {
        assert!((s.alpha_bar(t as i64) as f32 - w).abs() <= 1e-7, "t = {t}");
    }
}

#[test]
fn a_ddim_step_with_classifier_free_guidance_matches_pytorch() {
    for precision in precisions() {
        let mut f = Fixture::open("tiny_unet", precision);
        let (x, shape) = f.stored("io.in.x");
        let frame = x.len() / 4;
        let context = Tensor::upload(
            &f.gpu,
            "context",
            &[1, 3, 4, 16, 16],
            &x[..3 * frame],
            precision,
        )
        .unwrap();
        let target = Tensor::upload(
            &f.gpu,
            "target",
            &[1, 4, 16, 16],
            &x[3 * frame..],
            precision,
        )
        .unwrap();
        assert_eq!(shape[1], 4);
        let (a, scale, t_prev) = (
            action(&f),
            f.scalar("io.in.cfg_scale"),
            f.scalar("io.in.t_prev") as i64,
        );
        let t = f.stored("io.in.t").0[3] as i64;
        let (mut r, w) = f.recorder();
        let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
        let both = r.concat(&context, &context, 0).unwrap();
        let cache = unet
            .context(&mut r, &both, &[a, unet.cfg.null_action()])
            .unwrap();
        let eps = sampler::guided_eps(&mut r, &unet, &target, t, &cache, scale).unwrap();
        let (ca, cb) = schedule().ddim_coefficients(t, t_prev);
        let x_prev = r.axpby(ca, &target, 0, cb, &eps, 0, &target.shape).unwrap();
        r.submit();
        let tolerance = tolerances(precision).1;
        f.assert_close(&eps, "io.out.guided_eps", tolerance);
        f.assert_close(&x_prev, "io.out.x_prev", tolerance);
    }
}

#[test]
fn a_four_step_ddim_sample_matches_pytorch() {
    for precision in precisions() {
        let mut f = Fixture::open("tiny_unet", precision);
        let (context, noise, a) = (f.input("io.in.context"), f.input("io.in.noise"), action(&f));
        let sampling = Sampling::new(
            f.scalar("io.in.steps") as usize,
            f.scalar("io.in.cfg_scale"),
        );
        let (mut r, w) = f.recorder();
        let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
        let x0 = sampler::sample_next(&mut r, &unet, &schedule(), &context, &[a], &noise, sampling)
            .unwrap();
        r.submit();
        f.assert_close(&x0, "io.out.x0", tolerances(precision).1);
    }
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

#[test]
fn the_shipped_witch_bundle_generates_and_decodes_what_pytorch_does() {
    // Trained weights, the bundle's teacher sampler (10 DDIM steps, its guidance; Idle
    // sampled as its manifest says) and its distilled student's one pass, then the
    // decoder: values are latents of size ~3 and map coordinates in [0, 1]. Forward and
    // Idle.
    for (name, precision) in [
        "witch_frame",
        "witch_idle_frame",
        "witch_one_pass_frame",
        "witch_one_pass_idle_frame",
    ]
    .into_iter()
    .flat_map(|name| precisions().into_iter().map(move |p| (name, p)))
    {
        let mut f = Fixture::open(name, precision);
        let (noise, a) = (f.input("io.in.noise"), action(&f));
        let bundle = Bundle::load(&witch_bundle(), &f.gpu, precision).unwrap();
        let teacher = bundle.manifest.sampler;
        let sampling = if name.contains("one_pass") {
            assert_eq!(bundle.live_sampling().unet_passes(), 1, "{name}");
            bundle.live_sampling()
        } else {
            teacher.ddim(teacher.steps)
        };
        let mut r = Recorder::new(&f.gpu, &mut f.pipelines, precision);
        let context = bundle.context.reshaped(&[1, 3, 4, 16, 16]);
        let z = bundle
            .generate(&mut r, &context, a, &noise, sampling)
            .unwrap();
        let map = bundle.decode(&mut r, &z).unwrap();
        r.submit();
        // In f16 storage a trained model's frame is further off than the tiny models':
        // its latents are ~3 in size and the student's weights (an int8 difference added
        // to the UNet's) are rounded to 11 bits on upload. Measured on lavapipe: z 0.4e-3
        // to 5.2e-3, map 3e-4. 1e-2 is still 100x below an indexing error.
        let tolerance = match precision {
            Precision::F32 => tolerances(precision).1,
            Precision::F16 => 1e-2,
        };
        f.assert_close(&z, "io.out.z", tolerance);
        f.assert_close(&map, "io.out.map", tolerance);
    }
}

/// A copy of the Witch bundle whose manifest `edit` changes.
fn edited_bundle(edit: impl FnOnce(&mut serde_json::Value)) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let source = witch_bundle();
    std::fs::copy(
        source.join("weights.safetensors"),
        dir.path().join("weights.safetensors"),
    )
    .unwrap();
    let mut manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source.join("manifest.json")).unwrap())
            .unwrap();
    edit(&mut manifest);
    std::fs::write(dir.path().join("manifest.json"), manifest.to_string()).unwrap();
    dir
}

fn load_error(dir: &Path) -> String {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    match Bundle::load(dir, &gpu, Precision::F32) {
        Ok(_) => panic!("{} loaded", dir.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bundles_of_another_version_or_format_are_refused() {
    let dir = edited_bundle(|m| m["version"] = 2.into());
    let message = load_error(dir.path());
    assert!(
        message.contains("manifest.json")
            && message.contains("bundle version 2, this build reads version 1"),
        "{message}"
    );
    let dir = edited_bundle(|m| m["format"] = "something-else".into());
    let message = load_error(dir.path());
    assert!(message.contains("not a unica bundle"), "{message}");
}

#[test]
fn the_first_tensor_that_disagrees_with_the_config_is_named() {
    // A manifest claiming a 64-d embedding: the first embedding-sized tensor loaded is
    // the action table (for the cross-attention tables), stored as [6, 128].
    let dir = edited_bundle(|m| m["unet"]["embed"] = 64.into());
    let message = load_error(dir.path());
    assert!(
        message.contains("weights.safetensors")
            && message.contains("'unet.action.weight' has shape [6, 128], expected [6, 64]"),
        "{message}"
    );
    // A missing file is named too.
    let dir = edited_bundle(|_| {});
    std::fs::remove_file(dir.path().join("weights.safetensors")).unwrap();
    let message = load_error(dir.path());
    assert!(message.contains("weights.safetensors"), "{message}");
}

#[test]
fn unsupported_model_shapes_are_refused_before_loading() {
    let dir = edited_bundle(|m| m["unet"]["heads"] = 1.into());
    let message = load_error(dir.path());
    assert!(message.contains("at most 64 channels"), "{message}");
}

#[test]
fn the_recorded_flops_agree_with_the_trainers_counter() {
    // unica_train.unet.conv_and_linear_flops on the tiny configs (batch 1, 4 frames):
    // UNet 121,053,184, decoder 53,968,896. The engine runs the cross-attention to the
    // one action token as a table looked up at load, so it does not run that work per
    // frame: per cross layer and frame, q and out (2·64·32·32 each), the attention
    // product (4·64·32) and the token's kv (2·32·64): 274,432 × 4 frames × 3 layers =
    // 3,293,184 fewer. Nor does it repeat the time MLP and the ResBlocks' projections of
    // its output, which depend only on the timesteps: they run once when the work is
    // recorded (2·32·32 twice, and 2·32·(16+32+32+32+32+16), per frame: 57,344 for 4
    // frames). The decoder agrees exactly.
    let mut f = Fixture::open("tiny_unet", Precision::F32);
    let (x, t, a) = (f.input("io.in.x"), f.stored("io.in.t").0, action(&f));
    let (mut r, w) = f.recorder();
    let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
    unet.groups(&mut r, &x, &t, &[a]).unwrap();
    assert_eq!(r.flops(), 121_053_184 - 3_293_184 - 57_344);

    let mut f = Fixture::open("vae_decoder", Precision::F32);
    let z = f.input("io.in.z");
    let (mut r, w) = f.recorder();
    Decoder::load(&w, &VaeConfig::TINY)
        .unwrap()
        .forward(&mut r, &z)
        .unwrap();
    assert_eq!(r.flops(), 53_968_896);
}

/// Points of a fixture tensor [N, 3].
fn points(f: &Fixture, name: &str) -> Vec<glam::Vec3> {
    f.stored(name)
        .0
        .chunks_exact(3)
        .map(glam::Vec3::from_slice)
        .collect()
}

#[test]
fn the_refiner_matches_pytorch() {
    // 300 points in 18 patches of 16 and a tail of 12, pooled by 4 into 75 (4 patches
    // and a tail of 11): serialisation, patch attention, pooling and unpooling; then the
    // same network with a random residual per point added (`refiner_pixel`).
    for (fixture, pixel_residuals) in [("refiner", 0), ("refiner_pixel", 300)] {
        refiner_matches(fixture, pixel_residuals);
    }
}

fn refiner_matches(fixture: &str, pixel_residuals: usize) {
    let cfg = RefinerConfig {
        channels: [16, 32],
        depths: [1, 1],
        heads: [2, 2],
        decoder_depth: 1,
        patch: 16,
        stride: 4,
        mean_bound: 0.004,
        pixel_residuals,
    };
    for (precision, kernels) in variants() {
        let mut f = Fixture::open(fixture, precision);
        let unit = points(&f, "io.in.unit");
        let features = f.input("io.in.features");
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let y = Refiner::load(&w, &cfg)
            .unwrap()
            .forward(&mut r, &features, &unit)
            .unwrap();
        r.submit();
        f.assert_close(&y, "io.out.y", tolerances(precision).1);
    }
}

#[test]
fn the_shipped_refiner_matches_pytorch_on_a_witch_frame() {
    for (precision, kernels) in variants() {
        let mut f = Fixture::open("witch_refiner", precision);
        let manifest: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(witch_bundle().join("manifest.json")).unwrap(),
        )
        .unwrap();
        let cfg: RefinerConfig = serde_json::from_value(manifest["refiner"].clone()).unwrap();
        let file = TensorFile::open(&witch_bundle().join("weights.safetensors")).unwrap();
        let unit = points(&f, "io.in.unit");
        let features = f.input("io.in.features");
        let mut r = Recorder::new(&f.gpu, &mut f.pipelines, precision);
        r.set_kernels(kernels);
        let w = Weights::new(&file, &f.gpu, precision);
        let refiner = Refiner::load(&w.at("refiner"), &cfg).unwrap();
        let y = refiner.forward(&mut r, &features, &unit).unwrap();
        r.submit();
        f.assert_close(&y, "io.out.y", tolerances(precision).1);
    }
}

#[test]
fn every_variant_of_the_group_norm_and_the_packed_convolutions_agrees_on_odd_shapes() {
    // Shapes the fixtures do not reach: a 12-channel group norm over 4 groups of 76,800
    // values (near the CPU kernel's SERIAL_NORM_LIMIT; lavapipe's loop limiter once
    // truncated it silently above 65,535 iterations), and a 3×3 convolution whose rows (13) are not a
    // multiple of its 8-pixel tiles and whose 12 output channels are not a multiple of 8.
    // The simple kernels are the PyTorch-tested reference here.
    let f = Fixture::open("down", Precision::F32);
    let mut pipelines = PipelineCache::default();
    let x = Tensor::upload(
        &f.gpu,
        "x",
        &[1, 12, 160, 160],
        &wave(12 * 160 * 160, 0.37),
        Precision::F32,
    )
    .unwrap();
    let gamma = Tensor::upload(&f.gpu, "g", &[12], &wave(12, 1.3), Precision::F32).unwrap();
    let beta = Tensor::upload(&f.gpu, "b", &[12], &wave(12, 0.7), Precision::F32).unwrap();
    let x2 = Tensor::upload(
        &f.gpu,
        "x2",
        &[2, 5, 11, 13],
        &wave(2 * 5 * 11 * 13, 0.11),
        Precision::F32,
    )
    .unwrap();
    let weights = unica::nn::ops::PackedConv::new(
        &f.gpu,
        "w",
        &wave(12 * 5 * 9, 0.23),
        [12, 5, 3],
        Precision::F32,
    )
    .unwrap();
    // A 1×1 convolution over planes of 12 × 13 = 156 pixels: 39 vec4s, so the last
    // 8-pixel tile is half full.
    let x3 = Tensor::upload(
        &f.gpu,
        "x3",
        &[2, 5, 12, 13],
        &wave(2 * 5 * 12 * 13, 0.13),
        Precision::F32,
    )
    .unwrap();
    let pointwise = unica::nn::ops::PackedConv::new(
        &f.gpu,
        "w1",
        &wave(12 * 5, 0.29),
        [12, 5, 1],
        Precision::F32,
    )
    .unwrap();
    let bias = Tensor::upload(&f.gpu, "bias", &[12], &wave(12, 0.5), Precision::F32).unwrap();
    // A per-image addend for the 3×3 convolution's two images (a ResBlock's embedding).
    let extra = Tensor::upload(&f.gpu, "extra", &[2, 12], &wave(24, 0.9), Precision::F32).unwrap();
    let run = |kernels: Kernels, pipelines: &mut PipelineCache| {
        let mut r = Recorder::new(&f.gpu, pipelines, Precision::F32);
        r.set_kernels(kernels);
        let norm = r.group_norm(&x, &gamma, &beta, 4, true).unwrap();
        let conv = r
            .conv3x3(&x2, &weights, Some(&bias), Some(&extra), None)
            .unwrap();
        let point = r.conv1x1(&x3, &pointwise, Some(&bias)).unwrap();
        r.submit();
        let read = |t: &Tensor| t.read(&f.gpu).unwrap();
        (read(&norm), read(&conv), read(&point))
    };
    let (norm, conv, point) = run(Kernels::Simple, &mut pipelines);
    for kernels in [Kernels::Cpu, Kernels::Gpu] {
        let (n, c, q) = run(kernels, &mut pipelines);
        let norm_error = worst_difference(&n, &norm);
        let conv_error = worst_difference(&c, &conv);
        let point_error = worst_difference(&q, &point);
        println!(
            "{kernels:?}: group norm {norm_error:.1e}, conv3x3 {conv_error:.1e}, conv1x1 {point_error:.1e}"
        );
        // The norm's statistics sum in another order (1e-5 of unit values); the
        // convolutions sum the same terms in the same order, except the GPU 3×3 one,
        // whose threads split the input channels (sums of ~10: a few f32 steps).
        let conv_bound = if kernels == Kernels::Gpu { 1e-5 } else { 1e-6 };
        assert!(norm_error < 1e-5, "{kernels:?} group norm: {norm_error}");
        assert!(conv_error < conv_bound, "{kernels:?} conv3x3: {conv_error}");
        assert!(point_error < 1e-6, "{kernels:?} conv1x1: {point_error}");
    }
}

#[test]
fn the_convolution_with_its_residual_equals_a_separate_add_bit_for_bit() {
    // A ResBlock's `skip + conv2(h)`: the residual fused into conv3x3's epilogue must give
    // exactly what conv3x3 then add.wgsl gives, in every kernel variant and precision
    // (the ResBlock fixtures then check both against PyTorch).
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let x = upload("x", &[2, 5, 11, 13], 0.11);
        let skip = upload("skip", &[2, 12, 11, 13], 0.17);
        let bias = upload("bias", &[12], 0.5);
        let extra = upload("extra", &[2, 12], 0.9);
        let weights = unica::nn::ops::PackedConv::new(
            &f.gpu,
            "w",
            &wave(12 * 5 * 9, 0.23),
            [12, 5, 3],
            precision,
        )
        .unwrap();
        // The fused form is one dispatch (the simple variant: conv2d and two adds).
        let mut c = Recorder::capture(&f.gpu, &mut pipelines, precision);
        c.set_kernels(kernels);
        c.conv3x3(&x, &weights, Some(&bias), Some(&extra), Some(&skip))
            .unwrap();
        let fused_dispatches = c.finish().dispatches();
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let fused = r
            .conv3x3(&x, &weights, Some(&bias), Some(&extra), Some(&skip))
            .unwrap();
        let conv = r
            .conv3x3(&x, &weights, Some(&bias), Some(&extra), None)
            .unwrap();
        let separate = r.add(&skip, &conv, Broadcast::Leading).unwrap();
        r.submit();
        let (a, b) = (fused.read(&f.gpu).unwrap(), separate.read(&f.gpu).unwrap());
        assert_same_bits(precision, &a, &b, &format!("{precision:?} {kernels:?}"));
        let expected = if kernels == Kernels::Simple { 3 } else { 1 };
        assert_eq!(fused_dispatches, expected, "{kernels:?}");
    }
}

#[test]
fn attention_over_a_cached_prefix_equals_attention_over_the_concatenation_bit_for_bit() {
    // The temporal layers' target pass: 3 cached frames' packed qkv rows and 1 new frame,
    // causal, 2 heads of 8 — read in place must equal reading their concatenation, in
    // every kernel variant and precision (head 8: the CPU variant applies).
    let (sequences, cached_keys, c) = (6usize, 3usize, 16usize);
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let cached = upload("cached", &[1, sequences, cached_keys, 3 * c], 0.37);
        let fresh = upload("fresh", &[1, sequences, 1, 3 * c], 0.61);
        let params = unica::nn::ops::AttentionParams {
            sequences: sequences as u32,
            heads: 2,
            queries: 1,
            keys: (cached_keys + 1) as u32,
            channels: c as u32,
            q_stride: (3 * c) as u32,
            q_offset: 0,
            kv_stride: (3 * c) as u32,
            k_offset: c as u32,
            v_offset: (2 * c) as u32,
            causal: 1,
            kv_share: 1,
            prefix_keys: 0,
            rows: 0,
            reserved1: 0,
            reserved2: 0,
        };
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let joined = r.concat(&cached, &fresh, 2).unwrap();
        let whole = r.attention(&fresh, &joined, params).unwrap();
        let in_place = r
            .attention_after(
                &fresh,
                Some(&cached),
                &fresh,
                unica::nn::ops::AttentionParams {
                    prefix_keys: cached_keys as u32,
                    ..params
                },
            )
            .unwrap();
        r.submit();
        let (a, b) = (whole.read(&f.gpu).unwrap(), in_place.read(&f.gpu).unwrap());
        assert_same_bits(precision, &a, &b, &format!("{precision:?} {kernels:?}"));
    }
}

#[test]
fn the_permute_with_its_addends_equals_the_separate_ops_bit_for_bit() {
    // The spatial attention's residual (a + permuted tokens) and the cross-attention's
    // action bias in one pass must equal add_permuted then add_action_bias exactly, in
    // every precision (one kernel serves every variant): 2 samples × 3 frames of 4×5
    // images with 8 channels, actions 2 and 0 of a 3-row table.
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let a = upload("a", &[6, 8, 4, 5], 0.31);
        let tokens = upload("tokens", &[6, 20, 8], 0.53);
        let table = upload("table", &[3, 8], 0.77);
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let ids = r.indices("ids", &[2, 0]).unwrap();
        let (shape, perm) = ([1, 6, 20, 8], [0, 1, 3, 2]);
        let fused = r
            .add_permuted_bias(&a, &tokens, shape, perm, Some((&table, &ids, 3)))
            .unwrap();
        let sum = r.add_permuted(&a, &tokens, shape, perm).unwrap();
        let separate = r.add_action_bias(&sum, &table, &ids, 3).unwrap();
        r.submit();
        let (x, y) = (fused.read(&f.gpu).unwrap(), separate.read(&f.gpu).unwrap());
        let plain = sum.read(&f.gpu).unwrap();
        assert_same_bits(precision, &x, &y, &format!("{precision:?} {kernels:?}"));
        assert!(worst_difference(&x, &plain) > 0.1, "the bias was added");

        // The temporal layers' tokens: permuted, plus frame positions 1..4 of a 5-row
        // table repeated over the leading axes, equal to a permute then add_part.
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let positions = upload("positions", &[5, 8], 0.43);
        let (shape, perm) = ([2, 3, 8, 20], [0, 3, 1, 2]);
        let fused = r
            .permute_add_rows(&a, shape, perm, &positions, 8..32)
            .unwrap();
        let permuted = r.permute(&a, shape, perm).unwrap();
        let separate = r
            .add_part(&permuted, &positions, 8..32, Broadcast::Trailing)
            .unwrap();
        r.submit();
        let (x, y) = (fused.read(&f.gpu).unwrap(), separate.read(&f.gpu).unwrap());
        assert_eq!(fused.shape, vec![2, 20, 3, 8]);
        assert_same_bits(
            precision,
            &x,
            &y,
            &format!("{precision:?} {kernels:?} rows"),
        );
    }
}

#[test]
fn the_norm_stored_as_tokens_equals_the_norm_then_the_permute_bit_for_bit() {
    // The attention layers' group norm then permute to token rows (spatial: one frame;
    // temporal: 3 frames with positions 1..4 of a 5-row table) in one dispatch on CPU
    // drivers must equal group_norm then permute(_add_rows) exactly, in every variant
    // and precision: 2 sequences × 3 frames of 4×5 images with 8 channels in 4 groups.
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let x = upload("x", &[6, 8, 4, 5], 0.31);
        let gamma = upload("gamma", &[8], 0.7);
        let beta = upload("beta", &[8], 0.9);
        let positions = upload("positions", &[5, 8], 0.43);
        let what = format!("{precision:?} {kernels:?}");
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let spatial = r
            .group_norm_tokens(&x, (&gamma, &beta, 4), 1, None)
            .unwrap();
        let temporal = r
            .group_norm_tokens(&x, (&gamma, &beta, 4), 3, Some((&positions, 8..32)))
            .unwrap();
        let normed = r.group_norm(&x, &gamma, &beta, 4, false).unwrap();
        let spatial_ops = r.permute(&normed, [6, 1, 8, 20], [0, 3, 1, 2]).unwrap();
        let temporal_ops = r
            .permute_add_rows(&normed, [2, 3, 8, 20], [0, 3, 1, 2], &positions, 8..32)
            .unwrap();
        r.submit();
        assert_eq!(spatial.shape, vec![6, 20, 1, 8]);
        assert_eq!(temporal.shape, vec![2, 20, 3, 8]);
        let read = |t: &Tensor| t.read(&f.gpu).unwrap();
        assert_same_bits(precision, &read(&spatial), &read(&spatial_ops), &what);
        assert_same_bits(
            precision,
            &read(&temporal),
            &read(&temporal_ops),
            &format!("{what} rows"),
        );
        assert!(
            worst_difference(&read(&temporal), &read(&spatial)) > 0.1,
            "{what}: the layouts differ"
        );
    }
}

#[test]
fn the_projection_into_images_equals_the_linear_layer_then_the_permute_bit_for_bit() {
    // The attention layers' output projection put back into NCHW images with their
    // residual (spatial: with an action-table row per sample; temporal: 3 frames per
    // sequence) in one dispatch on CPU drivers must equal linear then add_permuted(_bias)
    // exactly, in every variant and precision: 2 sequences × 3 frames of 4×5 images,
    // 12 inputs and 8 channels, actions 2 and 0 of a 3-row table.
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let a = upload("a", &[6, 8, 4, 5], 0.31);
        let tokens = upload("tokens", &[2, 20, 3, 12], 0.53);
        let weight = upload("weight", &[8, 12], 0.29);
        let bias = upload("bias", &[8], 0.61);
        let table = upload("table", &[3, 8], 0.77);
        let what = format!("{precision:?} {kernels:?}");
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let ids = r.indices("ids", &[2, 0]).unwrap();
        let spatial_tokens = tokens.reshaped(&[6, 20, 12]);
        let spatial = r
            .linear_to_images(
                &spatial_tokens,
                (&weight, &bias),
                &a,
                1,
                Some((&table, &ids, 3)),
            )
            .unwrap();
        let temporal = r
            .linear_to_images(&tokens, (&weight, &bias), &a, 3, None)
            .unwrap();
        let out = r.linear(&spatial_tokens, &weight, &bias, false).unwrap();
        let spatial_ops = r
            .add_permuted_bias(
                &a,
                &out,
                [1, 6, 20, 8],
                [0, 1, 3, 2],
                Some((&table, &ids, 3)),
            )
            .unwrap();
        let temporal_ops = r
            .add_permuted(&a, &out, [2, 20, 3, 8], [0, 2, 3, 1])
            .unwrap();
        r.submit();
        assert_eq!(spatial.shape, vec![6, 8, 4, 5]);
        let read = |t: &Tensor| t.read(&f.gpu).unwrap();
        assert_same_bits(precision, &read(&spatial), &read(&spatial_ops), &what);
        assert_same_bits(
            precision,
            &read(&temporal),
            &read(&temporal_ops),
            &format!("{what} frames"),
        );
        assert!(
            worst_difference(&read(&temporal), &read(&spatial)) > 0.1,
            "{what}: the bias and the layouts differ"
        );
    }
}

#[test]
fn the_linear_layer_over_gathered_normed_rows_equals_the_separate_ops_bit_for_bit() {
    // The refiner's layer norm, projection and serialisation gather in one dispatch on
    // CPU drivers must equal gather, layer norm (the group norm with one group per row)
    // and linear (plus residual) exactly, in every variant and precision: 11 rows of 12
    // values (a partial 8-row tile) in a scrambled order, 8 outputs.
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let x = upload("x", &[11, 12], 0.37);
        let weight = upload("weight", &[8, 12], 0.29);
        let bias = upload("bias", &[8], 0.61);
        let gamma = upload("gamma", &[12], 0.7);
        let beta = upload("beta", &[12], 0.9);
        let residual = upload("residual", &[11, 8], 0.47);
        let what = format!("{precision:?} {kernels:?}");
        let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
        r.set_kernels(kernels);
        let order = r
            .indices("order", &[3, 7, 0, 10, 1, 9, 2, 8, 4, 6, 5])
            .unwrap();
        let layer = (&weight, &bias);
        let fused = r
            .linear_rows(
                &x,
                layer,
                Some((&gamma, &beta)),
                Some(&order),
                Some(&residual),
            )
            .unwrap();
        let plain = r.linear_rows(&x, layer, None, None, None).unwrap();
        let gathered = r.gather(&x, &order).unwrap();
        let normed = r
            .group_norm(&gathered.reshaped(&[11, 12, 1, 1]), &gamma, &beta, 1, false)
            .unwrap()
            .reshaped(&[11, 12]);
        let separate = r
            .linear_plus(&normed, &weight, &bias, false, Some(&residual))
            .unwrap();
        let plain_ops = r.linear(&x, &weight, &bias, false).unwrap();
        r.submit();
        let read = |t: &Tensor| t.read(&f.gpu).unwrap();
        assert_same_bits(precision, &read(&fused), &read(&separate), &what);
        assert_same_bits(
            precision,
            &read(&plain),
            &read(&plain_ops),
            &format!("{what} plain"),
        );
        assert!(
            worst_difference(&read(&fused), &read(&plain)) > 0.1,
            "{what}: the norm and the order changed the result"
        );
    }
}

#[test]
fn the_one_frame_temporal_attention_equals_the_projection_then_the_attention_bit_for_bit() {
    // A temporal layer's step for one new frame (each sequence projects its own q, k and
    // v, then attends over 3 cached rows and its own) in one dispatch on CPU drivers must
    // equal linear then attention_after exactly, in every variant and precision: 6
    // sequences, heads of 8 values (16 channels) and of 24 (48 channels, the wide path).
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        for c in [16, 48] {
            let tokens = upload("tokens", &[6, 1, c], 0.37);
            let weight = upload("weight", &[3 * c, c], 0.29);
            let bias = upload("bias", &[3 * c], 0.61);
            let cached = upload("cached", &[6, 3, 3 * c], 0.53);
            let params = AttentionParams {
                sequences: 6,
                heads: 2,
                queries: 1,
                keys: 4,
                channels: c as u32,
                q_stride: 3 * c as u32,
                q_offset: 0,
                kv_stride: 3 * c as u32,
                k_offset: c as u32,
                v_offset: 2 * c as u32,
                causal: 1,
                kv_share: 1,
                prefix_keys: 3,
                rows: 0,
                reserved1: 0,
                reserved2: 0,
            };
            let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
            r.set_kernels(kernels);
            let fused = r
                .temporal_next(&tokens, (&weight, &bias), &cached, params)
                .unwrap();
            let qkv = r.linear(&tokens, &weight, &bias, false).unwrap();
            let separate = r
                .attention_after(&qkv, Some(&cached), &qkv, params)
                .unwrap();
            r.submit();
            let what = format!("{precision:?} {kernels:?} {c} channels");
            assert_eq!(fused.shape, separate.shape, "{what}");
            let (x, y) = (fused.read(&f.gpu).unwrap(), separate.read(&f.gpu).unwrap());
            assert_same_bits(precision, &x, &y, &what);
        }
    }
}

#[test]
fn the_linear_layer_with_its_residual_equals_a_separate_add_bit_for_bit() {
    // The refiner's `x + proj(a)` and `x + fc2(silu(h))`: the residual in the linear
    // kernels' epilogue equals linear then add.wgsl, in every variant and precision, for
    // 7 rows (a partial 4-row tile) and 1 row (the one-output-per-invocation kernel).
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let upload = |name: &str, shape: &[usize], k: f32| f.wave(name, shape, k);
        let weight = upload("w", &[12, 8], 0.29);
        let bias = upload("b", &[12], 0.5);
        for rows in [7, 1] {
            let x = upload("x", &[rows, 8], 0.13);
            let res = upload("res", &[rows, 12], 0.71);
            let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
            r.set_kernels(kernels);
            let fused = r.linear_plus(&x, &weight, &bias, true, Some(&res)).unwrap();
            let plain = r.linear(&x, &weight, &bias, true).unwrap();
            let separate = r.add(&res, &plain, Broadcast::Trailing).unwrap();
            r.submit();
            let (a, b) = (fused.read(&f.gpu).unwrap(), separate.read(&f.gpu).unwrap());
            assert_same_bits(
                precision,
                &a,
                &b,
                &format!("{precision:?} {kernels:?} {rows} rows"),
            );
        }
    }
}

#[test]
fn the_upsampled_convolution_equals_upsample_then_convolution_bit_for_bit() {
    // Up (decoder and UNet): nearest ×2 upsampling fused into the 3×3 convolution's loads
    // must equal the two ops, in every variant and precision, on 5 × 6 images (12-pixel
    // rows: a partial 8-pixel tile) and 3 × 3 ones (6-pixel rows: the two-op fallback).
    for (precision, kernels) in variants() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        let bias = Tensor::upload(&f.gpu, "b", &[12], &wave(12, 0.5), precision).unwrap();
        let weights = unica::nn::ops::PackedConv::new(
            &f.gpu,
            "w",
            &wave(12 * 5 * 9, 0.23),
            [12, 5, 3],
            precision,
        )
        .unwrap();
        for (h, w) in [(5, 6), (3, 3)] {
            let x = Tensor::upload(
                &f.gpu,
                "x",
                &[2, 5, h, w],
                &wave(2 * 5 * h * w, 0.11),
                precision,
            )
            .unwrap();
            let mut r = Recorder::new(&f.gpu, &mut pipelines, precision);
            r.set_kernels(kernels);
            let fused = r.upsampled_conv3x3(&x, &weights, Some(&bias)).unwrap();
            let up = r.upsample_nearest2x(&x).unwrap();
            let separate = r.conv3x3(&up, &weights, Some(&bias), None, None).unwrap();
            r.submit();
            assert_eq!(fused.shape, vec![2, 12, 2 * h, 2 * w]);
            let (a, b) = (fused.read(&f.gpu).unwrap(), separate.read(&f.gpu).unwrap());
            assert_same_bits(
                precision,
                &a,
                &b,
                &format!("{precision:?} {kernels:?} {h}x{w}"),
            );
        }
    }
}

#[test]
fn the_action_table_gives_the_cross_attention_bit_for_bit() {
    // One token per sample: the UNet's table lookup must equal the layer exactly, in
    // every kernel variant and precision (and the layer itself matches PyTorch above).
    for (precision, kernels) in variants() {
        let mut f = Fixture::open("cross_attention", precision);
        let (x, ctx) = (f.input("io.in.x"), f.input("io.in.ctx"));
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let layer = CrossAttention::load(&w, 16, 32, 2).unwrap();
        let full = layer.forward(&mut r, &x, &ctx).unwrap();
        let table = layer.action_table(&mut r, &ctx.reshaped(&[2, 32])).unwrap();
        let ids = r.indices("ids", &[0, 1]).unwrap();
        let looked_up = r.add_action_bias(&x, &table, &ids, 1).unwrap();
        r.submit();
        let (a, b) = (full.read(&f.gpu).unwrap(), looked_up.read(&f.gpu).unwrap());
        assert_same_bits(precision, &a, &b, &format!("{precision:?} {kernels:?}"));
    }
}

#[test]
fn the_convolution_of_a_normed_input_equals_the_norm_then_the_convolution() {
    // A ResBlock's norm-SiLU-conv: for CPU drivers the norm is folded into conv3x3's
    // loads (its statistics computed per workgroup, the serial norm's sums in the same
    // order), which must give what group_norm then conv3x3 give. Two shapes: 16 channels
    // in 8 groups over 16² (the decoder's first level) with an addend and a residual, and
    // 12 channels in 4 groups over 10 × 12 (rows not a multiple of the 8-pixel tiles).
    type Shape = ([usize; 4], usize, usize);
    let shapes: [Shape; 2] = [([2, 16, 16, 16], 16, 8), ([2, 12, 10, 12], 12, 4)];
    for precision in precisions() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        for ([n, c, h, w], c_out, groups) in shapes {
            let x = f.wave("x", &[n, c, h, w], 0.37);
            let gamma = f.wave("gamma", &[c], 1.3);
            let beta = f.wave("beta", &[c], 0.7);
            let bias = f.wave("bias", &[c_out], 0.5);
            let extra = f.wave("extra", &[n, c_out], 0.9);
            let skip = f.wave("skip", &[n, c_out, h, w], 0.17);
            let weights = unica::nn::ops::PackedConv::new(
                &f.gpu,
                "w",
                &wave(c_out * c * 9, 0.23),
                [c_out, c, 3],
                precision,
            )
            .unwrap();
            let norm = unica::nn::ops::InputNorm {
                gamma: &gamma,
                beta: &beta,
                groups,
                silu: true,
            };
            let what = format!("{precision:?} {:?}", [n, c, h, w]);
            let fold = |r: &mut Recorder| {
                let (bias, extra, skip) = (Some(&bias), Some(&extra), Some(&skip));
                r.normed_conv3x3(&x, Some(norm), &weights, bias, extra, skip)
            };
            let mut plan = Recorder::capture(&f.gpu, &mut pipelines, precision);
            plan.set_kernels(Kernels::Cpu);
            assert!(plan.can_fold_norm([n, c, h, w], groups), "{what}");
            fold(&mut plan).unwrap();
            assert_eq!(plan.finish().dispatches(), 1, "{what}: one dispatch");
            let run = |kernels: Kernels, fused: bool, pipelines: &mut PipelineCache| {
                let mut r = Recorder::new(&f.gpu, pipelines, precision);
                r.set_kernels(kernels);
                let y = if fused {
                    fold(&mut r)
                } else {
                    let h = r.group_norm(&x, &gamma, &beta, groups, true).unwrap();
                    r.conv3x3(&h, &weights, Some(&bias), Some(&extra), Some(&skip))
                }
                .unwrap();
                r.submit();
                y.read(&f.gpu).unwrap()
            };
            let fused = run(Kernels::Cpu, true, &mut pipelines);
            let separate = run(Kernels::Cpu, false, &mut pipelines);
            assert_same_bits(precision, &fused, &separate, &what);
            // And the simple kernels (the PyTorch-tested reference), within the layer
            // tolerance.
            let simple = run(Kernels::Simple, false, &mut pipelines);
            let error = relative_error(&fused, &simple);
            println!("{what}: fused against simple {error:.1e}");
            assert!(error <= tolerances(precision).0, "{what}: {error}");
        }
    }
}

#[test]
fn the_decoder_records_its_norms_inside_its_convolutions_for_cpu_drivers() {
    // The tiny decoder (16² to 128²): the four norms of the 16² and 32² blocks go into
    // the convolutions after them; the 64² block's and the 128² output norm stay
    // dispatches of their own. the_vae_decoder_matches_pytorch checks the result.
    let f = Fixture::open("vae_decoder", Precision::F32);
    let z = f.input("io.in.z");
    let w = Weights::new(&f.file, &f.gpu, Precision::F32);
    let decoder = Decoder::load(&w, &VaeConfig::TINY).unwrap();
    let mut pipelines = PipelineCache::default();
    let mut counts = vec![];
    for kernels in [Kernels::Cpu, Kernels::Gpu] {
        let mut c = Recorder::capture(&f.gpu, &mut pipelines, Precision::F32);
        c.set_kernels(kernels);
        decoder.forward(&mut c, &z).unwrap();
        counts.push(c.finish().dispatches());
    }
    // 11 convolutions and 3 norms; the GPU kernels record all 7 norms.
    assert_eq!(counts, [14, 18]);
}
