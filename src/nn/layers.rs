//! The trainer's building blocks (train/unica_train/layers.py) on the GPU: convolutions,
//! group norms, linear layers, residual blocks and the three attention kinds, loaded by
//! their PyTorch names and recorded with a [`Recorder`].

use super::Tensor;
use super::ops::{AttentionParams, Broadcast, Indices, InputNorm, PackedConv, Recorder};
use super::weights::{LoadError, Weights};
use crate::gpu::GpuError;

/// A square convolution with bias and "same" padding (k / 2). 3×3 (stride 1 or 2) and
/// 1×1 stride-1 ones keep their weights in both layouts and record the register-tiled
/// `conv3x3`, `conv3x3_s2_cpu` and `conv1x1` kernels.
pub struct Conv {
    weights: ConvWeights,
    bias: Tensor,
    stride: usize,
}

enum ConvWeights {
    Plain(Tensor),
    Packed(PackedConv),
}

impl Conv {
    pub fn load(
        w: &Weights,
        c_in: usize,
        c_out: usize,
        kernel: usize,
        stride: usize,
    ) -> Result<Self, LoadError> {
        let weights = if (kernel == 3 && stride <= 2) || (kernel == 1 && stride == 1) {
            ConvWeights::Packed(w.packed_conv("weight", [c_out, c_in, kernel], c_out)?)
        } else {
            ConvWeights::Plain(w.tensor("weight", &[c_out, c_in, kernel, kernel])?)
        };
        Ok(Self {
            weights,
            bias: w.tensor("bias", &[c_out])?,
            stride,
        })
    }

    /// Only the first `keep` output channels of a 3×3 convolution with `c_out` of them.
    pub fn load_first(
        w: &Weights,
        c_in: usize,
        c_out: usize,
        keep: usize,
    ) -> Result<Self, LoadError> {
        Ok(Self {
            weights: ConvWeights::Packed(w.packed_conv("weight", [c_out, c_in, 3], keep)?),
            bias: w.rows("bias", &[c_out], keep)?,
            stride: 1,
        })
    }

    pub fn forward(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        self.forward_plus(r, x, None)
    }

    /// The convolution, plus `extra` [N, c_out] on every pixel of image n's channels
    /// (fused into the 3×3 kernel; a separate add otherwise).
    pub fn forward_plus(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        extra: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        self.forward_with(r, x, extra, None)
    }

    /// [`Conv::forward_with`] of `norm` (then SiLU) applied to `x`: one dispatch where
    /// [`Recorder::normed_conv3x3`] folds the norm into a 3×3 convolution.
    pub fn forward_normed(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        norm: &Norm,
        extra: Option<&Tensor>,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        match &self.weights {
            ConvWeights::Packed(weights) if weights.kernel == 3 && self.stride == 1 => {
                let bias = Some(&self.bias);
                r.normed_conv3x3(x, Some(norm.input(true)), weights, bias, extra, residual)
            }
            _ => {
                let h = norm.forward(r, x, true)?;
                self.forward_with(r, &h, extra, residual)
            }
        }
    }

    /// [`Conv::forward_plus`], then `residual + ` the result (`residual` of the output's
    /// shape; fused into the 3×3 kernel, a separate add otherwise).
    pub fn forward_with(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        extra: Option<&Tensor>,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let y = match &self.weights {
            ConvWeights::Packed(weights) if self.stride == 2 => {
                r.conv3x3_stride2(x, weights, Some(&self.bias))?
            }
            ConvWeights::Packed(weights) if weights.kernel == 3 => {
                return r.conv3x3(x, weights, Some(&self.bias), extra, residual);
            }
            ConvWeights::Packed(weights) => r.conv1x1(x, weights, Some(&self.bias))?,
            ConvWeights::Plain(weight) => {
                let pad = weight.shape[2] / 2;
                r.conv2d(x, weight, Some(&self.bias), self.stride, pad)?
            }
        };
        let y = match extra {
            Some(e) => r.add(&y, e, Broadcast::Leading)?,
            None => y,
        };
        match residual {
            Some(skip) => r.add(skip, &y, Broadcast::Leading),
            None => Ok(y),
        }
    }
}

/// Group norm with gcd(8, channels) groups, as the trainer's `norm`.
pub struct Norm {
    gamma: Tensor,
    beta: Tensor,
    groups: usize,
}

impl Norm {
    pub fn load(w: &Weights, channels: usize) -> Result<Self, LoadError> {
        Ok(Self {
            gamma: w.tensor("weight", &[channels])?,
            beta: w.tensor("bias", &[channels])?,
            groups: gcd(8, channels),
        })
    }

    pub fn forward(&self, r: &mut Recorder, x: &Tensor, silu: bool) -> Result<Tensor, GpuError> {
        r.group_norm(x, &self.gamma, &self.beta, self.groups, silu)
    }

    /// This norm (then SiLU with `silu`) as the input norm of a convolution.
    pub fn input(&self, silu: bool) -> InputNorm<'_> {
        InputNorm {
            gamma: &self.gamma,
            beta: &self.beta,
            groups: self.groups,
            silu,
        }
    }

    /// (gamma, beta, groups), as [`Recorder::group_norm_tokens`] takes them.
    pub fn parts(&self) -> (&Tensor, &Tensor, usize) {
        (&self.gamma, &self.beta, self.groups)
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

pub struct Linear {
    weight: Tensor,
    bias: Tensor,
}

impl Linear {
    pub fn load(w: &Weights, inputs: usize, outputs: usize) -> Result<Self, LoadError> {
        Ok(Self {
            weight: w.tensor("weight", &[outputs, inputs])?,
            bias: w.tensor("bias", &[outputs])?,
        })
    }

    pub fn forward(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        input_silu: bool,
    ) -> Result<Tensor, GpuError> {
        r.linear(x, &self.weight, &self.bias, input_silu)
    }

    /// (weight, bias), as [`Recorder::linear_to_images`] takes them.
    pub fn parts(&self) -> (&Tensor, &Tensor) {
        (&self.weight, &self.bias)
    }

    /// `residual + forward(x)` in one dispatch ([`Recorder::linear_plus`]).
    pub fn forward_plus(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        input_silu: bool,
        residual: &Tensor,
    ) -> Result<Tensor, GpuError> {
        r.linear_plus(x, &self.weight, &self.bias, input_silu, Some(residual))
    }
}

/// GroupNorm-SiLU-Conv twice, an optional per-sample embedding added in between, and a
/// 1×1 skip when the channel count changes.
pub struct ResBlock {
    norm1: Norm,
    conv1: Conv,
    emb: Option<Linear>,
    norm2: Norm,
    conv2: Conv,
    skip: Option<Conv>,
}

impl ResBlock {
    pub fn load(
        w: &Weights,
        c_in: usize,
        c_out: usize,
        emb: Option<usize>,
    ) -> Result<Self, LoadError> {
        Ok(Self {
            norm1: Norm::load(&w.at("norm1"), c_in)?,
            conv1: Conv::load(&w.at("conv1"), c_in, c_out, 3, 1)?,
            emb: emb
                .map(|e| Linear::load(&w.at("emb"), e, c_out))
                .transpose()?,
            norm2: Norm::load(&w.at("norm2"), c_out)?,
            conv2: Conv::load(&w.at("conv2"), c_out, c_out, 3, 1)?,
            skip: (c_in != c_out)
                .then(|| Conv::load(&w.at("skip"), c_in, c_out, 1, 1))
                .transpose()?,
        })
    }

    /// `x` [N, C, H, W]; `emb` [N, E] when the block has an embedding.
    pub fn forward(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        emb: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let projected = match emb {
            Some(emb) => self.project(r, emb)?,
            None => None,
        };
        self.forward_projected(r, x, projected.as_ref())
    }

    /// The block's projection of the embedding `emb` [N, E] to [N, C_out] (None when the
    /// block takes no embedding).
    pub fn project(&self, r: &mut Recorder, emb: &Tensor) -> Result<Option<Tensor>, GpuError> {
        self.emb
            .as_ref()
            .map(|layer| layer.forward(r, emb, true))
            .transpose()
    }

    /// [`ResBlock::forward_projected`] of the concatenation of `a` and `b` along the
    /// channels (the UNet's skip connections). For CPU drivers the concatenation exists
    /// only as texels copied from the two, which the first norm and the 1×1 skip read
    /// (no concatenation kernel); otherwise [`Recorder::concat`], then the block.
    pub fn forward_concat(
        &self,
        r: &mut Recorder,
        a: &Tensor,
        b: &Tensor,
        projected: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        if let Some(Conv {
            weights: ConvWeights::Packed(skip),
            bias: skip_bias,
            ..
        }) = &self.skip
            && skip.kernel == 1
            && let Some((texels, shape)) = r.concat_texels(a, b, self.norm1.groups)?
        {
            let h = r.group_norm_of_texels(&texels, shape, self.norm1.parts(), true)?;
            let skip = r.conv1x1_of_texels(&texels, shape, skip, skip_bias)?;
            return self.after_norm(r, &h, projected, &skip);
        }
        let x = r.concat(a, b, 1)?;
        self.forward_projected(r, &x, projected)
    }

    /// [`ResBlock::forward`] with the embedding already projected ([`ResBlock::project`]).
    pub fn forward_projected(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        projected: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        assert_eq!(
            projected.is_some(),
            self.emb.is_some(),
            "this block's embedding"
        );
        let h = self.norm1.forward(r, x, true)?;
        let skip = self.skip(r, x)?;
        self.after_norm(r, &h, projected, &skip)
    }

    /// [`ResBlock::forward`] without an embedding, each norm folded into the convolution
    /// after it where the recorder can ([`Conv::forward_normed`]): 2 dispatches fewer,
    /// the same values.
    pub fn forward_folded(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        assert!(self.emb.is_none(), "a block with an embedding");
        let skip = self.skip(r, x)?;
        let h = self.conv1.forward_normed(r, x, &self.norm1, None, None)?;
        self.conv2
            .forward_normed(r, &h, &self.norm2, None, Some(&skip))
    }

    /// The skip path: the 1×1 convolution when the channel count changes, else `x`.
    fn skip(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        match &self.skip {
            Some(conv) => conv.forward(r, x),
            None => Ok(x.clone()),
        }
    }

    /// The block after its first norm `h`: the first convolution (plus the embedding),
    /// the second norm, and `skip` + the second convolution (the add fused into it).
    fn after_norm(
        &self,
        r: &mut Recorder,
        h: &Tensor,
        projected: Option<&Tensor>,
        skip: &Tensor,
    ) -> Result<Tensor, GpuError> {
        let h = self.conv1.forward_plus(r, h, projected)?;
        let h = self.norm2.forward(r, &h, true)?;
        self.conv2.forward_with(r, &h, None, Some(skip))
    }
}

/// Nearest ×2 upsampling then a 3×3 convolution.
pub struct UpBlock {
    conv: Conv,
}

impl UpBlock {
    pub fn load(w: &Weights, c_in: usize, c_out: usize) -> Result<Self, LoadError> {
        Ok(Self {
            conv: Conv::load(&w.at("conv"), c_in, c_out, 3, 1)?,
        })
    }

    pub fn forward(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        match &self.conv.weights {
            // The upsampling fused into the convolution's loads.
            ConvWeights::Packed(weights) if weights.kernel == 3 => {
                r.upsampled_conv3x3(x, weights, Some(&self.conv.bias))
            }
            _ => {
                let up = r.upsample_nearest2x(x)?;
                self.conv.forward(r, &up)
            }
        }
    }
}

/// Attention shapes: `sequences` × `queries` rows attend to `keys` rows; packed qkv rows
/// ([q | k | v], self-attention) or separate q rows and [k | v] rows.
fn attention_params(
    sequences: usize,
    queries: usize,
    keys: usize,
    channels: usize,
    heads: usize,
    packed: bool,
) -> AttentionParams {
    let (q_stride, kv_stride, k_offset) = if packed {
        (3 * channels, 3 * channels, channels)
    } else {
        (channels, 2 * channels, 0)
    };
    AttentionParams {
        sequences: sequences as u32,
        heads: heads as u32,
        queries: queries as u32,
        keys: keys as u32,
        channels: channels as u32,
        q_stride: q_stride as u32,
        q_offset: 0,
        kv_stride: kv_stride as u32,
        k_offset: k_offset as u32,
        v_offset: (k_offset + channels) as u32,
        causal: 0,
        kv_share: 1,
        prefix_keys: 0,
        rows: 0,
        reserved1: 0,
        reserved2: 0,
    }
}

/// NCHW images as [N, HW, C] token rows, and back (adding the residual).
fn to_tokens(r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
    let [n, c, h, w] = x.shape[..] else {
        panic!("NCHW expected, got {:?}", x.shape)
    };
    r.permute(x, [1, n, c, h * w], [0, 1, 3, 2])
}

fn add_tokens(r: &mut Recorder, x: &Tensor, tokens: &Tensor) -> Result<Tensor, GpuError> {
    let [n, c, h, w] = x.shape[..] else {
        panic!("NCHW expected, got {:?}", x.shape)
    };
    r.add_permuted(x, tokens, [1, n, h * w, c], [0, 1, 3, 2])
}

/// Self-attention among the H×W positions of each image.
pub struct SpatialAttention {
    norm: Norm,
    qkv: Linear,
    out: Linear,
    heads: usize,
}

impl SpatialAttention {
    pub fn load(w: &Weights, channels: usize, heads: usize) -> Result<Self, LoadError> {
        Ok(Self {
            norm: Norm::load(&w.at("norm"), channels)?,
            qkv: Linear::load(&w.at("qkv"), channels, 3 * channels)?,
            out: Linear::load(&w.at("out"), channels, channels)?,
            heads,
        })
    }

    pub fn forward(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        self.forward_with_bias(r, x, None)
    }

    /// [`SpatialAttention::forward`], then plus a row of an action table per sample
    /// (`table`, `ids`, images per sample), fused into the residual's pass: what
    /// [`Recorder::add_action_bias`] after `forward` gives, bit for bit.
    pub fn forward_with_bias(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        bias: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        let [n, c, h, w] = x.shape[..] else {
            panic!("NCHW expected, got {:?}", x.shape)
        };
        let tokens = r.group_norm_tokens(x, self.norm.parts(), 1, None)?;
        let qkv = self.qkv.forward(r, &tokens, false)?;
        let mixed = r.attention(
            &qkv,
            &qkv,
            attention_params(n, h * w, h * w, c, self.heads, true),
        )?;
        r.linear_to_images(&mixed, self.out.parts(), x, 1, bias)
    }
}

/// Every position attends to its sample's context tokens (here: one action token).
pub struct CrossAttention {
    norm: Norm,
    q: Linear,
    kv: Linear,
    out: Linear,
    heads: usize,
}

impl CrossAttention {
    pub fn load(
        w: &Weights,
        channels: usize,
        context: usize,
        heads: usize,
    ) -> Result<Self, LoadError> {
        Ok(Self {
            norm: Norm::load(&w.at("norm"), channels)?,
            q: Linear::load(&w.at("q"), channels, channels)?,
            kv: Linear::load(&w.at("kv"), context, 2 * channels)?,
            out: Linear::load(&w.at("out"), channels, channels)?,
            heads,
        })
    }

    /// `x` [N·F, C, H, W]; `context` [N, T, E]: the F consecutive images of a sample
    /// share its T tokens.
    pub fn forward(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        context: &Tensor,
    ) -> Result<Tensor, GpuError> {
        let [nf, c, h, w] = x.shape[..] else {
            panic!("NCHW expected, got {:?}", x.shape)
        };
        let [n, tokens_per_sample, _] = context.shape[..] else {
            panic!("context must be [N, T, E], got {:?}", context.shape)
        };
        let normed = self.norm.forward(r, x, false)?;
        let tokens = to_tokens(r, &normed)?;
        let q = self.q.forward(r, &tokens, false)?;
        let kv = self.kv.forward(r, context, false)?;
        let params = AttentionParams {
            kv_share: (nf / n) as u32,
            ..attention_params(nf, h * w, tokens_per_sample, c, self.heads, false)
        };
        let mixed = r.attention(&q, &kv, params)?;
        let out = self.out.forward(r, &mixed, false)?;
        add_tokens(r, x, &out)
    }
}

impl CrossAttention {
    /// The layer's output for each row of `tokens` [A, E] as the only token of a sample,
    /// before the residual: softmax over one key is exactly 1, so every position gets
    /// `out(v(token))`, whatever it holds. Recorded with the kernels `forward` uses (the
    /// same variant picks the same summation order), so `x` plus a row of this table
    /// ([`Recorder::add_action_bias`]) equals `forward` bit for bit. [A, C].
    pub fn action_table(&self, r: &mut Recorder, tokens: &Tensor) -> Result<Tensor, GpuError> {
        let [actions, _] = tokens.shape[..] else {
            panic!("tokens must be [A, E], got {:?}", tokens.shape)
        };
        let kv = self.kv.forward(r, tokens, false)?; // [A, 2C]
        let c = kv.shape[1] / 2;
        let params = AttentionParams {
            q_stride: (2 * c) as u32,
            ..attention_params(actions, 1, 1, c, self.heads, false)
        };
        let v = r.attention(&kv, &kv, params)?;
        self.out.forward(r, &v.reshaped(&[actions, c]), false)
    }
}

/// Which frames of each group a batch holds, for [`TemporalAttention`].
pub enum Frames<'a> {
    /// The first `count` frames of every group, in order; their packed qkv rows
    /// [N, HW, count, 3C] are handed to `keep` when given (the context cache).
    First {
        count: usize,
        keep: Option<&'a mut Vec<Tensor>>,
    },
    /// Only the frame after the cached ones: `cached` holds the earlier frames' qkv rows.
    Next { cached: &'a Tensor },
}

/// Each position attends across the frames of its group, with learned frame positions
/// and a causal mask (frame i sees frames <= i).
pub struct TemporalAttention {
    norm: Norm,
    position: Tensor,
    qkv: Linear,
    out: Linear,
    heads: usize,
}

impl TemporalAttention {
    pub fn load(
        w: &Weights,
        channels: usize,
        frames: usize,
        heads: usize,
    ) -> Result<Self, LoadError> {
        Ok(Self {
            norm: Norm::load(&w.at("norm"), channels)?,
            position: w.tensor("position", &[frames, channels])?,
            qkv: Linear::load(&w.at("qkv"), channels, 3 * channels)?,
            out: Linear::load(&w.at("out"), channels, channels)?,
            heads,
        })
    }

    /// The rows the next frame's steps read of this layer ([`Frames::First`]'s `keep`)
    /// for `x` [N·F, C, H, W] in groups of `count` frames, without the attention after
    /// them (a context pass's last temporal layer).
    pub fn keep_rows(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        count: usize,
        keep: &mut Vec<Tensor>,
    ) -> Result<(), GpuError> {
        let tokens = self.tokens(r, x, count, 0)?;
        keep.push(self.qkv.forward(r, &tokens, false)?);
        Ok(())
    }

    /// `x` [N·F, C, H, W] normed as token rows [N, HW, F, C], the positions of frames
    /// `first` … `first + F - 1` added.
    fn tokens(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        frames: usize,
        first: usize,
    ) -> Result<Tensor, GpuError> {
        let c = x.shape[1];
        let positions = (&self.position, first * c..(first + frames) * c);
        r.group_norm_tokens(x, self.norm.parts(), frames, Some(positions))
    }

    /// `x` [N·F, C, H, W] with F frames per group as `frames` says.
    pub fn forward(
        &self,
        r: &mut Recorder,
        x: &Tensor,
        frames: Frames,
    ) -> Result<Tensor, GpuError> {
        let [nf, c, h, w] = x.shape[..] else {
            panic!("NCHW expected, got {:?}", x.shape)
        };
        let (f, first) = match &frames {
            Frames::First { count, .. } => (*count, 0),
            Frames::Next { cached } => (1, cached.shape[2]),
        };
        let n = nf / f;
        let hw = h * w;
        let tokens = self.tokens(r, x, f, first)?; // [N, HW, F, C]
        let params = AttentionParams {
            causal: 1,
            prefix_keys: first as u32,
            ..attention_params(n * hw, f, first + f, c, self.heads, true)
        };
        // The keys: the cached context rows (read in place, no concatenation), then
        // this batch's.
        let mixed = match frames {
            Frames::First { keep, .. } => {
                let qkv = self.qkv.forward(r, &tokens, false)?;
                if let Some(keep) = keep {
                    keep.push(qkv.clone());
                }
                r.attention_after(&qkv, None, &qkv, params)?
            }
            // One new frame: its keys are read by its own queries only.
            Frames::Next { cached } => {
                r.temporal_next(&tokens, self.qkv.parts(), cached, params)?
            }
        }; // [N·HW, F, C]
        r.linear_to_images(&mixed, self.out.parts(), x, f, None) // [N·F, C, H, W]
    }
}
