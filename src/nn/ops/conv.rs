//! Convolutions: `conv2d` (any square kernel, stride and padding), the 3×3 stride-1
//! convolution from repacked weights (with a folded input norm, an addend, a residual, an
//! upsampled input), the 3×3 stride-2 one and the 1×1 one, in every [`Kernels`] variant.

use super::norm::{GROUP_NORM_EPS, GroupNormParams, InputNorm, NORM_STATS};
use super::{Broadcast, Kernels, Recorder, nchw};
use crate::gpu::kernel::{Grid, Precision};
use crate::gpu::shaders::Shader;
use crate::gpu::texels::Texels;
use crate::gpu::{Bound, GpuContext, GpuError};
use crate::gpu_struct;
use crate::nn::Tensor;
use crate::wgsl_shader as shader;

pub const CONV2D: Shader = shader!("nn/conv/conv2d.wgsl", [Conv2dParams], elem);
/// The convolution in register tiles of 4 output pixels × 8 channels.
pub const CONV2D_TILED: Shader = shader!("nn/conv/conv2d_tiled.wgsl", [Conv2dParams], elem);
/// The convolution for GPUs: a workgroup per tile of 4 pixels × 8 channels.
pub const CONV2D_SPLIT: Shader = shader!("nn/conv/conv2d_split.wgsl", [Conv2dParams], elem);
/// The 3×3 stride-1 convolution in register tiles of 8 pixels × 8 channels, from
/// repacked f32 weights (`ops::PackedConv`).
pub const CONV3X3: Shader = shader!("nn/conv/conv3x3.wgsl", [Conv2dParams], elem);
/// `CONV3X3` for CPU drivers: the input and the weights read as texels.
pub const CONV3X3_CPU: Shader = shader!("nn/conv/conv3x3_cpu.wgsl", [Conv2dParams], elem)
    .with_uints(&[("NORM_STATS", NORM_STATS as u32), ("NORMED", 0)]);
/// `CONV3X3_CPU` that group-normalises its input as it loads it (`Recorder::normed_conv3x3`):
/// the same file built with `NORMED` set, so the plain form carries none of it.
pub const CONV3X3_NORMED_CPU: Shader = shader!("nn/conv/conv3x3_cpu.wgsl", [Conv2dParams], elem)
    .with_uints(&[("NORM_STATS", NORM_STATS as u32), ("NORMED", 1)]);
/// The 1×1 convolution in register tiles of 8 pixels × 8 channels, from repacked f32
/// weights (`ops::PackedConv`).
/// The 3×3 stride-2 convolution for CPU drivers: input and packed weights as texels.
pub const CONV3X3_S2_CPU: Shader = shader!("nn/conv/conv3x3_s2_cpu.wgsl", [Conv2dParams], elem);
pub const CONV1X1: Shader = shader!("nn/conv/conv1x1.wgsl", [Conv2dParams], elem);
/// `CONV1X1` for CPU drivers: the input and the weights read as texels.
pub const CONV1X1_CPU: Shader = shader!("nn/conv/conv1x1_cpu.wgsl", [Conv2dParams], elem);

/// Every shader of this file (see [`super::shaders`]).
pub const SHADERS: &[Shader] = &[
    CONV2D,
    CONV2D_TILED,
    CONV2D_SPLIT,
    CONV3X3,
    CONV3X3_CPU,
    CONV3X3_NORMED_CPU,
    CONV3X3_S2_CPU,
    CONV1X1,
    CONV1X1_CPU,
];

gpu_struct! {
    /// Shapes of one 2-D convolution (NCHW, square kernel, zero padding).
    pub struct Conv2dParams {
        pub batch: u32,
        pub c_in: u32,
        pub c_out: u32,
        pub h_in: u32,
        pub w_in: u32,
        pub h_out: u32,
        pub w_out: u32,
        pub kernel: u32,
        pub stride: u32,
        pub pad: u32,
        pub has_bias: u32,
        /// conv3x3: add a per-image addend [N, c_out] after the sums.
        pub has_extra: u32,
        /// conv3x3: then add a residual of the output's shape.
        pub has_residual: u32,
        /// conv3x3: the input is read upsampled ×2 (nearest): output pixel (y, x) of the
        /// 2H × 2W image sees input pixel (y / 2, x / 2) through each tap.
        pub upsample: u32,
        /// conv3x3 for CPU drivers: G > 0 group-normalises the input on load in G
        /// groups (statistics per workgroup), as [`Recorder::group_norm`] would before
        /// the convolution; see [`Recorder::normed_conv3x3`].
        pub norm_groups: u32,
        /// With `norm_groups`: the norm's epsilon (SiLU always follows the norm).
        pub norm_eps: f32,
        pub reserved3: u32,
        pub reserved0: u32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

impl Conv2dParams {
    /// A convolution of `input` [N, C_in, H, W] to `c_out` channels at `out` [H', W']:
    /// square `kernel`, `stride`, zero padding `pad`; no addend, residual or upsampling.
    fn new(
        input: [usize; 4],
        c_out: usize,
        out: [usize; 2],
        (kernel, stride, pad): (usize, usize, usize),
        has_bias: bool,
    ) -> Self {
        let [n, c_in, h, w] = input;
        Self {
            batch: n as u32,
            c_in: c_in as u32,
            c_out: c_out as u32,
            h_in: h as u32,
            w_in: w as u32,
            h_out: out[0] as u32,
            w_out: out[1] as u32,
            kernel: kernel as u32,
            stride: stride as u32,
            pad: pad as u32,
            has_bias: u32::from(has_bias),
            has_extra: 0,
            has_residual: 0,
            upsample: 0,
            norm_groups: 0,
            norm_eps: 0.0,
            reserved3: 0,
            reserved0: 0,
            reserved1: 0,
            reserved2: 0,
        }
    }
}

/// A k×k convolution's weights (k = 1 or 3, stride 1) in both layouts: `plain`
/// [c_out, c_in, k, k] in the recorder's precision for `conv2d`, and `packed` for
/// `conv3x3.wgsl` / `conv1x1.wgsl`: f32 [c_in, k, k, c_out rounded up to 8] (zeros past
/// c_out), so the 8 output channels of a tap are two vec4 loads. The packed values are
/// the stored ones (rounded to f16 first in an f16 recorder), so every kernel sums the
/// same numbers.
pub struct PackedConv {
    pub plain: Tensor,
    pub packed: Tensor,
    pub c_in: usize,
    pub c_out: usize,
    pub kernel: usize,
}

impl PackedConv {
    /// `values` [c_out, c_in, k, k] as PyTorch stores them.
    pub fn new(
        gpu: &GpuContext,
        label: &str,
        values: &[f32],
        [c_out, c_in, kernel]: [usize; 3],
        precision: Precision,
    ) -> Result<Self, GpuError> {
        assert!(
            kernel == 1 || kernel == 3,
            "packed convolutions are 1×1 or 3×3"
        );
        let taps = kernel * kernel;
        let plain = Tensor::upload(
            gpu,
            label,
            &[c_out, c_in, kernel, kernel],
            values,
            precision,
        )?;
        let stored = precision.decode(&precision.encode(values));
        let lanes = c_out.next_multiple_of(8);
        let mut packed = vec![0.0f32; c_in * taps * lanes];
        for co in 0..c_out {
            for ci in 0..c_in {
                for tap in 0..taps {
                    packed[(ci * taps + tap) * lanes + co] = stored[(co * c_in + ci) * taps + tap];
                }
            }
        }
        let packed = Tensor::upload(
            gpu,
            &format!("{label} (packed)"),
            &[c_in * taps, lanes],
            &packed,
            Precision::F32,
        )?;
        Ok(Self {
            plain,
            packed,
            c_in,
            c_out,
            kernel,
        })
    }
}

impl Recorder<'_> {
    /// `y = conv2d(x, weight) + bias` (square kernel, `stride`, zero padding `pad`).
    pub fn conv2d(
        &mut self,
        x: &Tensor,
        weight: &Tensor,
        bias: Option<&Tensor>,
        stride: usize,
        pad: usize,
    ) -> Result<Tensor, GpuError> {
        let [n, c_in, h_in, w_in] = x.shape[..] else {
            panic!("conv2d input must be NCHW, got {:?}", x.shape)
        };
        let [c_out, wc_in, k, _] = weight.shape[..] else {
            panic!(
                "conv2d weight must be [c_out, c_in, k, k], got {:?}",
                weight.shape
            )
        };
        assert_eq!(c_in, wc_in, "conv2d channel mismatch");
        let h_out = (h_in + 2 * pad - k) / stride + 1;
        let w_out = (w_in + 2 * pad - k) / stride + 1;
        let y = self.output("conv2d.y", &[n, c_out, h_out, w_out])?;
        let params = Conv2dParams::new(
            [n, c_in, h_in, w_in],
            c_out,
            [h_out, w_out],
            (k, stride, pad),
            bias.is_some(),
        );
        self.flops += 2 * (y.len() * c_in * k * k) as u64;
        // A bias binding must exist even without a bias; the weight stands in (unread).
        let bias = bias.unwrap_or(weight);
        // For GPUs a workgroup per tile of 4 output pixels × 8 channels, its threads
        // splitting the terms. Otherwise register tiles of 4 output pixels × 8 channels
        // where a row has 4 pixels, and one thread per output pixel and block of 8
        // channels where not; these two sum in the same order. All three are
        // parity-tested (tests/nn/).
        if self.kernels == Kernels::Gpu {
            let tiles = n * c_out.div_ceil(8) * h_out * w_out.div_ceil(4);
            let grid = self.workgroups(tiles);
            self.launch(&CONV2D_SPLIT, &params, &[x, weight, bias, &y], grid);
        } else if w_out >= 4 && self.kernels != Kernels::Simple {
            let grid = self.grid(n * c_out.div_ceil(8) * h_out * w_out.div_ceil(4));
            self.launch(&CONV2D_TILED, &params, &[x, weight, bias, &y], grid);
        } else {
            let grid = self.grid(n * c_out.div_ceil(8) * h_out * w_out);
            self.launch(&CONV2D, &params, &[x, weight, bias, &y], grid);
        }
        Ok(y)
    }

    /// A 3×3, stride-1, padding-1 convolution from weights repacked by [`PackedConv`]:
    /// register tiles of 8 pixels × 8 channels (`conv3x3.wgsl`), the same sums in the same
    /// order as [`Recorder::conv2d`]. With [`Kernels::Simple`], and for rows narrower than 8,
    /// it records `conv2d` instead.
    ///
    /// `extra` [N, c_out], when given, is added to every pixel of image n's channel after
    /// the sums (a ResBlock's embedding), as an `add` after the convolution would.
    pub fn conv3x3(
        &mut self,
        x: &Tensor,
        weights: &PackedConv,
        bias: Option<&Tensor>,
        extra: Option<&Tensor>,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        self.normed_conv3x3(x, None, weights, bias, extra, residual)
    }

    /// [`Recorder::conv3x3`] of `norm` applied to `x` ([`Recorder::group_norm`], SiLU
    /// with `norm.silu`). For CPU drivers, with SiLU and where
    /// [`Recorder::can_fold_norm`] allows, in one dispatch: each workgroup first
    /// computes the statistics of every (sample, group) with the serial norm's
    /// `texel_stats`, then normalises the input as it loads it and rounds it to Elem as
    /// the norm's store would. Otherwise the norm, then the convolution.
    pub fn normed_conv3x3(
        &mut self,
        x: &Tensor,
        norm: Option<InputNorm>,
        weights: &PackedConv,
        bias: Option<&Tensor>,
        extra: Option<&Tensor>,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let [n, c_in, h, w] = x.shape[..] else {
            panic!("conv3x3 input must be NCHW, got {:?}", x.shape)
        };
        assert_eq!((c_in, weights.kernel), (weights.c_in, 3), "conv3x3 weights");
        if let Some(e) = extra {
            assert_eq!(e.len(), n * weights.c_out, "conv3x3 extra {:?}", e.shape);
        }
        if let Some(r) = residual {
            assert_eq!(
                r.len(),
                n * weights.c_out * h * w,
                "conv3x3 residual {:?}",
                r.shape
            );
        }
        if let Some(norm) = norm
            && !(norm.silu && self.can_fold_norm([n, c_in, h, w], norm.groups))
        {
            let normed = self.group_norm(x, norm.gamma, norm.beta, norm.groups, norm.silu)?;
            return self.normed_conv3x3(&normed, None, weights, bias, extra, residual);
        }
        if w < 8 || self.kernels == Kernels::Simple {
            let y = self.conv2d(x, &weights.plain, bias, 1, 1)?;
            let y = match extra {
                Some(e) => self.add(&y, e, Broadcast::Leading)?,
                None => y,
            };
            return match residual {
                Some(r) => self.add(r, &y, Broadcast::Leading),
                None => Ok(y),
            };
        }
        let (y, mut params) =
            self.packed_output(nchw(x), weights, bias.is_some(), extra.is_some(), false)?;
        params.has_residual = u32::from(residual.is_some());
        if let Some(norm) = norm {
            self.check(&[norm.gamma, norm.beta]);
            params.norm_groups = norm.groups as u32;
            params.norm_eps = GROUP_NORM_EPS;
        }
        let c_out = weights.c_out;
        // Bias, extra and residual bindings must exist even when absent; the input stands
        // in (unread).
        let bias = bias.unwrap_or(x);
        let extra = extra.unwrap_or(x);
        let residual = residual.unwrap_or(x);
        self.check(&[x, bias, extra, residual, &y]);
        let grid = self.grid(n * c_out.div_ceil(8) * h * w.div_ceil(8));
        let norm = norm.map(|m| [m.gamma, m.beta]);
        self.packed_conv3x3(&params, x, weights, [bias, extra, residual, &y], norm, grid)?;
        Ok(y)
    }

    /// Whether [`Recorder::normed_conv3x3`] can fold the norm of `input` [N, C, H, W] (in
    /// `groups` groups) into the convolution: CPU drivers, rows of 8 pixels or more in whole
    /// vec4s, at most [`NORM_STATS`] (sample, group) pairs, and a norm the serial kernel takes
    /// ([`GroupNormParams::serial`]: the fold computes its statistics). Whether it pays is the
    /// caller's choice: on lavapipe the folded norm is recomputed for every tile that reads a
    /// value (3·⌈c_out / 8⌉ times), which costs more than the dispatch it saves (about 0.1 ms
    /// per million multiply-adds of the convolution; see `vae::Decoder::forward`).
    pub fn can_fold_norm(&self, [n, c, h, w]: [usize; 4], groups: usize) -> bool {
        self.kernels == Kernels::Cpu
            && w >= 8
            && w.is_multiple_of(4)
            && n * groups <= NORM_STATS
            && GroupNormParams::nchw([n, c, h, w], groups, true).serial()
    }

    /// A 3×3, stride-2, padding-1 convolution from weights packed by [`PackedConv`]: for
    /// CPU drivers `conv3x3_s2_cpu.wgsl` (tiles of 4 pixels × 8 channels read as texels),
    /// otherwise [`Recorder::conv2d`] with the plain weights; both sum in the same order.
    pub fn conv3x3_stride2(
        &mut self,
        x: &Tensor,
        weights: &PackedConv,
        bias: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let [n, c_in, h, w] = nchw(x);
        assert_eq!((c_in, weights.kernel), (weights.c_in, 3), "conv3x3 weights");
        if self.kernels != Kernels::Cpu {
            return self.conv2d(x, &weights.plain, bias, 2, 1);
        }
        let (h_out, w_out) = (h.div_ceil(2), w.div_ceil(2));
        let y = self.output("conv3x3_s2.y", &[n, weights.c_out, h_out, w_out])?;
        let params = Conv2dParams::new(
            [n, c_in, h, w],
            weights.c_out,
            [h_out, w_out],
            (3, 2, 1),
            bias.is_some(),
        );
        self.flops += 2 * (y.len() * c_in * 9) as u64;
        self.check(&[x]);
        let input = self.texels(x)?;
        let packed = weights.packed.constant_texels(self.gpu)?;
        // Absent bias, addend and residual keep their bindings; the packed weights stand
        // in (unread).
        let unread = &weights.packed.buffer;
        let bias = bias.map_or(unread, |b| {
            self.check(&[b]);
            &b.buffer
        });
        let bound = [
            Bound::Texels(&input),
            Bound::Texels(packed),
            Bound::Buffer(bias),
            Bound::Buffer(unread),
            Bound::Buffer(unread),
            Bound::Buffer(&y.buffer),
        ];
        let grid = self.grid(n * weights.c_out.div_ceil(8) * h_out * w_out.div_ceil(4));
        self.steps
            .dispatch_bound(&CONV3X3_S2_CPU, &params, &bound, grid);
        Ok(y)
    }

    /// Nearest ×2 upsampling then a 3×3 convolution, in one dispatch: the kernel reads
    /// each upsampled pixel from its source (the same sums as upsample_nearest then
    /// conv3x3). With [`Kernels::Simple`] and for rows under 8 pixels, the two ops.
    pub fn upsampled_conv3x3(
        &mut self,
        x: &Tensor,
        weights: &PackedConv,
        bias: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let [n, c_in, h, w] = x.shape[..] else {
            panic!("conv3x3 input must be NCHW, got {:?}", x.shape)
        };
        assert_eq!((c_in, weights.kernel), (weights.c_in, 3), "conv3x3 weights");
        if 2 * w < 8 || self.kernels == Kernels::Simple {
            let up = self.upsample_nearest2x(x)?;
            return self.conv3x3(&up, weights, bias, None, None);
        }
        let (y, params) = self.packed_output(nchw(x), weights, bias.is_some(), false, true)?;
        let bias = bias.unwrap_or(x);
        self.check(&[x, bias, &y]);
        let grid = self.grid(n * weights.c_out.div_ceil(8) * 2 * h * (2 * w).div_ceil(8));
        self.packed_conv3x3(&params, x, weights, [bias, x, x, &y], None, grid)?;
        Ok(y)
    }

    /// Records `conv3x3.wgsl` (or, for CPU drivers and output rows of whole vec4s,
    /// `conv3x3_cpu.wgsl`, which reads the input and the weights as texels and stores
    /// four pixels at a time) over `x` and `weights`, then `rest`: bias, addend,
    /// residual and output; for CPU drivers then the input norm's gamma and beta (with
    /// `params.norm_groups`).
    fn packed_conv3x3(
        &mut self,
        params: &Conv2dParams,
        x: &Tensor,
        weights: &PackedConv,
        rest: [&Tensor; 4],
        norm: Option<[&Tensor; 2]>,
        grid: Grid,
    ) -> Result<(), GpuError> {
        // Without a norm its bindings exist all the same; the bias (or its stand-in)
        // stands in, unread.
        let norm = norm.unwrap_or([rest[0], rest[0]]);
        let rest = rest.map(|t| Bound::Buffer(&t.buffer));
        // conv3x3_cpu.wgsl stores four pixels of a row at a time: rows of whole vec4s.
        if self.kernels == Kernels::Cpu && params.w_out.is_multiple_of(4) {
            let input = self.texels(x)?;
            let packed = weights.packed.constant_texels(self.gpu)?;
            let mut bound = vec![Bound::Texels(&input), Bound::Texels(packed)];
            bound.extend(rest);
            bound.extend(norm.map(|t| Bound::Buffer(&t.buffer)));
            let kernel = if params.norm_groups != 0 {
                &CONV3X3_NORMED_CPU
            } else {
                &CONV3X3_CPU
            };
            self.steps.dispatch_bound(kernel, params, &bound, grid);
        } else {
            assert_eq!(params.norm_groups, 0, "the GPU conv3x3 normalises no input");
            // One workgroup per tile of 8 pixels × 8 channels (conv3x3.wgsl).
            let tiles = params.batch as usize
                * (params.c_out as usize).div_ceil(8)
                * params.h_out as usize
                * (params.w_out as usize).div_ceil(8);
            let grid = self.workgroups(tiles);
            let mut bound = vec![
                Bound::Buffer(&x.buffer),
                Bound::Buffer(&weights.packed.buffer),
            ];
            bound.extend(rest);
            self.steps.dispatch_bound(&CONV3X3, params, &bound, grid);
        }
        Ok(())
    }

    /// The output [N, c_out, H, W] (2H × 2W with `upsample`) and parameters of a
    /// stride-1 "same" convolution from packed weights (`conv3x3` and `conv1x1`), its
    /// FLOPs counted.
    fn packed_output(
        &mut self,
        input: [usize; 4],
        weights: &PackedConv,
        has_bias: bool,
        has_extra: bool,
        upsample: bool,
    ) -> Result<(Tensor, Conv2dParams), GpuError> {
        let [n, c_in, h, w] = input;
        let k = weights.kernel;
        let scale = if upsample { 2 } else { 1 };
        let (h_out, w_out) = (scale * h, scale * w);
        let y = self.output("packed_conv.y", &[n, weights.c_out, h_out, w_out])?;
        let params = Conv2dParams {
            has_extra: u32::from(has_extra),
            upsample: u32::from(upsample),
            ..Conv2dParams::new(
                input,
                weights.c_out,
                [h_out, w_out],
                (k, 1, k / 2),
                has_bias,
            )
        };
        self.flops += 2 * (y.len() * c_in * k * k) as u64;
        Ok((y, params))
    }

    /// A 1×1 convolution from weights packed by [`PackedConv`]: register tiles of 8
    /// pixels × 8 channels (`conv1x1.wgsl`), the same sums in the same order as
    /// [`Recorder::conv2d`]. With [`Kernels::Simple`], and for planes whose pixel count
    /// is not a multiple of 4, it records `conv2d` instead.
    pub fn conv1x1(
        &mut self,
        x: &Tensor,
        weights: &PackedConv,
        bias: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let [_, c_in, h, w] = nchw(x);
        assert_eq!((c_in, weights.kernel), (weights.c_in, 1), "conv1x1 weights");
        if !(h * w).is_multiple_of(4) || self.kernels == Kernels::Simple {
            return self.conv2d(x, &weights.plain, bias, 1, 0);
        }
        let (y, params) = self.packed_output(nchw(x), weights, bias.is_some(), false, false)?;
        // A bias binding must exist even without a bias; the input stands in (unread).
        let bias = bias.unwrap_or(x);
        self.check(&[x, bias, &y]);
        let grid = self.conv1x1_grid(&params);
        if self.kernels == Kernels::Cpu {
            // The input and the weights as texels.
            let input = self.texels(x)?;
            self.conv1x1_cpu(&params, &input, weights, bias, &y)?;
            return Ok(y);
        }
        let buffers = [&x.buffer, &weights.packed.buffer, &bias.buffer, &y.buffer];
        self.steps.dispatch(&CONV1X1, &params, &buffers, grid);
        Ok(y)
    }

    /// The 1×1 convolutions' grid: one invocation per 8 output channels × 8 pixels.
    fn conv1x1_grid(&self, p: &Conv2dParams) -> Grid {
        let quads = (p.h_in * p.w_in / 4) as usize;
        self.grid(p.batch as usize * (p.c_out as usize).div_ceil(8) * quads.div_ceil(2))
    }

    /// Records `conv1x1_cpu.wgsl` over `input` into `y`.
    fn conv1x1_cpu(
        &mut self,
        params: &Conv2dParams,
        input: &Texels,
        weights: &PackedConv,
        bias: &Tensor,
        y: &Tensor,
    ) -> Result<(), GpuError> {
        let grid = self.conv1x1_grid(params);
        let packed = weights.packed.constant_texels(self.gpu)?;
        let bound = [
            Bound::Texels(input),
            Bound::Texels(packed),
            Bound::Buffer(&bias.buffer),
            Bound::Buffer(&y.buffer),
        ];
        self.steps
            .dispatch_bound(&CONV1X1_CPU, params, &bound, grid);
        Ok(())
    }

    /// [`Recorder::conv1x1`] of an NCHW tensor of `shape` held as `input` texels
    /// ([`Recorder::concat_texels`]), on the CPU-driver kernel.
    pub fn conv1x1_of_texels(
        &mut self,
        input: &Texels,
        shape: [usize; 4],
        weights: &PackedConv,
        bias: &Tensor,
    ) -> Result<Tensor, GpuError> {
        assert_eq!(
            (shape[1], weights.kernel),
            (weights.c_in, 1),
            "conv1x1 weights"
        );
        let (y, params) = self.packed_output(shape, weights, true, false, false)?;
        self.conv1x1_cpu(&params, input, weights, bias, &y)?;
        Ok(y)
    }
}
