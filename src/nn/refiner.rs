//! The splat refiner's network (docs/architecture.md, Appearance) on the GPU: a small
//! point transformer (PTv3-style) that predicts residuals per base splat. Its inputs, the
//! serialisation orders and pooling groups come from the splat stage (`splat::frame` on
//! the GPU, `splat::serialise` its host reference), and the engine passes them on; the
//! network — linear layers, layer norms, attention inside patches of each order, strided
//! pooling and unpooling — runs as WGSL kernels, pinned to
//! train/unica_train/refiner/model.py by parity tests.

use serde::Deserialize;

use super::layers::Linear;
use super::ops::{AttentionParams, Recorder};
use super::{LoadError, Tensor, Weights};
use crate::gpu::{GpuError, Indices, Permutation};

#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct RefinerConfig {
    pub channels: [usize; 2],
    pub depths: [usize; 2],
    pub heads: [usize; 2],
    pub decoder_depth: usize,
    pub patch: usize,
    pub stride: usize,
    /// Bound of the mean offsets in normalised units.
    pub mean_bound: f32,
    /// Rows of the learned residual per map pixel added to the network's output (the
    /// map's foreground pixel count; 0, the default: none).
    #[serde(default)]
    pub pixel_residuals: usize,
}

impl RefinerConfig {
    /// A config the engine can run, or what is wrong with it.
    pub fn check(&self) -> Result<(), String> {
        for (c, h) in self.channels.iter().zip(&self.heads) {
            if *h == 0 || c % h != 0 || c / h > super::ops::MAX_HEAD_SIZE {
                return Err(format!(
                    "refiner: {c} channels in {h} heads (each head at most {} channels)",
                    super::ops::MAX_HEAD_SIZE
                ));
            }
        }
        if self.patch == 0 || self.stride == 0 {
            return Err("refiner: patch and stride must be positive".into());
        }
        Ok(())
    }
}

/// A layer norm over the last axis: the group-norm kernel with one group per row.
struct LayerNorm {
    gamma: Tensor,
    beta: Tensor,
}

impl LayerNorm {
    fn load(w: &Weights, channels: usize) -> Result<Self, LoadError> {
        Ok(Self {
            gamma: w.tensor("weight", &[channels])?,
            beta: w.tensor("bias", &[channels])?,
        })
    }

    /// (gamma, beta), as [`Recorder::linear_rows`] takes them.
    fn parts(&self) -> (&Tensor, &Tensor) {
        (&self.gamma, &self.beta)
    }

    fn forward(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        let [rows, channels] = x.shape[..] else {
            panic!("layer norm of {:?}", x.shape)
        };
        let y = r.group_norm(
            &x.reshaped(&[rows, channels, 1, 1]),
            &self.gamma,
            &self.beta,
            1,
            false,
        )?;
        Ok(y.reshaped(&[rows, channels]))
    }
}

/// Attention inside patches along an order, then an MLP; both residual.
struct Block {
    heads: usize,
    norm1: LayerNorm,
    qkv: Linear,
    proj: Linear,
    norm2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
}

impl Block {
    fn load(w: &Weights, channels: usize, heads: usize) -> Result<Self, LoadError> {
        Ok(Self {
            heads,
            norm1: LayerNorm::load(&w.at("norm1"), channels)?,
            qkv: Linear::load(&w.at("qkv"), channels, 3 * channels)?,
            proj: Linear::load(&w.at("proj"), channels, channels)?,
            norm2: LayerNorm::load(&w.at("norm2"), channels)?,
            fc1: Linear::load(&w.at("fc1"), channels, 2 * channels)?,
            fc2: Linear::load(&w.at("fc2"), 2 * channels, channels)?,
        })
    }

    fn forward(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        order: &Permutation,
        patch: usize,
    ) -> Result<Tensor, GpuError> {
        // The norms and the serialisation gathers ride in the projections' loads (the
        // rows are normed and projected one by one, so gathering the input rows equals
        // gathering the projected ones), the residual adds in their epilogues.
        let norm1 = Some(self.norm1.parts());
        let sorted = r.linear_rows(x, self.qkv.parts(), norm1, Some(&order.sort), None)?;
        let attended = patch_attention(r, &sorted, self.heads, patch)?;
        let unsort = Some(&order.unsort);
        let x = r.linear_rows(&attended, self.proj.parts(), None, unsort, Some(x))?;
        let h = r.linear_rows(&x, self.fc1.parts(), Some(self.norm2.parts()), None, None)?;
        self.fc2.forward_plus(r, &h, true, &x)
    }
}

/// Attention within consecutive patches of `patch` rows of packed qkv rows [n, 3C] (the
/// last patch is shorter), one dispatch: [n, C].
fn patch_attention(
    r: &mut Recorder,
    qkv: &Tensor,
    heads: usize,
    patch: usize,
) -> Result<Tensor, GpuError> {
    let [n, c3] = qkv.shape[..] else {
        panic!("packed qkv of {:?}", qkv.shape)
    };
    assert!(n > 0, "patch attention over no points");
    let c = c3 / 3;
    let params = AttentionParams {
        sequences: n.div_ceil(patch) as u32,
        heads: heads as u32,
        queries: patch as u32,
        keys: patch as u32,
        channels: c as u32,
        q_stride: c3 as u32,
        q_offset: 0,
        kv_stride: c3 as u32,
        k_offset: c as u32,
        v_offset: (2 * c) as u32,
        causal: 0,
        kv_share: 1,
        prefix_keys: 0,
        rows: n as u32,
        reserved1: 0,
        reserved2: 0,
    };
    r.attention(qkv, qkv, params)
}

pub struct Refiner {
    pub cfg: RefinerConfig,
    embed: Linear,
    encoder: Vec<Block>,
    down: Linear,
    middle: Vec<Block>,
    up: Linear,
    decoder: Vec<Block>,
    norm: LayerNorm,
    head: Linear,
    /// [pixel_residuals, residuals]: each map pixel's own residuals.
    pixel: Option<Tensor>,
}

impl Refiner {
    /// Loads the weights under `w` (the trainer's state-dict names) of a refiner that
    /// reads `features` values per point and writes `residuals` (the splat stage's
    /// `splat::frame::FEATURES` and `splat::base::RESIDUALS`).
    pub fn load(
        w: &Weights,
        cfg: &RefinerConfig,
        features: usize,
        residuals: usize,
    ) -> Result<Self, LoadError> {
        let [c0, c1] = cfg.channels;
        let blocks = |prefix: &str, count: usize, channels: usize, heads: usize| {
            (0..count)
                .map(|i| Block::load(&w.at(&format!("{prefix}.{i}")), channels, heads))
                .collect::<Result<Vec<_>, _>>()
        };
        Ok(Self {
            embed: Linear::load(&w.at("embed"), features, c0)?,
            encoder: blocks("encoder", cfg.depths[0], c0, cfg.heads[0])?,
            down: Linear::load(&w.at("down"), c0, c1)?,
            middle: blocks("middle", cfg.depths[1], c1, cfg.heads[1])?,
            up: Linear::load(&w.at("up"), c1, c0)?,
            decoder: blocks("decoder", cfg.decoder_depth, c0, cfg.heads[0])?,
            norm: LayerNorm::load(&w.at("norm"), c0)?,
            head: Linear::load(&w.at("head"), c0, residuals)?,
            pixel: match cfg.pixel_residuals {
                0 => None,
                rows => Some(w.tensor("pixel", &[rows, residuals])?),
            },
            cfg: cfg.clone(),
        })
    }

    /// Records the residuals [N, residuals] of `features` [N, features] along the points'
    /// four serialisation orders `fine`, the pooled points' `coarse` and each point's
    /// pooled group `groups` (made by the splat stage: `splat::serialise`).
    pub fn forward(
        &self,
        r: &mut Recorder,
        features: &Tensor,
        fine: &[Permutation],
        coarse: &[Permutation],
        groups: &Indices,
    ) -> Result<Tensor, GpuError> {
        let stride = self.cfg.stride;
        let patch = self.cfg.patch;
        let mut block = 0;
        let mut x = self.embed.forward(r, features, false)?;
        for b in &self.encoder {
            x = b.forward(r, &x, &fine[block % 4], patch)?;
            block += 1;
        }
        let skip = x;
        let sorted = r.gather(&skip, &fine[0].sort)?;
        let pooled = r.segment_mean(&sorted, stride)?;
        let mut y = self.down.forward(r, &pooled, false)?;
        for b in &self.middle {
            y = b.forward(r, &y, &coarse[block % 4], patch)?;
            block += 1;
        }
        let up = self.up.forward(r, &y, false)?;
        let unpooled = r.gather(&up, groups)?;
        let mut x = r.add(&skip, &unpooled, super::Broadcast::Trailing)?;
        for b in &self.decoder {
            x = b.forward(r, &x, &fine[block % 4], patch)?;
            block += 1;
        }
        let normed = self.norm.forward(r, &x)?;
        match &self.pixel {
            None => self.head.forward(r, &normed, false),
            // Each point's own residuals ride in the head's epilogue (no extra dispatch).
            Some(pixel) => {
                assert_eq!(
                    pixel.shape[0], normed.shape[0],
                    "the refiner's pixel residuals against its points"
                );
                self.head.forward_plus(r, &normed, false, pixel)
            }
        }
    }
}
