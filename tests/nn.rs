//! WGSL kernels against the PyTorch trainer's fixtures (tests/fixtures/nn, written by
//! `python -m unica_train.fixtures`). Tolerance: f32 sums of up to 72 products of values
//! around 1 in another order differ by a few ulps; 1e-4 absolute on outputs of size ~5
//! (2e-5 relative) leaves room for that and catches any indexing error (errors of O(1)).

use std::path::Path;

use unica::gpu::kernel::PipelineCache;
use unica::gpu::{GpuContext, GpuOptions};
use unica::nn::{self, AttentionParams, Broadcast, Tensor};
use unica::tensors::TensorFile;

const TOLERANCE: f32 = 1e-4;
/// Every group norm of the fixtures has 8 groups (gcd(8, channels)).
const GROUPS: usize = 8;

/// One fixture, a device and one command encoder: kernels are recorded in order, reading
/// the fixture's tensors by name, and `result` runs them and compares with PyTorch.
struct Fixture {
    file: TensorFile,
    gpu: GpuContext,
    cache: PipelineCache,
    encoder: wgpu::CommandEncoder,
}

impl Fixture {
    fn open(name: &str) -> Self {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("tests/fixtures/nn/{name}.safetensors"));
        let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
        Self {
            file: TensorFile::open(&path).unwrap(),
            encoder: gpu.device.create_command_encoder(&Default::default()),
            gpu,
            cache: PipelineCache::default(),
        }
    }

    /// The rank of a stored tensor (tried from 1 to 4 dimensions).
    fn rank(&self, name: &str) -> usize {
        (1..=4)
            .find(|&r| self.file.f32(name, &vec![None; r]).is_ok())
            .unwrap_or_else(|| panic!("{name}: no f32 tensor of rank 1-4"))
    }

    fn t(&self, name: &str) -> Tensor {
        let (values, shape) = self.file.f32(name, &vec![None; self.rank(name)]).unwrap();
        Tensor::upload(&self.gpu, name, &shape, &values).unwrap()
    }

    fn conv(
        &mut self,
        x: &Tensor,
        layer: &str,
        with_bias: bool,
        stride: usize,
        pad: usize,
    ) -> Tensor {
        let (w, b) = (
            self.t(&format!("{layer}.weight")),
            self.t(&format!("{layer}.bias")),
        );
        nn::conv2d(
            &self.gpu,
            &mut self.cache,
            &mut self.encoder,
            x,
            &w,
            with_bias.then_some(&b),
            stride,
            pad,
        )
        .unwrap()
    }

    fn norm(&mut self, x: &Tensor, layer: &str, silu: bool) -> Tensor {
        let (g, b) = (
            self.t(&format!("{layer}.weight")),
            self.t(&format!("{layer}.bias")),
        );
        nn::group_norm(
            &self.gpu,
            &mut self.cache,
            &mut self.encoder,
            x,
            &g,
            &b,
            GROUPS,
            silu,
        )
        .unwrap()
    }

    fn linear(&mut self, x: &Tensor, layer: &str, input_silu: bool) -> Tensor {
        let (w, b) = (
            self.t(&format!("{layer}.weight")),
            self.t(&format!("{layer}.bias")),
        );
        nn::linear(
            &self.gpu,
            &mut self.cache,
            &mut self.encoder,
            x,
            &w,
            &b,
            input_silu,
        )
        .unwrap()
    }

    fn add(&mut self, a: &Tensor, b: &Tensor, broadcast: Broadcast) -> Tensor {
        nn::add(
            &self.gpu,
            &mut self.cache,
            &mut self.encoder,
            a,
            b,
            broadcast,
        )
        .unwrap()
    }

    fn permute(&mut self, x: &Tensor, shape: [usize; 4], perm: [usize; 4]) -> Tensor {
        nn::permute(
            &self.gpu,
            &mut self.cache,
            &mut self.encoder,
            x,
            shape,
            perm,
        )
        .unwrap()
    }

    fn attention(&mut self, q: &Tensor, kv: &Tensor, params: AttentionParams) -> Tensor {
        nn::attention(&self.gpu, &mut self.cache, &mut self.encoder, q, kv, params).unwrap()
    }

    /// Runs what was recorded and returns the largest difference of `y` from the
    /// fixture's `io.out.y`.
    fn worst_difference(self, y: &Tensor) -> f32 {
        self.gpu.queue.submit([self.encoder.finish()]);
        let got = y.read(&self.gpu).unwrap();
        let want = self
            .file
            .f32("io.out.y", &vec![None; y.shape.len()])
            .unwrap()
            .0;
        assert_eq!(got.len(), want.len(), "io.out.y: length");
        got.iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max)
    }

    fn assert_matches(self, y: &Tensor) {
        let worst = self.worst_difference(y);
        assert!(worst <= TOLERANCE, "io.out.y: max abs difference {worst}");
    }
}

#[test]
fn stride_two_convolution_matches_pytorch() {
    let mut f = Fixture::open("down");
    let y = f.conv(&f.t("io.in.x"), "conv", true, 2, 1);
    assert_eq!(y.shape, [1, 12, 8, 8]);
    f.assert_matches(&y);
}

#[test]
fn nearest_upsampling_then_convolution_matches_pytorch() {
    let mut f = Fixture::open("up");
    let x = f.t("io.in.x");
    let up = nn::upsample_nearest2x(&f.gpu, &mut f.cache, &mut f.encoder, &x).unwrap();
    let y = f.conv(&up, "conv", true, 1, 1);
    assert_eq!(y.shape, [1, 12, 16, 16]);
    f.assert_matches(&y);
}

#[test]
fn a_wrong_index_would_be_caught() {
    // The check above is only as good as its tolerance: a convolution without its bias
    // (one missing term) must fail it.
    let mut f = Fixture::open("down");
    let y = f.conv(&f.t("io.in.x"), "conv", false, 2, 1);
    let worst = f.worst_difference(&y);
    assert!(worst > 100.0 * TOLERANCE, "{worst}");
}

#[test]
fn a_residual_block_from_group_norm_silu_conv_linear_and_adds_matches_pytorch() {
    // ResBlock(8 -> 16, embedding 32): h = conv1(silu(norm1 x)) + emb(silu(e));
    // out = skip(x) + conv2(silu(norm2 h)).
    let mut f = Fixture::open("resblock");
    let (x, e) = (f.t("io.in.x"), f.t("io.in.emb"));
    let h = f.norm(&x, "norm1", true);
    let h = f.conv(&h, "conv1", true, 1, 1);
    let projected = f.linear(&e, "emb", true);
    let h = f.add(&h, &projected, Broadcast::Leading);
    let h = f.norm(&h, "norm2", true);
    let h = f.conv(&h, "conv2", true, 1, 1);
    let skip = f.conv(&x, "skip", true, 1, 0);
    let y = f.add(&skip, &h, Broadcast::Leading);
    assert_eq!(y.shape, [2, 16, 8, 8]);
    f.assert_matches(&y);
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

/// The shape of the spatial and cross layers on x [2, 16, 8, 8]: norm -> tokens
/// [2, 64, 16] -> `mix` (the attention proper) -> out projection -> image + x.
fn image_attention(f: &mut Fixture, mix: impl FnOnce(&mut Fixture, &Tensor) -> Tensor) -> Tensor {
    let x = f.t("io.in.x");
    let normed = f.norm(&x, "norm", false);
    let tokens = f.permute(&normed, [1, 2, 16, 64], [0, 1, 3, 2]);
    let mixed = mix(f, &tokens);
    let projected = f.linear(&mixed, "out", false);
    let image = f.permute(&projected, [1, 2, 64, 16], [0, 1, 3, 2]);
    f.add(&x, &image, Broadcast::Leading)
}

#[test]
fn spatial_self_attention_matches_pytorch() {
    let mut f = Fixture::open("spatial_attention");
    let y = image_attention(&mut f, |f, tokens| {
        let qkv = f.linear(tokens, "qkv", false);
        f.attention(&qkv, &qkv, attention_params(2, 64, 64, 16, true))
    });
    f.assert_matches(&y);
}

#[test]
fn cross_attention_to_the_action_token_matches_pytorch() {
    let mut f = Fixture::open("cross_attention");
    let y = image_attention(&mut f, |f, tokens| {
        let q = f.linear(tokens, "q", false);
        let kv = f.linear(&f.t("io.in.ctx"), "kv", false);
        f.attention(&q, &kv, attention_params(2, 64, 1, 16, false))
    });
    f.assert_matches(&y);
}

#[test]
fn causal_temporal_attention_with_frame_positions_matches_pytorch() {
    // x [8, 16, 4, 4] = 2 groups x 4 frames: norm -> [b, hw, f, c] + position [f, c] ->
    // qkv -> causal attention over the 4 frames -> out -> back to [b*f, c, h, w] + x.
    let mut f = Fixture::open("temporal_attention");
    let x = f.t("io.in.x");
    let normed = f.norm(&x, "norm", false);
    let tokens = f.permute(&normed, [2, 4, 16, 16], [0, 3, 1, 2]);
    let tokens = f.add(&tokens, &f.t("position"), Broadcast::Trailing);
    let qkv = f.linear(&tokens, "qkv", false);
    let params = AttentionParams {
        causal: 1,
        ..attention_params(2 * 16, 4, 4, 16, true)
    };
    let mixed = f.attention(&qkv, &qkv, params);
    let projected = f.linear(&mixed, "out", false);
    let image = f.permute(&projected, [2, 16, 4, 16], [0, 2, 3, 1]);
    let y = f.add(&x, &image, Broadcast::Leading);
    f.assert_matches(&y);
}

#[test]
fn the_timestep_embedding_matches_pytorch() {
    // Arguments reach 999 rad, whose f32 spacing is 6.1e-5; sin/cos of the same rounded
    // argument may then differ by that much plus a few ulps of the GPU's approximations.
    let mut f = Fixture::open("timestep_embedding");
    let t = f.t("io.in.t");
    let y = nn::timestep_embedding(&f.gpu, &mut f.cache, &mut f.encoder, &t, 32).unwrap();
    assert_eq!(y.shape, [4, 32]);
    let worst = f.worst_difference(&y);
    assert!(worst <= 5e-4, "max abs difference {worst}");
}
