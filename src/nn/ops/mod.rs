//! The geometry model's ops, recorded into one command encoder by a [`Recorder`]: this
//! file is the recorder's core (modes, stage boundaries, dispatch, upload, the kernel
//! variant); each op family has its file, which owns its parameter structs (shared with
//! WGSL), its shaders in every variant, its `Recorder` methods with the variant choice:
//! `conv` (convolutions), `norm` (group norms), `linear`, `attention`, `layout`
//! (upsampling, permutes, concatenation, gathers, segment means) and `arith` (adds,
//! axpby, the timestep embedding). Each op allocates its output and records one
//! dispatch, in the [`Kernels`] variant that suits the adapter (all variants compute the
//! same thing); nothing is read back.

mod arith;
mod attention;
mod conv;
mod layout;
mod linear;
mod norm;

pub use arith::{ActionBiasParams, AddParams, AxpbyParams, Broadcast, EmbeddingParams};
pub use attention::{AttentionParams, MAX_HEAD_SIZE, TILE_HEAD_SIZE};
pub use conv::{Conv2dParams, PackedConv};
pub use layout::{ConcatParams, GatherParams, PermuteParams, SegmentParams, UpsampleParams};
pub use linear::LinearParams;
pub use norm::{GROUP_NORM_EPS, GroupNormParams, InputNorm, NORM_STATS, SERIAL_NORM_LIMIT};

use super::Tensor;
use crate::gpu::kernel::{Grid, PipelineCache, Precision};
pub use crate::gpu::plan::{Builder, Plan};
use crate::gpu::shaders::Shader;
use crate::gpu::texels::Texels;
use crate::gpu::{GpuContext, GpuError};

/// Every shader of the model, from the op files that own them.
pub fn shaders() -> Vec<Shader> {
    [
        conv::SHADERS,
        norm::SHADERS,
        linear::SHADERS,
        attention::SHADERS,
        layout::SHADERS,
        arith::SHADERS,
    ]
    .concat()
}

pub use crate::gpu::Indices;

/// What a [`Recorder`] does with its work.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mode {
    /// Submitted in one submission by [`Recorder::submit`].
    Once,
    /// Kept as a [`Plan`] by [`Recorder::finish`].
    Capture,
}

/// Which variant of each kernel a [`Recorder`] records. Every variant computes the same
/// thing and is parity-tested against PyTorch (tests/nn/).
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
        if gpu.cpu_driver() {
            Self::Cpu
        } else {
            Self::Gpu
        }
    }
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

impl<'a> Recorder<'a> {
    /// A recorder whose work [`Recorder::submit`] submits at once.
    pub fn new(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
    ) -> Self {
        Self {
            gpu,
            steps: Builder::new(gpu, pipelines, precision),
            flops: 0,
            mode: Mode::Once,
            kernels: Kernels::for_adapter(gpu),
        }
    }

    /// A recorder whose work is kept as a [`Plan`] ([`Recorder::finish`]).
    pub fn capture(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
    ) -> Self {
        let once = Self::new(gpu, pipelines, precision);
        Self {
            mode: Mode::Capture,
            ..once
        }
    }

    /// A point between stages (e.g. denoising steps): a capturing recorder starts a new
    /// part of its plan (submitted in parts beside a window); nothing is read back.
    pub fn boundary(&mut self) {
        match self.mode {
            Mode::Once => {}
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
}

/// The shape of an NCHW tensor.
fn nchw(x: &Tensor) -> [usize; 4] {
    let [n, c, h, w] = x.shape[..] else {
        panic!("an NCHW tensor expected, got {:?}", x.shape)
    };
    [n, c, h, w]
}
