//! WGSL kernels against the PyTorch trainer's fixtures (tests/fixtures/nn, written by
//! `python -m unica_train.fixtures`). Tolerance: f32 sums of up to 72 products of values
//! around 1 in another order differ by a few ulps; 1e-4 absolute on outputs of size ~5
//! (2e-5 relative) leaves room for that and catches any indexing error (errors of O(1)).

use std::path::Path;

use unica::gpu::kernel::PipelineCache;
use unica::gpu::{GpuContext, GpuOptions};
use unica::nn::{
    AttentionParams, Broadcast, Tensor, add, attention, conv2d, group_norm, linear, permute,
    timestep_embedding, upsample_nearest2x,
};
use unica::tensors::TensorFile;

const TOLERANCE: f32 = 1e-4;

fn fixture(name: &str) -> TensorFile {
    TensorFile::open(
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("tests/fixtures/nn/{name}.safetensors")),
    )
    .unwrap()
}

fn tensor(gpu: &GpuContext, file: &TensorFile, name: &str) -> Tensor {
    let (values, shape) = file.f32(name, &[None; 4][..rank(file, name)]).unwrap();
    Tensor::upload(gpu, name, &shape, &values).unwrap()
}

/// The rank of a stored tensor (tried from 1 to 4 dimensions).
fn rank(file: &TensorFile, name: &str) -> usize {
    (1..=4)
        .find(|&r| file.f32(name, &vec![None; r]).is_ok())
        .unwrap_or_else(|| panic!("{name}: no f32 tensor of rank 1-4"))
}

fn assert_close(got: &[f32], file: &TensorFile, name: &str) {
    let want = file.f32(name, &vec![None; rank(file, name)]).unwrap().0;
    assert_eq!(got.len(), want.len(), "{name}: length");
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= TOLERANCE, "{name}: max abs difference {worst}");
}

#[test]
fn stride_two_convolution_matches_pytorch() {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("down");
    let mut cache = PipelineCache::default();
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let (x, w, b) = (
        tensor(&gpu, &f, "io.in.x"),
        tensor(&gpu, &f, "conv.weight"),
        tensor(&gpu, &f, "conv.bias"),
    );
    let y = conv2d(&gpu, &mut cache, &mut encoder, &x, &w, Some(&b), 2, 1).unwrap();
    gpu.queue.submit([encoder.finish()]);
    assert_eq!(y.shape, [1, 12, 8, 8]);
    assert_close(&y.read(&gpu).unwrap(), &f, "io.out.y");
}

#[test]
fn nearest_upsampling_then_convolution_matches_pytorch() {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("up");
    let mut cache = PipelineCache::default();
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let (x, w, b) = (
        tensor(&gpu, &f, "io.in.x"),
        tensor(&gpu, &f, "conv.weight"),
        tensor(&gpu, &f, "conv.bias"),
    );
    let up = upsample_nearest2x(&gpu, &mut cache, &mut encoder, &x).unwrap();
    let y = conv2d(&gpu, &mut cache, &mut encoder, &up, &w, Some(&b), 1, 1).unwrap();
    gpu.queue.submit([encoder.finish()]);
    assert_eq!(y.shape, [1, 12, 16, 16]);
    assert_close(&y.read(&gpu).unwrap(), &f, "io.out.y");
}

#[test]
fn a_wrong_index_would_be_caught() {
    // The check above is only as good as its tolerance: a convolution without its bias
    // (one missing term) must fail it.
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("down");
    let mut cache = PipelineCache::default();
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let (x, w) = (tensor(&gpu, &f, "io.in.x"), tensor(&gpu, &f, "conv.weight"));
    let y = conv2d(&gpu, &mut cache, &mut encoder, &x, &w, None, 2, 1).unwrap();
    gpu.queue.submit([encoder.finish()]);
    let got = y.read(&gpu).unwrap();
    let want = f.f32("io.out.y", &[None; 4]).unwrap().0;
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst > 100.0 * TOLERANCE, "{worst}");
}

#[test]
fn a_residual_block_from_group_norm_silu_conv_linear_and_adds_matches_pytorch() {
    // ResBlock(8 -> 16, embedding 32): h = conv1(silu(norm1 x)) + emb(silu(e));
    // out = skip(x) + conv2(silu(norm2 h)); 8 groups in both norms (gcd(8, channels)).
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("resblock");
    let t = |name: &str| tensor(&gpu, &f, name);
    let mut cache = PipelineCache::default();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let x = t("io.in.x");
    let e = t("io.in.emb");
    let h = group_norm(
        &gpu,
        &mut cache,
        &mut enc,
        &x,
        &t("norm1.weight"),
        &t("norm1.bias"),
        8,
        true,
    )
    .unwrap();
    let h = conv2d(
        &gpu,
        &mut cache,
        &mut enc,
        &h,
        &t("conv1.weight"),
        Some(&t("conv1.bias")),
        1,
        1,
    )
    .unwrap();
    let projected = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &e,
        &t("emb.weight"),
        &t("emb.bias"),
        true,
    )
    .unwrap();
    let h = add(
        &gpu,
        &mut cache,
        &mut enc,
        &h,
        &projected,
        Broadcast::Leading,
    )
    .unwrap();
    let h = group_norm(
        &gpu,
        &mut cache,
        &mut enc,
        &h,
        &t("norm2.weight"),
        &t("norm2.bias"),
        8,
        true,
    )
    .unwrap();
    let h = conv2d(
        &gpu,
        &mut cache,
        &mut enc,
        &h,
        &t("conv2.weight"),
        Some(&t("conv2.bias")),
        1,
        1,
    )
    .unwrap();
    let skip = conv2d(
        &gpu,
        &mut cache,
        &mut enc,
        &x,
        &t("skip.weight"),
        Some(&t("skip.bias")),
        1,
        0,
    )
    .unwrap();
    let y = add(&gpu, &mut cache, &mut enc, &skip, &h, Broadcast::Leading).unwrap();
    gpu.queue.submit([enc.finish()]);
    assert_eq!(y.shape, [2, 16, 8, 8]);
    assert_close(&y.read(&gpu).unwrap(), &f, "io.out.y");
}

fn attention_params(
    sequences: usize,
    queries: usize,
    keys: usize,
    channels: usize,
    packed_kv: bool,
) -> AttentionParams {
    // Packed qkv rows [q | k | v] (self-attention) or q rows and [k | v] rows (cross).
    let (q_stride, kv_stride, k_offset) = if packed_kv {
        (3 * channels, 3 * channels, channels)
    } else {
        (channels, 2 * channels, 0)
    };
    AttentionParams {
        sequences: sequences as u32,
        heads: 2,
        queries: queries as u32,
        keys: keys as u32,
        channels: channels as u32,
        q_stride: q_stride as u32,
        q_offset: 0,
        kv_stride: kv_stride as u32,
        k_offset: k_offset as u32,
        v_offset: (k_offset + channels) as u32,
        causal: 0,
        reserved: 0,
    }
}

#[test]
fn spatial_self_attention_matches_pytorch() {
    // x [2, 16, 8, 8]: norm -> tokens [2, 64, 16] -> qkv -> attention -> out -> image + x.
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("spatial_attention");
    let t = |name: &str| tensor(&gpu, &f, name);
    let mut cache = PipelineCache::default();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let x = t("io.in.x");
    let normed = group_norm(
        &gpu,
        &mut cache,
        &mut enc,
        &x,
        &t("norm.weight"),
        &t("norm.bias"),
        8,
        false,
    )
    .unwrap();
    let tokens = permute(
        &gpu,
        &mut cache,
        &mut enc,
        &normed,
        [1, 2, 16, 64],
        [0, 1, 3, 2],
    )
    .unwrap();
    let qkv = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &tokens,
        &t("qkv.weight"),
        &t("qkv.bias"),
        false,
    )
    .unwrap();
    let mixed = attention(
        &gpu,
        &mut cache,
        &mut enc,
        &qkv,
        &qkv,
        attention_params(2, 64, 64, 16, true),
    )
    .unwrap();
    let projected = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &mixed,
        &t("out.weight"),
        &t("out.bias"),
        false,
    )
    .unwrap();
    let image = permute(
        &gpu,
        &mut cache,
        &mut enc,
        &projected,
        [1, 2, 64, 16],
        [0, 1, 3, 2],
    )
    .unwrap();
    let y = add(&gpu, &mut cache, &mut enc, &x, &image, Broadcast::Leading).unwrap();
    gpu.queue.submit([enc.finish()]);
    assert_close(&y.read(&gpu).unwrap(), &f, "io.out.y");
}

#[test]
fn cross_attention_to_the_action_token_matches_pytorch() {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("cross_attention");
    let t = |name: &str| tensor(&gpu, &f, name);
    let mut cache = PipelineCache::default();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let x = t("io.in.x");
    let normed = group_norm(
        &gpu,
        &mut cache,
        &mut enc,
        &x,
        &t("norm.weight"),
        &t("norm.bias"),
        8,
        false,
    )
    .unwrap();
    let tokens = permute(
        &gpu,
        &mut cache,
        &mut enc,
        &normed,
        [1, 2, 16, 64],
        [0, 1, 3, 2],
    )
    .unwrap();
    let q = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &tokens,
        &t("q.weight"),
        &t("q.bias"),
        false,
    )
    .unwrap();
    let kv = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &t("io.in.ctx"),
        &t("kv.weight"),
        &t("kv.bias"),
        false,
    )
    .unwrap();
    let mixed = attention(
        &gpu,
        &mut cache,
        &mut enc,
        &q,
        &kv,
        attention_params(2, 64, 1, 16, false),
    )
    .unwrap();
    let projected = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &mixed,
        &t("out.weight"),
        &t("out.bias"),
        false,
    )
    .unwrap();
    let image = permute(
        &gpu,
        &mut cache,
        &mut enc,
        &projected,
        [1, 2, 64, 16],
        [0, 1, 3, 2],
    )
    .unwrap();
    let y = add(&gpu, &mut cache, &mut enc, &x, &image, Broadcast::Leading).unwrap();
    gpu.queue.submit([enc.finish()]);
    assert_close(&y.read(&gpu).unwrap(), &f, "io.out.y");
}

#[test]
fn causal_temporal_attention_with_frame_positions_matches_pytorch() {
    // x [8, 16, 4, 4] = 2 groups x 4 frames: norm -> [b, hw, f, c] + position [f, c] ->
    // qkv -> causal attention over the 4 frames -> out -> back to [b*f, c, h, w] + x.
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("temporal_attention");
    let t = |name: &str| tensor(&gpu, &f, name);
    let mut cache = PipelineCache::default();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let x = t("io.in.x");
    let normed = group_norm(
        &gpu,
        &mut cache,
        &mut enc,
        &x,
        &t("norm.weight"),
        &t("norm.bias"),
        8,
        false,
    )
    .unwrap();
    let tokens = permute(
        &gpu,
        &mut cache,
        &mut enc,
        &normed,
        [2, 4, 16, 16],
        [0, 3, 1, 2],
    )
    .unwrap();
    let tokens = add(
        &gpu,
        &mut cache,
        &mut enc,
        &tokens,
        &t("position"),
        Broadcast::Trailing,
    )
    .unwrap();
    let qkv = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &tokens,
        &t("qkv.weight"),
        &t("qkv.bias"),
        false,
    )
    .unwrap();
    let params = AttentionParams {
        causal: 1,
        ..attention_params(2 * 16, 4, 4, 16, true)
    };
    let mixed = attention(&gpu, &mut cache, &mut enc, &qkv, &qkv, params).unwrap();
    let projected = linear(
        &gpu,
        &mut cache,
        &mut enc,
        &mixed,
        &t("out.weight"),
        &t("out.bias"),
        false,
    )
    .unwrap();
    let image = permute(
        &gpu,
        &mut cache,
        &mut enc,
        &projected,
        [2, 16, 4, 16],
        [0, 2, 3, 1],
    )
    .unwrap();
    let y = add(&gpu, &mut cache, &mut enc, &x, &image, Broadcast::Leading).unwrap();
    gpu.queue.submit([enc.finish()]);
    assert_close(&y.read(&gpu).unwrap(), &f, "io.out.y");
}

#[test]
fn the_timestep_embedding_matches_pytorch() {
    // Arguments reach 999 rad, whose f32 spacing is 6.1e-5; sin/cos of the same rounded
    // argument may then differ by that much plus a few ulps of the GPU's approximations.
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let f = fixture("timestep_embedding");
    let mut cache = PipelineCache::default();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    let y =
        timestep_embedding(&gpu, &mut cache, &mut enc, &tensor(&gpu, &f, "io.in.t"), 32).unwrap();
    gpu.queue.submit([enc.finish()]);
    let got = y.read(&gpu).unwrap();
    let want = f.f32("io.out.y", &[Some(4), Some(32)]).unwrap().0;
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 5e-4, "max abs difference {worst}");
}
