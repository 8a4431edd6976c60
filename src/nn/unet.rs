//! The action-conditioned UNet (train/unica_train/unet.py) over groups of latent frames.
//! Because temporal attention is causal, the clean context frames never see the target:
//! [`UNet::context`] runs them once per generated frame and keeps their temporal-attention
//! rows, and every denoising step then runs only the target frame ([`UNet::next`]).

use serde::Deserialize;

use super::Tensor;
use super::layers::{
    Conv, CrossAttention, Frames, Linear, Norm, ResBlock, SpatialAttention, TemporalAttention,
    UpBlock,
};
use super::ops::{Indices, Recorder};
use super::weights::{LoadError, Weights};
use crate::gpu::GpuError;
use crate::gpu::kernel::PipelineCache;

/// The UNet's shape, as the bundle manifest's `unet` entry.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct UNetConfig {
    pub latent: usize,
    /// Channels at 16×16 and 8×8.
    pub channels: [usize; 2],
    pub embed: usize,
    pub heads: usize,
    pub frames: usize,
    pub actions: usize,
}

impl UNetConfig {
    /// The trainer's default (`UNetConfig()` in train/unica_train/unet.py).
    pub const DEFAULT: Self = Self {
        latent: 4,
        channels: [64, 128],
        embed: 128,
        heads: 4,
        frames: 4,
        actions: 5,
    };

    /// The parity fixtures' tiny UNet (`TINY_UNET` in train/unica_train/fixtures.py).
    pub const TINY: Self = Self {
        channels: [16, 32],
        embed: 32,
        heads: 2,
        ..Self::DEFAULT
    };

    /// The action id of the unconditional (null) token used by classifier-free guidance.
    pub fn null_action(&self) -> usize {
        self.actions
    }
}

/// Spatial self-attention, cross-attention to the action, temporal attention.
/// The cross-attention is kept as its table over the action tokens (one row per action
/// and the null action): the same values in one dispatch instead of eight.
struct AttentionStack {
    spatial: SpatialAttention,
    cross: Tensor,
    temporal: TemporalAttention,
}

impl AttentionStack {
    fn load(
        w: &Weights,
        r: &mut Recorder,
        tokens: &Tensor,
        c: usize,
        cfg: &UNetConfig,
    ) -> Result<Self, LoadError> {
        let cross = CrossAttention::load(&w.at("cross"), c, cfg.embed, cfg.heads)?;
        Ok(Self {
            spatial: SpatialAttention::load(&w.at("spatial"), c, cfg.heads)?,
            cross: cross.action_table(r, tokens)?,
            temporal: TemporalAttention::load(&w.at("temporal"), c, cfg.frames, cfg.heads)?,
        })
    }
}

/// The action ids of a batch: host values (copied rows) or ids on the GPU (gathered by
/// a kernel, so a captured plan can take new actions by rewriting them).
#[derive(Clone, Copy)]
pub enum ActionIds<'a> {
    Host(&'a [usize]),
    Gpu(&'a Indices),
}

impl ActionIds<'_> {
    pub fn len(&self) -> usize {
        match self {
            Self::Host(ids) => ids.len(),
            Self::Gpu(ids) => ids.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl<'a> From<&'a [usize]> for ActionIds<'a> {
    fn from(ids: &'a [usize]) -> Self {
        Self::Host(ids)
    }
}

impl<'a, const N: usize> From<&'a [usize; N]> for ActionIds<'a> {
    fn from(ids: &'a [usize; N]) -> Self {
        Self::Host(ids)
    }
}

impl<'a> From<&'a Vec<usize>> for ActionIds<'a> {
    fn from(ids: &'a Vec<usize>) -> Self {
        Self::Host(ids)
    }
}

impl<'a> From<&'a Indices> for ActionIds<'a> {
    fn from(ids: &'a Indices) -> Self {
        Self::Gpu(ids)
    }
}

/// The context frames' temporal-attention rows of one generated frame, for every
/// denoising step of it, and the action ids they were made with.
pub struct ContextCache {
    rows: Vec<Tensor>,
    /// The batch's N action ids.
    ids: Indices,
}

/// How the batch's frames meet the temporal layers (see [`Frames`]).
enum Pass<'a> {
    Groups {
        count: usize,
        keep: Option<&'a mut Vec<Tensor>>,
    },
    Next {
        cache: &'a ContextCache,
        layer: usize,
    },
}

impl Pass<'_> {
    fn temporal(
        &mut self,
        r: &mut Recorder,
        layer: &TemporalAttention,
        x: &Tensor,
    ) -> Result<Tensor, GpuError> {
        match self {
            Pass::Groups { count, keep } => layer.forward(
                r,
                x,
                Frames::First {
                    count: *count,
                    keep: keep.as_deref_mut(),
                },
            ),
            Pass::Next {
                cache,
                layer: index,
            } => {
                let cached = &cache.rows[*index];
                *index += 1;
                layer.forward(r, x, Frames::Next { cached })
            }
        }
    }

    fn frames(&self) -> usize {
        match self {
            Pass::Groups { count, .. } => *count,
            Pass::Next { .. } => 1,
        }
    }
}

pub struct UNet {
    pub cfg: UNetConfig,
    time_in: Linear,
    time_out: Linear,
    conv_in: Conv,
    down0: ResBlock,
    temporal0: TemporalAttention,
    down: Conv,
    down1: ResBlock,
    attn1: AttentionStack,
    mid1: ResBlock,
    mid_attn: AttentionStack,
    mid2: ResBlock,
    up1: ResBlock,
    up_attn: AttentionStack,
    up: UpBlock,
    up0: ResBlock,
    temporal_up0: TemporalAttention,
    norm_out: Norm,
    conv_out: Conv,
}

impl UNet {
    /// Loads the weights; the cross-attention tables are computed on the GPU here (one
    /// submission).
    pub fn load(w: &Weights, cfg: &UNetConfig) -> Result<Self, LoadError> {
        let [c0, c1] = cfg.channels;
        let e = Some(cfg.embed);
        let action = w.tensor("action.weight", &[cfg.actions + 1, cfg.embed])?;
        let mut pipelines = PipelineCache::default();
        let mut r = Recorder::new(w.gpu(), &mut pipelines, w.precision());
        let unet = Self {
            time_in: Linear::load(&w.at("time_mlp.0"), cfg.embed, cfg.embed)?,
            time_out: Linear::load(&w.at("time_mlp.2"), cfg.embed, cfg.embed)?,
            conv_in: Conv::load(&w.at("conv_in"), cfg.latent, c0, 3, 1)?,
            down0: ResBlock::load(&w.at("down0"), c0, c0, e)?,
            temporal0: TemporalAttention::load(&w.at("temporal0"), c0, cfg.frames, cfg.heads)?,
            down: Conv::load(&w.at("down.conv"), c0, c0, 3, 2)?,
            down1: ResBlock::load(&w.at("down1"), c0, c1, e)?,
            attn1: AttentionStack::load(&w.at("attn1"), &mut r, &action, c1, cfg)?,
            mid1: ResBlock::load(&w.at("mid1"), c1, c1, e)?,
            mid_attn: AttentionStack::load(&w.at("mid_attn"), &mut r, &action, c1, cfg)?,
            mid2: ResBlock::load(&w.at("mid2"), c1, c1, e)?,
            up1: ResBlock::load(&w.at("up1"), 2 * c1, c1, e)?,
            up_attn: AttentionStack::load(&w.at("up_attn"), &mut r, &action, c1, cfg)?,
            up: UpBlock::load(&w.at("up"), c1, c1)?,
            up0: ResBlock::load(&w.at("up0"), c1 + c0, c0, e)?,
            temporal_up0: TemporalAttention::load(
                &w.at("temporal_up0"),
                c0,
                cfg.frames,
                cfg.heads,
            )?,
            norm_out: Norm::load(&w.at("norm_out"), c0)?,
            conv_out: Conv::load(&w.at("conv_out"), c0, cfg.latent, 3, 1)?,
            cfg: cfg.clone(),
        };
        r.submit();
        Ok(unet)
    }

    pub fn groups<'a>(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        timesteps: &[f32],
        actions: impl Into<ActionIds<'a>>,
    ) -> Result<Tensor, GpuError> {
        let pass = Pass::Groups {
            count: self.cfg.frames,
            keep: None,
        };
        let ids = self.ids(r, actions.into())?;
        let eps = self.run(r, x, timesteps, &ids, pass)?;
        Ok(eps.reshaped(&x.shape))
    }

    /// Runs the clean context frames `context` [N, F-1, C, H, W] (timestep 0) under
    /// `actions` and keeps what the target frame's steps need: every temporal layer's
    /// rows, and nothing after the last one's.
    pub fn context<'a>(
        &self,
        r: &mut Recorder,
        context: &Tensor,
        actions: impl Into<ActionIds<'a>>,
    ) -> Result<ContextCache, GpuError> {
        let count = self.cfg.frames - 1;
        assert_eq!(context.shape[1], count, "context frames");
        let mut rows = Vec::new();
        let pass = Pass::Groups {
            count,
            keep: Some(&mut rows),
        };
        let ids = self.ids(r, actions.into())?;
        let n = ids.len();
        self.run(r, context, &vec![0.0; n * count], &ids, pass)?;
        Ok(ContextCache { rows, ids })
    }

    /// The batch's action ids on the GPU (host ids are uploaded).
    fn ids(&self, r: &mut Recorder, actions: ActionIds) -> Result<Indices, GpuError> {
        match actions {
            ActionIds::Host(ids) => {
                let ids: Vec<u32> = ids.iter().map(|&a| a as u32).collect();
                r.indices("unet.actions", &ids)
            }
            ActionIds::Gpu(ids) => Ok(ids.clone()),
        }
    }

    /// The noise prediction of the frame after the context: `x` [N, C, H, W] at
    /// `timestep`, with the actions the cache was made with.
    pub fn next(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        timestep: f32,
        cache: &ContextCache,
    ) -> Result<Tensor, GpuError> {
        let pass = Pass::Next { cache, layer: 0 };
        let n = cache.ids.len();
        self.run(r, x, &vec![timestep; n], &cache.ids, pass)
    }

    fn run(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        timesteps: &[f32],
        ids: &Indices,
        mut pass: Pass,
    ) -> Result<Tensor, GpuError> {
        let (c, h, w) = (
            self.cfg.latent,
            x.shape[x.shape.len() - 2],
            x.shape[x.shape.len() - 1],
        );
        let frames = timesteps.len();
        assert_eq!(
            x.len(),
            frames * c * h * w,
            "latents {:?} for {frames} frames",
            x.shape
        );
        assert_eq!(frames, ids.len() * pass.frames(), "timesteps per frame");
        let x = x.reshaped(&[frames, c, h, w]);
        let [e0, e1, e2, e3, e4, e5] = self.embeddings(r, timesteps)?;

        let h0 = self.conv_in.forward(r, &x)?;
        let h0 = self.down0.forward_projected(r, &h0, e0.as_ref())?;
        let h0 = pass.temporal(r, &self.temporal0, &h0)?;
        let h1 = self.down.forward(r, &h0)?;
        let h1 = self.down1.forward_projected(r, &h1, e1.as_ref())?;
        let h1 = self.attend(r, &self.attn1, &h1, ids, &mut pass)?;
        let m = self.mid1.forward_projected(r, &h1, e2.as_ref())?;
        let m = self.attend(r, &self.mid_attn, &m, ids, &mut pass)?;
        let m = self.mid2.forward_projected(r, &m, e3.as_ref())?;
        let u1 = self.up1.forward_concat(r, &m, &h1, e4.as_ref())?;
        let u1 = self.attend(r, &self.up_attn, &u1, ids, &mut pass)?;
        let u0 = self.up.forward(r, &u1)?;
        let u0 = self.up0.forward_concat(r, &u0, &h0, e5.as_ref())?;
        if let Pass::Groups {
            count,
            keep: Some(keep),
        } = &mut pass
        {
            // The context pass: what the target frame's steps read of the last temporal
            // layer is its keys and values; the context frames' own outputs are unused.
            self.temporal_up0.keep_rows(r, &u0, *count, keep)?;
            return Ok(u0);
        }
        let u0 = pass.temporal(r, &self.temporal_up0, &u0)?;
        let out = self.norm_out.forward(r, &u0, true)?;
        self.conv_out.forward(r, &out)
    }

    /// Each ResBlock's projection of the timestep embedding, [frames, C] per block in
    /// order. They depend only on the timesteps, which a recording fixes (a captured
    /// plan's steps have theirs), so they are computed here, once, in their own
    /// submission, with the recorder's kernel variant: a generated frame does not repeat
    /// them.
    fn embeddings(&self, r: &Recorder, timesteps: &[f32]) -> Result<[Option<Tensor>; 6], GpuError> {
        let mut pipelines = PipelineCache::default();
        let mut s = Recorder::new(r.gpu(), &mut pipelines, r.precision());
        s.set_kernels(r.kernels());
        let t = s.upload("unet.timesteps", &[timesteps.len()], timesteps)?;
        let te = s.timestep_embedding(&t, self.cfg.embed)?;
        let te = self.time_in.forward(&mut s, &te, false)?;
        let emb = self.time_out.forward(&mut s, &te, true)?; // [frames, E]
        let blocks = [
            &self.down0,
            &self.down1,
            &self.mid1,
            &self.mid2,
            &self.up1,
            &self.up0,
        ];
        let mut projected = [None, None, None, None, None, None];
        for (slot, block) in projected.iter_mut().zip(blocks) {
            *slot = block.project(&mut s, &emb)?;
        }
        s.submit();
        Ok(projected)
    }

    fn attend(
        &self,
        r: &mut Recorder,
        stack: &AttentionStack,
        x: &Tensor,
        ids: &Indices,
        pass: &mut Pass,
    ) -> Result<Tensor, GpuError> {
        let h = stack
            .spatial
            .forward_with_bias(r, x, Some((&stack.cross, ids, pass.frames())))?;
        pass.temporal(r, &stack.temporal, &h)
    }
}
