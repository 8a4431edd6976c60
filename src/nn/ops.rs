//! The kernels of the geometry model, recorded into one command encoder by a [`Recorder`]:
//! convolution, nearest upsampling, group norm (+SiLU), linear, broadcast adds, permutes,
//! concatenation, axpby, multi-head attention and the timestep embedding. Each call
//! allocates its output and records one dispatch, in the [`Kernels`] variant that suits
//! the adapter (all variants compute the same thing); nothing is read back.

use super::Tensor;
use super::kernels;
use crate::gpu::kernel::{Grid, PipelineCache, Precision};
pub use crate::gpu::plan::{Builder, Plan};
use crate::gpu::shaders::Shader;
use crate::gpu::texels::Texels;
use crate::gpu::{Bound, GpuContext, GpuError};
use crate::gpu_struct;

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

gpu_struct! {
    /// Shapes of a nearest ×2 upsampling: `planes` = batch × channels.
    pub struct UpsampleParams {
        pub planes: u32,
        pub h_in: u32,
        pub w_in: u32,
        pub reserved: u32,
    }
}

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

gpu_struct! {
    /// A fully connected layer over `rows` rows.
    pub struct LinearParams {
        pub rows: u32,
        pub inputs: u32,
        pub outputs: u32,
        pub input_silu: u32,
        /// Add a residual of the output's shape to the result rounded to Elem (the sum
        /// add.wgsl would make after the layer).
        pub has_residual: u32,
        /// 0: the output is [rows, outputs]. F > 0 (linear_cpu.wgsl only): the rows are
        /// tokens [N, HW, F] and each result goes to its NCHW image [N·F, outputs, H, W]
        /// (image n·F + f), as a permute after the layer would put it; the residual is
        /// then NCHW too.
        pub images: u32,
        /// Pixels per image (with `images`).
        pub hw: u32,
        /// With `images`: plus row ids[image / table_frames] of an action table
        /// [A, outputs], added last (as add_action_bias.wgsl).
        pub has_table: u32,
        pub table_frames: u32,
        /// linear_cpu.wgsl only: input row r is row ids[r] of x (a gather before the
        /// layer; `rows` counts the output rows).
        pub gather_rows: u32,
        /// linear_cpu.wgsl only: each input row layer-normed first (gamma, beta, `eps`),
        /// rounded to Elem as the layer norm stores it.
        pub norm_rows: u32,
        pub eps: f32,
    }
}

gpu_struct! {
    /// `y[i] = a[i] + b[b_offset + (i / per_value) % b_len]` over `len` values.
    pub struct AddParams {
        pub len: u32,
        pub per_value: u32,
        pub b_len: u32,
        pub b_offset: u32,
    }
}

gpu_struct! {
    /// `count` timesteps embedded in `dim` values each.
    pub struct EmbeddingParams {
        pub count: u32,
        pub dim: u32,
        pub reserved0: u32,
        pub reserved1: u32,
    }
}

gpu_struct! {
    /// A 4-D permutation (output axis k is input axis `perm[k]` of `shape`) and what is
    /// added to it, each sum rounded to Elem as add.wgsl rounds: with `has_a`, `a + `
    /// the permuted value; with `has_rows`, plus `rows[rows_offset + i % rows_len]` (a
    /// trailing broadcast, e.g. frame positions); with `has_bias`, plus a row of an
    /// action table as [`ActionBiasParams`] lays it over NCHW images (`hw`, `channels`,
    /// `frames` images per sample).
    pub struct PermuteParams {
        pub shape: [u32; 4],
        pub perm: [u32; 4],
        pub has_a: u32,
        pub has_rows: u32,
        pub rows_offset: u32,
        pub rows_len: u32,
        pub has_bias: u32,
        pub hw: u32,
        pub channels: u32,
        pub frames: u32,
    }
}

gpu_struct! {
    /// Multi-head attention over `sequences` independent sequences (see attention.wgsl).
    pub struct AttentionParams {
        pub sequences: u32,
        pub heads: u32,
        pub queries: u32,
        pub keys: u32,
        pub channels: u32,
        pub q_stride: u32,
        pub q_offset: u32,
        pub kv_stride: u32,
        pub k_offset: u32,
        pub v_offset: u32,
        pub causal: u32,
        /// Consecutive sequences that read the same keys and values.
        pub kv_share: u32,
        /// The first `prefix_keys` of each sequence's `keys` come from a second buffer
        /// (rows [sequence, prefix_keys] of the same stride and offsets), the rest from
        /// `kv` (rows [sequence, keys - prefix_keys]): a cache and the new rows need no
        /// concatenation. 0: all from `kv`.
        pub prefix_keys: u32,
        /// Self-attention within consecutive runs of `queries` rows that stops at row
        /// `rows` (the last run shorter: its queries and keys end there) and writes
        /// [rows, channels]; 0: every run whole.
        pub rows: u32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

gpu_struct! {
    /// Concatenation of [outer, a_inner] and [outer, b_inner] rows.
    pub struct ConcatParams {
        pub outer: u32,
        pub a_inner: u32,
        pub b_inner: u32,
        pub reserved: u32,
    }
}

gpu_struct! {
    /// `y = alpha · x[x_offset..] + beta · z[z_offset..]` over `len` values.
    pub struct AxpbyParams {
        pub len: u32,
        pub x_offset: u32,
        pub z_offset: u32,
        pub reserved: u32,
        pub alpha: f32,
        pub beta: f32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

gpu_struct! {
    /// `y = x + table[ids[sample], channel]` over `len` NCHW values (`frames` images per
    /// sample, planes of `hw`).
    pub struct ActionBiasParams {
        pub len: u32,
        pub hw: u32,
        pub channels: u32,
        pub frames: u32,
    }
}

gpu_struct! {
    pub struct GatherParams {
        pub rows: u32,
        pub width: u32,
        pub reserved0: u32,
        pub reserved1: u32,
    }
}

gpu_struct! {
    pub struct SegmentParams {
        pub rows: u32,
        pub width: u32,
        pub stride: u32,
        pub reserved: u32,
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

/// The largest attention head the attention kernel holds in registers.
pub const MAX_HEAD_SIZE: usize = 64;

/// The largest head `attention_tiled.wgsl` takes (its loops over a head are this long).
pub const TILE_HEAD_SIZE: usize = 32;

/// The fewest queries a sequence has for [`Recorder::attention_after`] to give GPUs
/// `attention_tiled.wgsl` (a thread per query, the keys loaded once per block of
/// queries) rather than `attention_split.wgsl` (a workgroup per query): the refiner's
/// patches and the UNet's spatial attention, not the temporal layers' few frames.
const TILED_QUERIES: u32 = 16;

/// The fewest values of a group for which GPUs normalise it with 256 threads.
const WIDE_NORM_VALUES: u32 = 4096;

/// How `b` lines up with `a` in [`Recorder::add`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Broadcast {
    /// `b` holds one value per leading index (e.g. [N, C] over each H×W plane of NCHW).
    Leading,
    /// `b` repeats over the leading axes (e.g. [F, C] over [B, HW, F, C]).
    Trailing,
}

/// Row indices in a u32 storage buffer (for [`Recorder::gather`]); rewritable in place
/// (e.g. the action ids of a captured [`Plan`]).
#[derive(Clone, Debug)]
pub struct Indices {
    buffer: wgpu::Buffer,
    len: usize,
}

impl Indices {
    /// Indices already in a u32 storage buffer (e.g. written by another stage's kernel).
    pub fn from_buffer(buffer: &wgpu::Buffer, len: usize) -> Self {
        Self {
            buffer: buffer.clone(),
            len,
        }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Overwrites the indices (same count) before the next submission that reads them.
    pub fn write(&self, gpu: &GpuContext, values: &[u32]) {
        assert_eq!(values.len(), self.len, "index count");
        gpu.queue
            .write_buffer(&self.buffer, 0, bytemuck::cast_slice(values));
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

/// What a [`Recorder`] does with its work.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    /// Submitted in one submission by [`Recorder::submit`].
    Once,
    /// Submitted at every [`Recorder::boundary`] (so other work on the queue, such as the
    /// window's frames, waits for at most one part).
    Split,
    /// Kept as a [`Plan`] by [`Recorder::finish`].
    Capture,
}

/// Records kernels in one precision as steps; [`Recorder::submit`] sends them to the GPU
/// in one submission, or [`Recorder::finish`] keeps them as a [`Plan`] to run again.
/// Shapes that do not fit are programming errors and panic; running out of buffer space
/// is a [`GpuError`]. It counts the FLOPs it records as the trainer's counter does (2 per
/// multiply-add of convolutions, linear layers and both attention products over all keys;
/// norms and element-wise work not counted).
pub struct Recorder<'a> {
    gpu: &'a GpuContext,
    steps: Builder<'a>,
    flops: u64,
    mode: Mode,
    kernels: Kernels,
}

/// The most values per group the CPU group norm takes: its invocation loops 3/4 of this
/// many times plus once per channel, and lavapipe ends any invocation's loops after
/// 65,535 iterations in all (its loop limiter), silently. Larger groups take the
/// workgroup kernel.
pub const SERIAL_NORM_LIMIT: usize = 80_000;

impl GroupNormParams {
    /// The norm of NCHW images of `shape` into NCHW, in `groups` groups.
    fn nchw([n, c, h, w]: [usize; 4], groups: usize, silu: bool) -> Self {
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
    fn serial(&self) -> bool {
        let (c, groups, hw) = (self.channels, self.groups, self.hw);
        let quads = hw.is_multiple_of(4) || (hw == 1 && (c / groups).is_multiple_of(4));
        c.is_multiple_of(groups) && quads && (c / groups * hw) as usize <= SERIAL_NORM_LIMIT
    }
}

/// Which variant of each kernel a [`Recorder`] records. Every variant computes the same
/// thing and is parity-tested against PyTorch (tests/nn.rs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernels {
    /// One output per invocation everywhere: the reference forms.
    Simple,
    /// For CPU drivers (lavapipe): register tiles, and no workgroup barriers (a CPU
    /// driver runs a barrier as a switch between invocations).
    Cpu,
    /// For GPUs: register tiles, and workgroup reductions where they spread the work.
    Gpu,
}

/// Environment variable that forces a kernel variant: `simple`, `cpu` or `gpu`.
pub const KERNELS_ENV: &str = "UNICA_KERNELS";

impl Kernels {
    pub const ALL: [Kernels; 3] = [Kernels::Simple, Kernels::Cpu, Kernels::Gpu];

    /// [`KERNELS_ENV`] when set (an unknown value is reported and ignored), otherwise by
    /// the adapter: `Cpu` on a CPU driver, `Gpu` on anything else.
    pub fn for_adapter(gpu: &GpuContext) -> Self {
        if let Ok(value) = std::env::var(KERNELS_ENV) {
            match value.as_str() {
                "simple" => return Self::Simple,
                "cpu" => return Self::Cpu,
                "gpu" => return Self::Gpu,
                "" => {}
                other => log::warn!("{KERNELS_ENV}={other} is not simple, cpu or gpu; ignored"),
            }
        }
        if gpu.adapter.get_info().device_type == wgpu::DeviceType::Cpu {
            Self::Cpu
        } else {
            Self::Gpu
        }
    }
}

impl<'a> Recorder<'a> {
    fn with_mode(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
        mode: Mode,
    ) -> Self {
        Self {
            gpu,
            steps: Builder::new(gpu, pipelines, precision),
            flops: 0,
            mode,
            kernels: Kernels::for_adapter(gpu),
        }
    }

    pub fn new(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
    ) -> Self {
        Self::with_mode(gpu, pipelines, precision, Mode::Once)
    }

    /// A recorder that submits its work in parts, at every [`Recorder::boundary`].
    pub fn split(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
    ) -> Self {
        Self::with_mode(gpu, pipelines, precision, Mode::Split)
    }

    /// A recorder whose work is kept as a [`Plan`] ([`Recorder::finish`]).
    pub fn capture(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
    ) -> Self {
        Self::with_mode(gpu, pipelines, precision, Mode::Capture)
    }

    /// A point between stages (e.g. denoising steps): a split recorder submits what it
    /// has recorded so far; a capturing one starts a new part; nothing is read back.
    pub fn boundary(&mut self) {
        match self.mode {
            Mode::Once => {}
            Mode::Split => self.steps.submit(),
            Mode::Capture => self.steps.boundary(),
        }
    }

    /// Names the work recorded from here on (until the next call) for profiles
    /// ([`Plan::profile_stages`]).
    pub fn stage(&mut self, name: &'static str) {
        self.steps.stage(name, self.flops);
    }

    /// The steps recorded so far, for stages that record their own kernels into the
    /// same work (e.g. the splats of a frame after the model).
    pub fn steps(&mut self) -> &mut Builder<'a> {
        &mut self.steps
    }

    /// Records `kernels` from now on (tests of every variant).
    pub fn set_kernels(&mut self, kernels: Kernels) {
        self.kernels = kernels;
    }

    /// The variant this recorder records.
    pub fn kernels(&self) -> Kernels {
        self.kernels
    }

    /// FLOPs recorded so far (see the type's documentation).
    pub fn flops(&self) -> u64 {
        self.flops
    }

    pub fn gpu(&self) -> &GpuContext {
        self.gpu
    }

    pub fn precision(&self) -> Precision {
        self.steps.precision()
    }

    /// Submits everything recorded (a capturing recorder's work too, once).
    pub fn submit(mut self) {
        self.steps.submit();
    }

    /// The recorded work as a [`Plan`] (nothing is submitted).
    pub fn finish(self) -> Plan {
        self.steps.finish(self.flops)
    }

    /// A tensor of host values in this recorder's precision (written before the
    /// submission runs).
    pub fn upload(&self, label: &str, shape: &[usize], values: &[f32]) -> Result<Tensor, GpuError> {
        Tensor::upload(self.gpu, label, shape, values, self.precision())
    }

    fn output(&self, label: &str, shape: &[usize]) -> Result<Tensor, GpuError> {
        Tensor::empty(self.gpu, label, shape, self.precision())
    }

    fn check(&self, tensors: &[&Tensor]) {
        for t in tensors {
            assert_eq!(
                t.precision,
                self.precision(),
                "a {:?} tensor {:?} in a {:?} recorder",
                t.precision,
                t.shape,
                self.precision()
            );
        }
    }

    /// Records one dispatch of `shader`: `params` as a uniform at binding 0, then
    /// `buffers`.
    fn launch<P: bytemuck::Pod>(
        &mut self,
        shader: &Shader,
        params: &P,
        buffers: &[&Tensor],
        grid: Grid,
    ) {
        self.check(buffers);
        let buffers: Vec<&wgpu::Buffer> = buffers.iter().map(|t| &t.buffer).collect();
        self.steps.dispatch(shader, params, &buffers, grid);
    }

    /// Records a kernel of another stage (its own shader and parameter struct) into this
    /// recorder's work: `params` at binding 0, then `buffers`, over `grid`.
    pub fn dispatch<P: bytemuck::Pod>(
        &mut self,
        shader: &Shader,
        params: &P,
        buffers: &[&wgpu::Buffer],
        grid: Grid,
    ) {
        self.steps.dispatch(shader, params, buffers, grid);
    }

    /// Records a buffer-to-buffer copy.
    pub fn copy(&mut self, source: &wgpu::Buffer, target: &wgpu::Buffer, size: u64) {
        self.steps.copy(source, 0, target, 0, size);
    }

    /// `t`'s values as texels, copied from its buffer at this point of the work: the
    /// CPU-driver kernels read their big inputs this way (see [`Texels`]).
    fn texels(&mut self, t: &Tensor) -> Result<Texels, GpuError> {
        let texels = Texels::new(self.gpu, "texels", t.len(), t.precision)?;
        self.steps.copy_to_texels(&t.buffer, &texels);
        Ok(texels)
    }

    /// One thread per element at 64 threads per workgroup.
    pub fn grid(&self, threads: usize) -> Grid {
        self.steps.grid(threads)
    }

    /// `count` workgroups (kernels that give each workgroup one tile, query or group).
    pub fn workgroups(&self, count: usize) -> Grid {
        self.steps.workgroups(count)
    }

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
        // parity-tested (tests/nn.rs).
        if self.kernels == Kernels::Gpu {
            let tiles = n * c_out.div_ceil(8) * h_out * w_out.div_ceil(4);
            let grid = self.workgroups(tiles);
            self.launch(
                &kernels::CONV2D_SPLIT,
                &params,
                &[x, weight, bias, &y],
                grid,
            );
        } else if w_out >= 4 && self.kernels != Kernels::Simple {
            let grid = self.grid(n * c_out.div_ceil(8) * h_out * w_out.div_ceil(4));
            self.launch(
                &kernels::CONV2D_TILED,
                &params,
                &[x, weight, bias, &y],
                grid,
            );
        } else {
            let grid = self.grid(n * c_out.div_ceil(8) * h_out * w_out);
            self.launch(&kernels::CONV2D, &params, &[x, weight, bias, &y], grid);
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

    /// Whether [`Recorder::normed_conv3x3`] can fold the norm of `input` [N, C, H, W]
    /// (in `groups` groups) into the convolution: CPU drivers, rows of 8 pixels or more,
    /// at most [`NORM_STATS`] (sample, group) pairs, and a norm the serial kernel takes
    /// ([`GroupNormParams::serial`]: the fold computes its statistics). Whether it pays
    /// is the caller's choice: on lavapipe the folded norm is recomputed for every tile
    /// that reads a value (3·⌈c_out / 8⌉ times), which costs more than the dispatch it
    /// saves (about 0.1 ms per million multiply-adds of the convolution; see
    /// `vae::Decoder::forward`).
    pub fn can_fold_norm(&self, [n, c, h, w]: [usize; 4], groups: usize) -> bool {
        self.kernels == Kernels::Cpu
            && w >= 8
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
            .dispatch_bound(&kernels::CONV3X3_S2_CPU, &params, &bound, grid);
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

    /// Records `conv3x3.wgsl` (or, for CPU drivers, `conv3x3_cpu.wgsl`, which reads the
    /// input and the weights as texels) over `x` and `weights`, then `rest`: bias, addend,
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
        if self.kernels == Kernels::Cpu {
            let input = self.texels(x)?;
            let packed = weights.packed.constant_texels(self.gpu)?;
            let mut bound = vec![Bound::Texels(&input), Bound::Texels(packed)];
            bound.extend(rest);
            bound.extend(norm.map(|t| Bound::Buffer(&t.buffer)));
            let kernel = if params.norm_groups != 0 {
                &kernels::CONV3X3_NORMED_CPU
            } else {
                &kernels::CONV3X3_CPU
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
            self.steps
                .dispatch_bound(&kernels::CONV3X3, params, &bound, grid);
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
        self.steps
            .dispatch(&kernels::CONV1X1, &params, &buffers, grid);
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
            .dispatch_bound(&kernels::CONV1X1_CPU, params, &bound, grid);
        Ok(())
    }

    /// The concatenation of NCHW `a` and `b` along the channels held only as texels,
    /// copied from the two (no kernel), for a ResBlock that reads it only through its
    /// first group norm (`groups`) and its 1×1 skip ([`Recorder::group_norm_of_texels`],
    /// [`Recorder::conv1x1_of_texels`]). None where those would not read texels: other
    /// kernel variants, planes of pixels not a multiple of 4, groups too large for the
    /// serial norm.
    pub fn concat_texels(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        groups: usize,
    ) -> Result<Option<(Texels, [usize; 4])>, GpuError> {
        let (&[n, ca, h, w], &[nb, cb, hb, wb]) = (&a.shape[..], &b.shape[..]) else {
            panic!("NCHW concatenation of {:?} and {:?}", a.shape, b.shape)
        };
        assert_eq!(
            (n, h, w),
            (nb, hb, wb),
            "concatenating {:?} and {:?}",
            a.shape,
            b.shape
        );
        let c = ca + cb;
        let norm = GroupNormParams::nchw([n, c, h, w], groups, true);
        if !(self.kernels == Kernels::Cpu && (h * w).is_multiple_of(4) && norm.serial()) {
            return Ok(None);
        }
        self.check(&[a, b]);
        let texels = Texels::new(self.gpu, "concat texels", n * c * h * w, self.precision())?;
        let (a_texels, b_texels) = ((ca * h * w / 4) as u32, (cb * h * w / 4) as u32);
        let texel_bytes = u64::from(texels.texel_bytes());
        for image in 0..n as u32 {
            let first = image * (a_texels + b_texels);
            let a_offset = u64::from(image * a_texels) * texel_bytes;
            let b_offset = u64::from(image * b_texels) * texel_bytes;
            self.steps
                .copy_range_to_texels(&a.buffer, a_offset, &texels, first, a_texels);
            self.steps.copy_range_to_texels(
                &b.buffer,
                b_offset,
                &texels,
                first + a_texels,
                b_texels,
            );
        }
        Ok(Some((texels, [n, c, h, w])))
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

    /// Nearest-neighbour ×2 upsampling of an NCHW tensor.
    pub fn upsample_nearest2x(&mut self, x: &Tensor) -> Result<Tensor, GpuError> {
        let [n, c, h, w] = x.shape[..] else {
            panic!("upsample input must be NCHW, got {:?}", x.shape)
        };
        let y = self.output("upsample.y", &[n, c, 2 * h, 2 * w])?;
        let params = UpsampleParams {
            planes: (n * c) as u32,
            h_in: h as u32,
            w_in: w as u32,
            reserved: 0,
        };
        let grid = self.grid(y.len());
        self.launch(&kernels::UPSAMPLE_NEAREST, &params, &[x, &y], grid);
        Ok(y)
    }

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
            &kernels::GROUP_NORM_WIDE
        } else {
            &kernels::GROUP_NORM
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
            .dispatch_bound(&kernels::GROUP_NORM_SERIAL, params, &bound, grid);
        Ok(())
    }

    /// `y = act(x) Wᵀ + b` over the last axis of `x`, `weight` [outputs, inputs]; act is
    /// SiLU when `input_silu` is set.
    pub fn linear(
        &mut self,
        x: &Tensor,
        weight: &Tensor,
        bias: &Tensor,
        input_silu: bool,
    ) -> Result<Tensor, GpuError> {
        self.linear_plus(x, weight, bias, input_silu, None)
    }

    /// `residual + linear(x)` in one dispatch (`residual` of the output's shape), the
    /// sum add.wgsl would make after [`Recorder::linear`]. `weight` is constant: the
    /// CPU-driver kernel reads the texels copied from it on first use.
    pub fn linear_plus(
        &mut self,
        x: &Tensor,
        weight: &Tensor,
        bias: &Tensor,
        input_silu: bool,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let inputs = *x.shape.last().expect("a tensor has a shape");
        let [outputs, w_inputs] = weight.shape[..] else {
            panic!(
                "linear weight must be [outputs, inputs], got {:?}",
                weight.shape
            )
        };
        assert_eq!(inputs, w_inputs, "linear input size mismatch");
        let mut shape = x.shape.clone();
        *shape.last_mut().expect("non-empty") = outputs;
        let y = self.output("linear.y", &shape)?;
        self.flops += 2 * (y.len() * inputs) as u64;
        let params = LinearParams {
            rows: (x.len() / inputs) as u32,
            inputs: inputs as u32,
            outputs: outputs as u32,
            input_silu: u32::from(input_silu),
            has_residual: u32::from(residual.is_some()),
            images: 0,
            hw: 1,
            has_table: 0,
            table_frames: 1,
            gather_rows: 0,
            norm_rows: 0,
            eps: GROUP_NORM_EPS,
        };
        if let Some(res) = residual {
            assert_eq!(res.len(), y.len(), "linear residual {:?}", res.shape);
        }
        // Without a residual its binding still exists; x stands in (unread).
        let residual = residual.unwrap_or(x);
        // For GPUs, a workgroup per tile of 4 rows × 4 outputs whatever the rows
        // (linear_split.wgsl: every linear layer sums in the same order, so the action
        // table equals the cross-attention it replaces bit for bit). Otherwise register
        // tiles of 4 rows × 4 outputs where there are rows to share a tile, one
        // invocation per output for fewer rows (the timestep and action embeddings):
        // both sum in the same order. All are parity-tested (tests/nn.rs).
        let rows = x.len() / inputs;
        if self.kernels == Kernels::Gpu {
            self.linear_split(&params, [x, weight, bias, residual], None, &y);
        } else if rows >= 4 && self.kernels != Kernels::Simple {
            if self.kernels == Kernels::Cpu && inputs.is_multiple_of(4) {
                self.check(&[x, weight, bias, residual]);
                let extras = LinearExtras {
                    residual: &residual.buffer,
                    table: None,
                    norm: None,
                };
                self.linear_cpu(&params, x, (weight, bias), extras, &y)?;
            } else {
                let grid = self.grid(rows.div_ceil(4) * outputs.div_ceil(4));
                self.launch(
                    &kernels::LINEAR_TILED,
                    &params,
                    &[x, weight, bias, residual, &y],
                    grid,
                );
            }
        } else {
            let grid = self.grid(y.len());
            self.launch(
                &kernels::LINEAR,
                &params,
                &[x, weight, bias, residual, &y],
                grid,
            );
        }
        Ok(y)
    }

    /// Records `linear_split.wgsl` over `inputs` (x, weight, bias, residual) and the
    /// optional action table (table, ids) into `y`: one workgroup per tile of 4 rows ×
    /// 4 outputs of `params`. Without a table the bias stands in for its bindings
    /// (unread).
    fn linear_split(
        &mut self,
        params: &LinearParams,
        inputs: [&Tensor; 4],
        table: Option<(&Tensor, &Indices)>,
        y: &Tensor,
    ) {
        let [x, weight, bias, residual] = inputs;
        self.check(&[x, weight, bias, residual, y]);
        let (table, ids) = table.map_or((&bias.buffer, &bias.buffer), |(t, i)| {
            (&t.buffer, &i.buffer)
        });
        let tiles = (params.rows as usize).div_ceil(4) * (params.outputs as usize).div_ceil(4);
        let grid = self.workgroups(tiles);
        let buffers = [
            &x.buffer,
            &weight.buffer,
            &bias.buffer,
            &residual.buffer,
            table,
            ids,
            &y.buffer,
        ];
        self.steps
            .dispatch(&kernels::LINEAR_SPLIT, params, &buffers, grid);
    }

    /// Records `linear_cpu.wgsl` over `x` into `y`: x and the constant weight as
    /// texels, then the bias, `extras` and the output, over tiles of 8 rows × 8 outputs
    /// of `params`. Absent extras keep their bindings: the bias and x stand in (unread).
    fn linear_cpu(
        &mut self,
        params: &LinearParams,
        x: &Tensor,
        layer: (&Tensor, &Tensor),
        extras: LinearExtras,
        y: &Tensor,
    ) -> Result<(), GpuError> {
        let (weight, bias) = layer;
        let input = self.texels(x)?;
        let weight = weight.constant_texels(self.gpu)?;
        let (table, ids) = extras.table.unwrap_or((&bias.buffer, &bias.buffer));
        let (gamma, beta) = match extras.norm {
            Some((gamma, beta)) => (
                gamma.constant_texels(self.gpu)?,
                beta.constant_texels(self.gpu)?,
            ),
            None => (&input, &input),
        };
        let bound = [
            Bound::Texels(&input),
            Bound::Texels(weight),
            Bound::Buffer(&bias.buffer),
            Bound::Buffer(extras.residual),
            Bound::Buffer(table),
            Bound::Buffer(ids),
            Bound::Texels(gamma),
            Bound::Texels(beta),
            Bound::Buffer(&y.buffer),
        ];
        let tiles = (params.rows as usize).div_ceil(8) * (params.outputs as usize).div_ceil(8);
        let grid = self.grid(tiles);
        self.steps
            .dispatch_bound(&kernels::LINEAR_CPU, params, &bound, grid);
        Ok(())
    }

    /// `a + permute(linear(x))`, plus an action-table row per sample with `table`
    /// (table, ids, images per sample): token rows `x` [N, HW, F, inputs] projected and
    /// put back into the NCHW images `a` [N·F, outputs, H, W] (image n·F + f), the
    /// attention layers' output projection and residual. Equal bit for bit to
    /// [`Recorder::linear`] then [`Recorder::add_permuted_bias`] (shape [N, HW, F, C],
    /// permutation [0, 2, 3, 1]), which other kernel variants record; for CPU drivers
    /// one dispatch (the linear kernel stores into the images). `weight` is constant.
    pub fn linear_to_images(
        &mut self,
        x: &Tensor,
        layer: (&Tensor, &Tensor),
        a: &Tensor,
        frames: usize,
        table: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        let (weight, bias) = layer;
        let [nf, c, h, w] = a.shape[..] else {
            panic!("NCHW residual expected, got {:?}", a.shape)
        };
        let inputs = *x.shape.last().expect("a tensor has a shape");
        assert_eq!(weight.shape, [c, inputs], "linear_to_images weight");
        assert!(nf.is_multiple_of(frames), "{nf} images in runs of {frames}");
        let (n, hw) = (nf / frames, h * w);
        let rows = x.len() / inputs;
        assert_eq!(rows, n * hw * frames, "{rows} tokens for {:?}", a.shape);
        if let Some((table, ids, per_sample)) = table {
            assert_eq!(table.shape[1], c, "action bias table {:?}", table.shape);
            assert_eq!(nf, ids.len * per_sample, "{} ids for {nf} images", ids.len);
        }
        let fused = self.kernels == Kernels::Gpu
            || (self.kernels == Kernels::Cpu && rows >= 4 && inputs.is_multiple_of(4));
        if !fused {
            let out = self.linear(x, weight, bias, false)?;
            return self.permute_plus(&out, [n, hw, frames, c], [0, 2, 3, 1], Some(a), None, table);
        }
        let y = self.output("linear.images", &a.shape)?;
        self.flops += 2 * (rows * c * inputs) as u64;
        let params = LinearParams {
            rows: rows as u32,
            inputs: inputs as u32,
            outputs: c as u32,
            input_silu: 0,
            has_residual: 1,
            images: frames as u32,
            hw: hw as u32,
            has_table: u32::from(table.is_some()),
            table_frames: table.map_or(1, |(_, _, per_sample)| per_sample as u32),
            gather_rows: 0,
            norm_rows: 0,
            eps: GROUP_NORM_EPS,
        };
        if self.kernels == Kernels::Gpu {
            let table = table.map(|(table, ids, _)| (table, ids));
            self.linear_split(&params, [x, weight, bias, a], table, &y);
            return Ok(y);
        }
        self.check(&[x, weight, bias, a]);
        if let Some((table, ..)) = table {
            self.check(&[table]);
        }
        let extras = LinearExtras {
            residual: &a.buffer,
            table: table.map(|(table, ids, _)| (&table.buffer, &ids.buffer)),
            norm: None,
        };
        self.linear_cpu(&params, x, (weight, bias), extras, &y)?;
        Ok(y)
    }

    /// `residual + linear(layer_norm(x[rows]))`: a linear layer over rows `rows` of x
    /// (all rows in order without it), each layer-normed first with `norm` (gamma,
    /// beta) when given, plus an optional residual of the output's shape: the
    /// refiner's norm, projection and serialisation gather. Equal bit for bit to
    /// [`Recorder::gather`], the layer norm ([`Recorder::group_norm`] with one group per
    /// row) and [`Recorder::linear_plus`] (other variants record them); for CPU drivers
    /// one dispatch. `weight`, gamma and beta are constant.
    pub fn linear_rows(
        &mut self,
        x: &Tensor,
        layer: (&Tensor, &Tensor),
        norm: Option<(&Tensor, &Tensor)>,
        rows: Option<&Indices>,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let (weight, bias) = layer;
        let [x_rows, inputs] = x.shape[..] else {
            panic!("linear rows of {:?}", x.shape)
        };
        let [outputs, w_inputs] = weight.shape[..] else {
            panic!("linear weight {:?}", weight.shape)
        };
        assert_eq!(inputs, w_inputs, "linear input size mismatch");
        let out_rows = rows.map_or(x_rows, |r| r.len);
        if let Some(res) = residual {
            assert_eq!(
                res.len(),
                out_rows * outputs,
                "linear residual {:?}",
                res.shape
            );
        }
        let fused = self.kernels == Kernels::Cpu && out_rows >= 4 && inputs.is_multiple_of(4);
        if !fused {
            let mut input = match rows {
                Some(rows) => self.gather(x, rows)?,
                None => x.clone(),
            };
            if let Some((gamma, beta)) = norm {
                let square = input.reshaped(&[out_rows, inputs, 1, 1]);
                input = self.group_norm(&square, gamma, beta, 1, false)?;
                input = input.reshaped(&[out_rows, inputs]);
            }
            return self.linear_plus(&input, weight, bias, false, residual);
        }
        let y = self.output("linear.rows", &[out_rows, outputs])?;
        self.flops += 2 * (out_rows * outputs * inputs) as u64;
        let params = LinearParams {
            rows: out_rows as u32,
            inputs: inputs as u32,
            outputs: outputs as u32,
            input_silu: 0,
            has_residual: u32::from(residual.is_some()),
            images: 0,
            hw: 1,
            has_table: 0,
            table_frames: 1,
            gather_rows: u32::from(rows.is_some()),
            norm_rows: u32::from(norm.is_some()),
            eps: GROUP_NORM_EPS,
        };
        let residual = residual.unwrap_or(x);
        self.check(&[x, weight, bias, residual]);
        if let Some((gamma, beta)) = norm {
            self.check(&[gamma, beta]);
        }
        // The row index rides in the ids binding (there is no action table).
        let extras = LinearExtras {
            residual: &residual.buffer,
            table: rows.map(|r| (&bias.buffer, &r.buffer)),
            norm,
        };
        self.linear_cpu(&params, x, (weight, bias), extras, &y)?;
        Ok(y)
    }

    /// `x` [N·F, C, H, W] plus row `ids[n]` of `table` [A, C] on every pixel of sample
    /// n's `frames` (F) images.
    pub fn add_action_bias(
        &mut self,
        x: &Tensor,
        table: &Tensor,
        ids: &Indices,
        frames: usize,
    ) -> Result<Tensor, GpuError> {
        let [nf, c, h, w] = x.shape[..] else {
            panic!("NCHW expected, got {:?}", x.shape)
        };
        assert_eq!(table.shape[1], c, "action bias table {:?}", table.shape);
        assert_eq!(nf, ids.len * frames, "{} ids for {nf} images", ids.len);
        self.check(&[x, table]);
        let y = self.output("action_bias.y", &x.shape)?;
        let params = ActionBiasParams {
            len: x.len() as u32,
            hw: (h * w) as u32,
            channels: c as u32,
            frames: frames as u32,
        };
        let grid = self.grid(y.len());
        let buffers = [&x.buffer, &table.buffer, &ids.buffer, &y.buffer];
        self.steps
            .dispatch(&kernels::ADD_ACTION_BIAS, &params, &buffers, grid);
        Ok(y)
    }

    /// `a + b`, where `b` is shaped like `a` or broadcast as `broadcast` says.
    pub fn add(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        broadcast: Broadcast,
    ) -> Result<Tensor, GpuError> {
        self.add_part(a, b, 0..b.len(), broadcast)
    }

    /// `a + b[part]`, the values `part` of `b` broadcast as `broadcast` says (e.g. some
    /// rows of a table of frame positions).
    pub fn add_part(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        part: std::ops::Range<usize>,
        broadcast: Broadcast,
    ) -> Result<Tensor, GpuError> {
        assert!(
            !part.is_empty() && part.end <= b.len() && a.len().is_multiple_of(part.len()),
            "cannot broadcast values {part:?} of {:?} onto {:?}",
            b.shape,
            a.shape
        );
        let y = self.output("add.y", &a.shape)?;
        let params = AddParams {
            len: a.len() as u32,
            per_value: match broadcast {
                Broadcast::Leading => (a.len() / part.len()) as u32,
                Broadcast::Trailing => 1,
            },
            b_len: part.len() as u32,
            b_offset: part.start as u32,
        };
        let grid = self.grid(y.len());
        self.launch(&kernels::ADD, &params, &[a, b, &y], grid);
        Ok(y)
    }

    /// A permutation of the axes of `x` seen as 4-D `shape` (output axis k is input axis
    /// `perm[k]`).
    pub fn permute(
        &mut self,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, None, None, None)
    }

    /// The permutation of `x` plus the values `part` of `rows` repeated over the leading
    /// axes (as [`Recorder::add_part`] with [`Broadcast::Trailing`] after the permute),
    /// in one dispatch.
    pub fn permute_add_rows(
        &mut self,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
        rows: &Tensor,
        part: std::ops::Range<usize>,
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, None, Some((rows, part)), None)
    }

    /// `a + permute(x)` in one dispatch: `x` viewed as `shape`, permuted as
    /// [`Recorder::permute`] does, must have `a`'s size; the result has `a`'s shape.
    pub fn add_permuted(
        &mut self,
        a: &Tensor,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, Some(a), None, None)
    }

    /// [`Recorder::add_permuted`] onto NCHW images `a`, then plus `table[ids[sample]]`
    /// per channel as [`Recorder::add_action_bias`] adds it (`frames` images per sample)
    /// — one pass, the same two roundings as the two ops.
    pub fn add_permuted_bias(
        &mut self,
        a: &Tensor,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
        bias: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, Some(a), None, bias)
    }

    /// permute.wgsl with what is added to the permuted values (see [`PermuteParams`]).
    fn permute_plus(
        &mut self,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
        a: Option<&Tensor>,
        rows: Option<(&Tensor, std::ops::Range<usize>)>,
        bias: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        assert_eq!(
            shape.iter().product::<usize>(),
            x.len(),
            "permute shape {shape:?} for {:?}",
            x.shape
        );
        let out_shape = match a {
            Some(a) => {
                assert_eq!(
                    a.len(),
                    x.len(),
                    "add_permuted: {:?} onto {:?}",
                    x.shape,
                    a.shape
                );
                a.shape.clone()
            }
            None => perm.map(|k| shape[k]).to_vec(),
        };
        if let Some((rows, part)) = &rows {
            assert!(
                !part.is_empty() && part.end <= rows.len() && x.len().is_multiple_of(part.len()),
                "cannot broadcast values {part:?} of {:?} onto {out_shape:?}",
                rows.shape
            );
        }
        let (hw, channels, frames) = match bias {
            Some((table, ids, frames)) => {
                let [nf, c, h, w] = out_shape[..] else {
                    panic!("NCHW expected, got {out_shape:?}")
                };
                assert_eq!(table.shape[1], c, "action bias table {:?}", table.shape);
                assert_eq!(nf, ids.len * frames, "{} ids for {nf} images", ids.len);
                (h * w, c, frames)
            }
            None => (1, 1, 1),
        };
        let y = self.output("permute.y", &out_shape)?;
        let part = rows.as_ref().map_or(0..1, |(_, part)| part.clone());
        let params = PermuteParams {
            shape: shape.map(|s| s as u32),
            perm: perm.map(|k| k as u32),
            has_a: u32::from(a.is_some()),
            has_rows: u32::from(rows.is_some()),
            rows_offset: part.start as u32,
            rows_len: part.len() as u32,
            has_bias: u32::from(bias.is_some()),
            hw: hw as u32,
            channels: channels as u32,
            frames: frames as u32,
        };
        // Absent addends keep their bindings; `x` stands in (unread).
        let a = a.unwrap_or(x);
        let rows = rows.map_or(x, |(rows, _)| rows);
        let (table, ids) = match bias {
            Some((table, ids, _)) => (table, &ids.buffer),
            None => (x, &x.buffer),
        };
        self.check(&[x, a, rows, table, &y]);
        let grid = self.grid(y.len());
        let buffers = [
            &x.buffer,
            &a.buffer,
            &rows.buffer,
            &table.buffer,
            ids,
            &y.buffer,
        ];
        self.steps
            .dispatch(&kernels::PERMUTE, &params, &buffers, grid);
        Ok(y)
    }

    /// `a` and `b` joined along `axis`; all other axes must agree. For GPUs two buffer
    /// copies per outer index (a copy command, not a dispatch) where the byte ranges are
    /// aligned, else `concat.wgsl`.
    pub fn concat(&mut self, a: &Tensor, b: &Tensor, axis: usize) -> Result<Tensor, GpuError> {
        assert!(
            a.shape.len() == b.shape.len()
                && a.shape
                    .iter()
                    .zip(&b.shape)
                    .enumerate()
                    .all(|(k, (x, y))| k == axis || x == y),
            "cannot concatenate {:?} and {:?} along axis {axis}",
            a.shape,
            b.shape
        );
        let outer: usize = a.shape[..axis].iter().product();
        let mut shape = a.shape.clone();
        shape[axis] += b.shape[axis];
        let y = self.output("concat.y", &shape)?;
        let params = ConcatParams {
            outer: outer as u32,
            a_inner: (a.len() / outer) as u32,
            b_inner: (b.len() / outer) as u32,
            reserved: 0,
        };
        // For GPUs two buffer copies per outer index where the byte ranges allow
        // (copies are aligned to 4 bytes): a copy command, not a dispatch.
        let bytes = self.precision().bytes();
        let (a_bytes, b_bytes) = (a.len() / outer * bytes, b.len() / outer * bytes);
        if self.kernels == Kernels::Gpu && a_bytes % 4 == 0 && b_bytes % 4 == 0 {
            self.check(&[a, b, &y]);
            for o in 0..outer {
                let at = (o * (a_bytes + b_bytes)) as u64;
                let (a_from, b_from) = ((o * a_bytes) as u64, (o * b_bytes) as u64);
                let steps = &mut self.steps;
                steps.copy(&a.buffer, a_from, &y.buffer, at, a_bytes as u64);
                steps.copy(
                    &b.buffer,
                    b_from,
                    &y.buffer,
                    at + a_bytes as u64,
                    b_bytes as u64,
                );
            }
            return Ok(y);
        }
        let grid = self.grid(y.len());
        self.launch(&kernels::CONCAT, &params, &[a, b, &y], grid);
        Ok(y)
    }

    /// `alpha · x + beta · z` of shape `shape`, read from `x` and `z` at value offsets
    /// (e.g. the halves of a batch).
    #[allow(clippy::too_many_arguments)]
    pub fn axpby(
        &mut self,
        alpha: f32,
        x: &Tensor,
        x_offset: usize,
        beta: f32,
        z: &Tensor,
        z_offset: usize,
        shape: &[usize],
    ) -> Result<Tensor, GpuError> {
        let y = self.output("axpby.y", shape)?;
        assert!(
            x_offset + y.len() <= x.len() && z_offset + y.len() <= z.len(),
            "axpby out of range"
        );
        let params = AxpbyParams {
            len: y.len() as u32,
            x_offset: x_offset as u32,
            z_offset: z_offset as u32,
            reserved: 0,
            alpha,
            beta,
            reserved1: 0,
            reserved2: 0,
        };
        let grid = self.grid(y.len());
        self.launch(&kernels::AXPBY, &params, &[x, z, &y], grid);
        Ok(y)
    }

    /// Multi-head attention; `q` rows and `kv` rows as `params` describes; the output is
    /// [sequences, queries, channels].
    pub fn attention(
        &mut self,
        q: &Tensor,
        kv: &Tensor,
        params: AttentionParams,
    ) -> Result<Tensor, GpuError> {
        self.attention_after(q, None, kv, params)
    }

    /// A temporal layer's qkv projection of `tokens` [S, C] (one new frame of S
    /// sequences) and its attention over the cached rows `cached` (`params.prefix_keys`
    /// a sequence) and the sequence's own key: [`Recorder::linear`] then
    /// [`Recorder::attention_after`] (`params` as that takes them, one query a
    /// sequence), which the simple kernels record. For CPU drivers one dispatch
    /// (`temporal_next.wgsl`: each invocation projects its own head's q, k and v), and
    /// for GPUs one (`temporal_next_split.wgsl`: a workgroup per sequence and head),
    /// each equal bit for bit to its variant's separate ops. `weight` is constant.
    pub fn temporal_next(
        &mut self,
        tokens: &Tensor,
        layer: (&Tensor, &Tensor),
        cached: &Tensor,
        params: AttentionParams,
    ) -> Result<Tensor, GpuError> {
        let (weight, bias) = layer;
        let c = params.channels as usize;
        let head = c / params.heads as usize;
        let fused = self.kernels == Kernels::Cpu
            && params.queries == 1
            && params.kv_share == 1
            && params.rows == 0
            && head <= 32
            && head.is_multiple_of(4)
            && [params.kv_stride, params.k_offset, params.v_offset]
                .iter()
                .all(|v| v % 4 == 0)
            && tokens.len() == params.sequences as usize * c
            && weight.shape == [3 * c, c];
        // For GPUs: the qkv rows as the separate linear stores them (q | k | v).
        let fused_gpu = self.kernels == Kernels::Gpu
            && params.queries == 1
            && params.kv_share == 1
            && params.rows == 0
            && params.keys == params.prefix_keys + 1
            && params.keys as usize <= crate::gpu::kernel::WORKGROUP_SIZE as usize
            && head <= MAX_HEAD_SIZE
            && (params.q_offset, params.k_offset, params.v_offset) == (0, c as u32, 2 * c as u32)
            && (params.q_stride, params.kv_stride) == (3 * c as u32, 3 * c as u32)
            && tokens.len() == params.sequences as usize * c
            && weight.shape == [3 * c, c];
        if fused_gpu {
            self.check(&[tokens, weight, bias, cached]);
            let sequences = params.sequences as usize;
            let y = self.output("temporal_next.y", &[sequences, 1, c])?;
            self.flops +=
                2 * (sequences * 3 * c * c) as u64 + 4 * (y.len() as u64) * u64::from(params.keys);
            let groups = sequences * params.heads as usize;
            let grid = self.workgroups(groups);
            self.launch(
                &kernels::TEMPORAL_NEXT_SPLIT,
                &params,
                &[tokens, weight, bias, cached, &y],
                grid,
            );
            return Ok(y);
        }
        if !fused {
            let qkv = self.linear(tokens, weight, bias, false)?;
            return self.attention_after(&qkv, Some(cached), &qkv, params);
        }
        self.check(&[tokens, weight, bias, cached]);
        let sequences = params.sequences as usize;
        let y = self.output("temporal_next.y", &[sequences, 1, c])?;
        // The FLOPs of the two ops it replaces.
        self.flops +=
            2 * (sequences * 3 * c * c) as u64 + 4 * (y.len() as u64) * u64::from(params.keys);
        let input = self.texels(tokens)?;
        let prefix = self.texels(cached)?;
        let weight = weight.constant_texels(self.gpu)?;
        let bound = [
            Bound::Texels(&input),
            Bound::Texels(weight),
            Bound::Buffer(&bias.buffer),
            Bound::Texels(&prefix),
            Bound::Buffer(&y.buffer),
        ];
        let grid = self.grid(sequences * params.heads as usize);
        self.steps
            .dispatch_bound(&kernels::TEMPORAL_NEXT, &params, &bound, grid);
        Ok(y)
    }

    /// [`Recorder::attention`] whose first `params.prefix_keys` keys of each sequence are
    /// the rows of `prefix` (e.g. a context cache) and the rest the rows of `kv`: the
    /// same keys in the same order as attention over their concatenation.
    pub fn attention_after(
        &mut self,
        q: &Tensor,
        prefix: Option<&Tensor>,
        kv: &Tensor,
        params: AttentionParams,
    ) -> Result<Tensor, GpuError> {
        assert_eq!(
            prefix.is_some(),
            params.prefix_keys > 0,
            "attention: a prefix buffer goes with prefix_keys"
        );
        assert!(
            params.prefix_keys <= params.keys,
            "attention prefix of {params:?}"
        );
        assert!(
            (params.channels / params.heads) as usize <= MAX_HEAD_SIZE,
            "attention heads of {} values (at most {MAX_HEAD_SIZE})",
            params.channels / params.heads
        );
        let shape = if params.rows > 0 {
            vec![params.rows as usize, params.channels as usize]
        } else {
            vec![
                params.sequences as usize,
                params.queries as usize,
                params.channels as usize,
            ]
        };
        let y = self.output("attention.y", &shape)?;
        // Each query row against its keys: a cut last run has fewer of both.
        let (run, c) = (params.queries as u64, params.channels as u64);
        self.flops += if params.rows > 0 {
            let (full, tail) = (params.rows as u64 / run, params.rows as u64 % run);
            4 * c * (full * run * run + tail * tail)
        } else {
            4 * (y.len() as u64) * params.keys as u64
        };
        let grid = self.grid((params.sequences * params.heads * params.queries) as usize);
        let head = params.channels / params.heads;
        let rows_in_vec4s = [
            head,
            params.q_stride,
            params.q_offset,
            params.kv_stride,
            params.k_offset,
            params.v_offset,
        ]
        .iter()
        .all(|v| v % 4 == 0);
        // The prefix binding must exist without a prefix; kv stands in (unread).
        let prefix = prefix.unwrap_or(kv);
        if self.kernels == Kernels::Cpu && head <= 32 && rows_in_vec4s {
            // q, the prefix and kv as texels (one copy of a buffer they share).
            self.check(&[q, prefix, kv]);
            let kv_texels = self.texels(kv)?;
            let same = |t: &Tensor| t.buffer == kv.buffer;
            let q_texels = if same(q) { None } else { Some(self.texels(q)?) };
            let prefix_texels = if same(prefix) {
                None
            } else {
                Some(self.texels(prefix)?)
            };
            let bound = [
                Bound::Texels(q_texels.as_ref().unwrap_or(&kv_texels)),
                Bound::Texels(prefix_texels.as_ref().unwrap_or(&kv_texels)),
                Bound::Texels(&kv_texels),
                Bound::Buffer(&y.buffer),
            ];
            self.steps
                .dispatch_bound(&kernels::ATTENTION_CPU, &params, &bound, grid);
        } else if self.kernels == Kernels::Gpu
            && params.queries >= TILED_QUERIES
            && head as usize <= TILE_HEAD_SIZE
            && head.is_multiple_of(4)
        {
            let blocks = params.queries.div_ceil(crate::gpu::kernel::WORKGROUP_SIZE);
            let grid = self.workgroups((params.sequences * params.heads * blocks) as usize);
            self.launch(
                &kernels::ATTENTION_TILED,
                &params,
                &[q, prefix, kv, &y],
                grid,
            );
        } else if self.kernels == Kernels::Gpu {
            // One workgroup per query (attention_split.wgsl), its threads splitting the
            // keys; a head's values are merged by its first head-size threads.
            const { assert!(MAX_HEAD_SIZE <= crate::gpu::kernel::WORKGROUP_SIZE as usize) };
            let queries = (params.sequences * params.heads * params.queries) as usize;
            let grid = self.workgroups(queries);
            self.launch(
                &kernels::ATTENTION_SPLIT,
                &params,
                &[q, prefix, kv, &y],
                grid,
            );
        } else {
            self.launch(&kernels::ATTENTION, &params, &[q, prefix, kv, &y], grid);
        }
        Ok(y)
    }

    /// The sinusoidal embedding of the timesteps in `t` (any shape) into `dim` values.
    pub fn timestep_embedding(&mut self, t: &Tensor, dim: usize) -> Result<Tensor, GpuError> {
        assert!(dim.is_multiple_of(2), "embedding size {dim} must be even");
        let y = self.output("timestep_embedding.y", &[t.len(), dim])?;
        let params = EmbeddingParams {
            count: t.len() as u32,
            dim: dim as u32,
            reserved0: 0,
            reserved1: 0,
        };
        let grid = self.grid(t.len() * dim / 2);
        self.launch(&kernels::TIMESTEP_EMBEDDING, &params, &[t, &y], grid);
        Ok(y)
    }

    /// Host row indices uploaded for [`Recorder::gather`].
    pub fn indices(&self, label: &str, values: &[u32]) -> Result<Indices, GpuError> {
        let bytes = (values.len().max(1) * 4) as u64;
        let buffer = self
            .gpu
            .storage_buffer(label, bytes, wgpu::BufferUsages::COPY_DST)?;
        self.gpu
            .queue
            .write_buffer(&buffer, 0, bytemuck::cast_slice(values));
        Ok(Indices {
            buffer,
            len: values.len(),
        })
    }

    /// `y[i, :] = x[index[i], :]` for a [R, D] `x`; the caller keeps indices below R.
    pub fn gather(&mut self, x: &Tensor, index: &Indices) -> Result<Tensor, GpuError> {
        let [_, width] = x.shape[..] else {
            panic!("gather needs a [rows, width] tensor, got {:?}", x.shape)
        };
        self.check(&[x]);
        let y = self.output("gather.y", &[index.len, width])?;
        let params = GatherParams {
            rows: index.len as u32,
            width: width as u32,
            reserved0: 0,
            reserved1: 0,
        };
        if self.kernels == Kernels::Cpu && width.is_multiple_of(4) {
            // Four values a texel of x.
            let input = self.texels(x)?;
            let grid = self.grid(y.len() / 4);
            let bound = [
                Bound::Buffer(&index.buffer),
                Bound::Texels(&input),
                Bound::Buffer(&y.buffer),
            ];
            self.steps
                .dispatch_bound(&kernels::GATHER_CPU, &params, &bound, grid);
            return Ok(y);
        }
        let grid = self.grid(y.len());
        self.dispatch(
            &kernels::GATHER,
            &params,
            &[&index.buffer, &x.buffer, &y.buffer],
            grid,
        );
        Ok(y)
    }

    /// The mean of each run of `stride` consecutive rows of a [R, D] `x` (the last run
    /// may be shorter): [ceil(R / stride), D].
    pub fn segment_mean(&mut self, x: &Tensor, stride: usize) -> Result<Tensor, GpuError> {
        let [rows, width] = x.shape[..] else {
            panic!(
                "segment mean needs a [rows, width] tensor, got {:?}",
                x.shape
            )
        };
        let y = self.output("segment_mean.y", &[rows.div_ceil(stride), width])?;
        let params = SegmentParams {
            rows: rows as u32,
            width: width as u32,
            stride: stride as u32,
            reserved: 0,
        };
        let grid = self.grid(y.len());
        self.launch(&kernels::SEGMENT_MEAN, &params, &[x, &y], grid);
        Ok(y)
    }
}

/// The shape of an NCHW tensor.
fn nchw(x: &Tensor) -> [usize; 4] {
    let [n, c, h, w] = x.shape[..] else {
        panic!("an NCHW tensor expected, got {:?}", x.shape)
    };
    [n, c, h, w]
}

/// What `linear_cpu.wgsl` reads besides x, the weight and the bias: the residual buffer
/// (read where `has_residual` or `images` says), an action table and ids (or the row
/// index in the ids binding), and a layer norm's gamma and beta.
struct LinearExtras<'t> {
    residual: &'t wgpu::Buffer,
    table: Option<(&'t wgpu::Buffer, &'t wgpu::Buffer)>,
    norm: Option<(&'t Tensor, &'t Tensor)>,
}
