//! Group normalisation (+SiLU) of NCHW images, into images or into the attention
//! layers' token rows, in every [`Kernels`] variant.

use super::{Kernels, Recorder};
use crate::gpu::shaders::Shader;
use crate::gpu::texels::Texels;
use crate::gpu::{Bound, GpuError};
use crate::gpu_struct;
use crate::nn::Tensor;
use crate::wgsl_shader as shader;

pub const GROUP_NORM: Shader =
    shader!("nn/norm/group_norm.wgsl", [GroupNormParams], elem).with_uints(&[("THREADS", 64)]);
/// `GROUP_NORM` with workgroups of 256 threads, for GPUs and large groups.
pub const GROUP_NORM_WIDE: Shader =
    shader!("nn/norm/group_norm.wgsl", [GroupNormParams], elem).with_uints(&[("THREADS", 256)]);
/// Group norm for CPU drivers: one invocation per (sample, group), no barriers.
pub const GROUP_NORM_SERIAL: Shader =
    shader!("nn/norm/group_norm_serial.wgsl", [GroupNormParams], elem);

/// Every shader of this file (see [`super::shaders`]).
pub const SHADERS: &[Shader] = &[GROUP_NORM, GROUP_NORM_WIDE, GROUP_NORM_SERIAL];

gpu_struct! {
    /// Group normalisation of `batch` samples of `channels` × `hw` values.
    pub struct GroupNormParams {
        pub batch: u32,
        pub channels: u32,
        pub groups: u32,
        pub hw: u32,
        pub eps: f32,
        pub silu: u32,
        /// 0: the output is NCHW like the input. F > 0 (group_norm_serial.wgsl only):
        /// token rows [N, HW, F, C] of the images taken F at a time (image n·F + f is
        /// frame f of sequence n), as a permute after the norm would lay them out.
        pub tokens: u32,
        /// With `tokens`: plus `rows[rows_offset + f·C + c]` (frame positions), added
        /// to the value rounded to Elem, as the permute's addend.
        pub has_rows: u32,
        pub rows_offset: u32,
        pub reserved0: u32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

/// The epsilon of every group norm in the trainer's models.
pub const GROUP_NORM_EPS: f32 = 1e-5;

/// The most (sample, group) statistics a convolution that normalises its input holds
/// (conv3x3_cpu.wgsl's workgroup array).
pub const NORM_STATS: usize = 64;

/// A group norm (and SiLU) of a convolution's input: [`Recorder::group_norm`]'s
/// arguments, for [`Recorder::normed_conv3x3`].
#[derive(Clone, Copy)]
pub struct InputNorm<'a> {
    pub gamma: &'a Tensor,
    pub beta: &'a Tensor,
    pub groups: usize,
    pub silu: bool,
}

/// The most values per group the CPU group norm takes: its invocation loops 3/4 of this
/// many times plus once per channel, and lavapipe ends any invocation's loops after
/// 65,535 iterations in all (its loop limiter), silently. Larger groups take the
/// workgroup kernel.
pub const SERIAL_NORM_LIMIT: usize = 80_000;

/// The fewest values of a group for which GPUs normalise it with 256 threads.
const WIDE_NORM_VALUES: u32 = 4096;

impl GroupNormParams {
    /// The norm of NCHW images of `shape` into NCHW, in `groups` groups.
    pub(super) fn nchw([n, c, h, w]: [usize; 4], groups: usize, silu: bool) -> Self {
        Self {
            batch: n as u32,
            channels: c as u32,
            groups: groups as u32,
            hw: (h * w) as u32,
            eps: GROUP_NORM_EPS,
            silu: u32::from(silu),
            tokens: 0,
            has_rows: 0,
            rows_offset: 0,
            reserved0: 0,
            reserved1: 0,
            reserved2: 0,
        }
    }

    /// Whether `group_norm_serial.wgsl` takes this norm: whole groups, planes of a
    /// multiple of 4 values or rows of a multiple of 4 channels (hw = 1), at most
    /// [`SERIAL_NORM_LIMIT`] values per group.
    pub(super) fn serial(&self) -> bool {
        let (c, groups, hw) = (self.channels, self.groups, self.hw);
        let quads = hw.is_multiple_of(4) || (hw == 1 && (c / groups).is_multiple_of(4));
        c.is_multiple_of(groups) && quads && (c / groups * hw) as usize <= SERIAL_NORM_LIMIT
    }
}

impl Recorder<'_> {
    /// Group normalisation of an NCHW tensor with the per-channel affine `gamma`, `beta`,
    /// followed by SiLU when `silu` is set.
    pub fn group_norm(
        &mut self,
        x: &Tensor,
        gamma: &Tensor,
        beta: &Tensor,
        groups: usize,
        silu: bool,
    ) -> Result<Tensor, GpuError> {
        let [n, c, h, w] = x.shape[..] else {
            panic!("group norm input must be NCHW, got {:?}", x.shape)
        };
        assert!(c.is_multiple_of(groups), "{c} channels in {groups} groups");
        let y = self.output("group_norm.y", &x.shape)?;
        let params = GroupNormParams::nchw([n, c, h, w], groups, silu);
        if self.kernels == Kernels::Cpu && params.serial() {
            // One invocation per (sample, group), no barriers; `x` stands in for the
            // absent rows (unread).
            let input = self.texels(x)?;
            self.group_norm_serial(&params, &input, [gamma, beta, x, &y])?;
            return Ok(y);
        }
        // One workgroup per (sample, group).
        let grid = self.workgroups(n * groups);
        // Without token rows their binding exists all the same; x stands in (unread).
        self.launch(
            self.group_norm_kernel(&params),
            &params,
            &[x, gamma, beta, x, &y],
            grid,
        );
        Ok(y)
    }

    /// `group_norm.wgsl` with workgroups of 256 threads for GPUs and groups of at least
    /// [`WIDE_NORM_VALUES`] values, else of 64. A workgroup of 64 threads per group left
    /// the VAE encoder's few large groups latency-bound on an H200 (docs/gpu).
    fn group_norm_kernel(&self, params: &GroupNormParams) -> &'static Shader {
        let values = params.channels / params.groups * params.hw;
        if self.kernels == Kernels::Gpu && values >= WIDE_NORM_VALUES {
            &GROUP_NORM_WIDE
        } else {
            &GROUP_NORM
        }
    }

    /// The group norm of NCHW `x` [N·F, C, H, W] (no SiLU) laid out as token rows
    /// [N, HW, F, C] (image n·F + f is frame f of sequence n), plus, with `rows`, values
    /// `part` of `rows` ([F, C] frame positions) on every token: what
    /// [`Recorder::permute_add_rows`] (or [`Recorder::permute`]) after
    /// [`Recorder::group_norm`] gives, bit for bit. For CPU drivers one dispatch (the
    /// serial norm stores the tokens); otherwise the two.
    pub fn group_norm_tokens(
        &mut self,
        x: &Tensor,
        norm: (&Tensor, &Tensor, usize),
        frames: usize,
        rows: Option<(&Tensor, std::ops::Range<usize>)>,
    ) -> Result<Tensor, GpuError> {
        let (gamma, beta, groups) = norm;
        let [nf, c, h, w] = x.shape[..] else {
            panic!("group norm input must be NCHW, got {:?}", x.shape)
        };
        assert!(nf.is_multiple_of(frames), "{nf} images in runs of {frames}");
        let (n, hw) = (nf / frames, h * w);
        if let Some((rows, part)) = &rows {
            assert!(
                part.len() == frames * c && part.end <= rows.len(),
                "frame positions {part:?} of {:?} for {frames} frames of {c} channels",
                rows.shape
            );
        }
        let part = rows.as_ref().map_or(0..0, |(_, part)| part.clone());
        let params = GroupNormParams {
            tokens: frames as u32,
            has_rows: u32::from(rows.is_some()),
            rows_offset: part.start as u32,
            ..GroupNormParams::nchw([nf, c, h, w], groups, false)
        };
        if self.kernels == Kernels::Gpu {
            // group_norm.wgsl stores the tokens: one workgroup per (sample, group).
            let y = self.output("group_norm.tokens", &[n, hw, frames, c])?;
            let rows = rows.map_or(x, |(rows, _)| rows);
            let grid = self.workgroups(nf * groups);
            self.launch(
                self.group_norm_kernel(&params),
                &params,
                &[x, gamma, beta, rows, &y],
                grid,
            );
            return Ok(y);
        }
        // The serial kernel's layer-norm rows (hw = 1) have no token form.
        if !(self.kernels == Kernels::Cpu && hw.is_multiple_of(4) && params.serial()) {
            let normed = self.group_norm(x, gamma, beta, groups, false)?;
            let (shape, perm) = ([n, frames, c, hw], [0, 3, 1, 2]);
            return match rows {
                Some((rows, part)) => self.permute_add_rows(&normed, shape, perm, rows, part),
                None => self.permute(&normed, shape, perm),
            };
        }
        let y = self.output("group_norm.tokens", &[n, hw, frames, c])?;
        let rows = rows.map_or(x, |(rows, _)| rows);
        let input = self.texels(x)?;
        self.group_norm_serial(&params, &input, [gamma, beta, rows, &y])?;
        Ok(y)
    }

    /// Records `group_norm_serial.wgsl` over `input` and `rest`: gamma, beta, rows and
    /// the output, one invocation per (sample, group).
    fn group_norm_serial(
        &mut self,
        params: &GroupNormParams,
        input: &Texels,
        rest: [&Tensor; 4],
    ) -> Result<(), GpuError> {
        self.check(&rest);
        let grid = self.grid((params.batch * params.groups) as usize);
        let mut bound = vec![Bound::Texels(input)];
        bound.extend(rest.map(|t| Bound::Buffer(&t.buffer)));
        self.steps
            .dispatch_bound(&GROUP_NORM_SERIAL, params, &bound, grid);
        Ok(())
    }

    /// [`Recorder::group_norm`] of an NCHW tensor of `shape` held as `input` texels
    /// ([`Recorder::concat_texels`]), on the serial kernel.
    pub fn group_norm_of_texels(
        &mut self,
        input: &Texels,
        shape: [usize; 4],
        norm: (&Tensor, &Tensor, usize),
        silu: bool,
    ) -> Result<Tensor, GpuError> {
        let (gamma, beta, groups) = norm;
        let y = self.output("group_norm.y", &shape)?;
        let params = GroupNormParams::nchw(shape, groups, silu);
        self.group_norm_serial(&params, input, [gamma, beta, gamma, &y])?;
        Ok(y)
    }
}
