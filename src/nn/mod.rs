//! The geometry model on the GPU: tensors in storage buffers and the WGSL kernels of the
//! VAE and UNet, pinned to the PyTorch trainer by parity tests (tests/nn.rs). Built so
//! far: convolution, upsampling, group norm (+SiLU), linear, adds, permutes, attention,
//! the timestep embedding; the VAE/UNet modules and the sampler are open work.

use crate::gpu::kernel::{Grid, PipelineCache, dispatch, uniform};
use crate::gpu::shaders::{self, Shader};
use crate::gpu::{GpuContext, GpuError, readback};
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
        pub reserved: u32,
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
        pub reserved0: u32,
        pub reserved1: u32,
    }
}

gpu_struct! {
    /// A fully connected layer over `rows` rows.
    pub struct LinearParams {
        pub rows: u32,
        pub inputs: u32,
        pub outputs: u32,
        pub input_silu: u32,
    }
}

gpu_struct! {
    /// `y[i] = a[i] + b[(i / per_value) % b_len]` over `len` values.
    pub struct AddParams {
        pub len: u32,
        pub per_value: u32,
        pub b_len: u32,
        pub reserved: u32,
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
    /// A 4-D permutation: output axis k is input axis `perm[k]` of `shape`.
    pub struct PermuteParams {
        pub shape: [u32; 4],
        pub perm: [u32; 4],
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
        pub reserved: u32,
    }
}

/// The epsilon of every group norm in the trainer's models.
pub const GROUP_NORM_EPS: f32 = 1e-5;

/// An f32 tensor in a GPU storage buffer, NCHW for images.
pub struct Tensor {
    pub buffer: wgpu::Buffer,
    pub shape: Vec<usize>,
}

impl Tensor {
    pub fn upload(
        gpu: &GpuContext,
        label: &str,
        shape: &[usize],
        values: &[f32],
    ) -> Result<Self, GpuError> {
        assert_eq!(
            shape.iter().product::<usize>(),
            values.len(),
            "{label}: shape and data disagree"
        );
        let buffer = gpu.storage_buffer_init(
            label,
            bytemuck::cast_slice(values),
            wgpu::BufferUsages::COPY_SRC,
        )?;
        Ok(Self {
            buffer,
            shape: shape.to_vec(),
        })
    }

    pub fn empty(gpu: &GpuContext, label: &str, shape: &[usize]) -> Result<Self, GpuError> {
        let bytes = 4 * shape.iter().product::<usize>().max(1) as u64;
        let buffer = gpu.storage_buffer(label, bytes, wgpu::BufferUsages::COPY_SRC)?;
        Ok(Self {
            buffer,
            shape: shape.to_vec(),
        })
    }

    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Reads the values back (tests and debugging; never inside a generated frame).
    pub fn read(&self, gpu: &GpuContext) -> Result<Vec<f32>, GpuError> {
        let raw = readback::buffer(gpu, &self.buffer, "tensor")?;
        Ok(bytemuck::cast_slice(&raw[..4 * self.len()]).to_vec())
    }
}

/// Records one dispatch of `shader`: `params` as a uniform at binding 0, then `buffers`.
#[allow(clippy::too_many_arguments)]
fn launch<P: bytemuck::Pod>(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    shader: &Shader,
    params: &P,
    buffers: &[&wgpu::Buffer],
    grid: Grid,
) {
    let params = uniform(&gpu.device, params);
    let bindings: Vec<&wgpu::Buffer> = std::iter::once(&params)
        .chain(buffers.iter().copied())
        .collect();
    let pipeline = cache.get(&gpu.device, shader, "main");
    dispatch(&gpu.device, encoder, pipeline, &bindings, grid, None);
}

fn grid(gpu: &GpuContext, elements: usize) -> Grid {
    Grid::for_elements(
        elements as u32,
        gpu.device.limits().max_compute_workgroups_per_dimension,
    )
}

/// Records `y = conv2d(x, weight) + bias` (square kernel, `stride`, zero padding `pad`).
#[allow(clippy::too_many_arguments)]
pub fn conv2d(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
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
    let y = Tensor::empty(gpu, "conv2d.y", &[n, c_out, h_out, w_out])?;
    let params = Conv2dParams {
        batch: n as u32,
        c_in: c_in as u32,
        c_out: c_out as u32,
        h_in: h_in as u32,
        w_in: w_in as u32,
        h_out: h_out as u32,
        w_out: w_out as u32,
        kernel: k as u32,
        stride: stride as u32,
        pad: pad as u32,
        has_bias: u32::from(bias.is_some()),
        reserved: 0,
    };
    // A bias binding must exist even without a bias; the weight stands in (unread).
    let bias = bias.map_or(&weight.buffer, |b| &b.buffer);
    launch(
        gpu,
        cache,
        encoder,
        &shaders::CONV2D,
        &params,
        &[&x.buffer, &weight.buffer, bias, &y.buffer],
        grid(gpu, y.len()),
    );
    Ok(y)
}

/// Records nearest-neighbour ×2 upsampling of an NCHW tensor.
pub fn upsample_nearest2x(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    x: &Tensor,
) -> Result<Tensor, GpuError> {
    let [n, c, h, w] = x.shape[..] else {
        panic!("upsample input must be NCHW, got {:?}", x.shape)
    };
    let y = Tensor::empty(gpu, "upsample.y", &[n, c, 2 * h, 2 * w])?;
    let params = UpsampleParams {
        planes: (n * c) as u32,
        h_in: h as u32,
        w_in: w as u32,
        reserved: 0,
    };
    launch(
        gpu,
        cache,
        encoder,
        &shaders::UPSAMPLE_NEAREST,
        &params,
        &[&x.buffer, &y.buffer],
        grid(gpu, y.len()),
    );
    Ok(y)
}

/// Records group normalisation of an NCHW tensor with the per-channel affine `gamma`,
/// `beta`, followed by SiLU when `silu` is set.
#[allow(clippy::too_many_arguments)]
pub fn group_norm(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    x: &Tensor,
    gamma: &Tensor,
    beta: &Tensor,
    groups: usize,
    silu: bool,
) -> Result<Tensor, GpuError> {
    let [n, c, h, w] = x.shape[..] else {
        panic!("group norm input must be NCHW, got {:?}", x.shape)
    };
    assert!(c % groups == 0, "{c} channels in {groups} groups");
    let y = Tensor::empty(gpu, "group_norm.y", &x.shape)?;
    let params = GroupNormParams {
        batch: n as u32,
        channels: c as u32,
        groups: groups as u32,
        hw: (h * w) as u32,
        eps: GROUP_NORM_EPS,
        silu: u32::from(silu),
        reserved0: 0,
        reserved1: 0,
    };
    // One workgroup per (sample, group).
    let grid = Grid::for_workgroups(
        (n * groups) as u32,
        gpu.device.limits().max_compute_workgroups_per_dimension,
    );
    let buffers = [&x.buffer, &gamma.buffer, &beta.buffer, &y.buffer];
    launch(
        gpu,
        cache,
        encoder,
        &shaders::GROUP_NORM,
        &params,
        &buffers,
        grid,
    );
    Ok(y)
}

/// Records `y = act(x) Wᵀ + b` for `x` of shape [rows, inputs] and `weight` [outputs,
/// inputs]; act is SiLU when `input_silu` is set.
#[allow(clippy::too_many_arguments)]
pub fn linear(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    x: &Tensor,
    weight: &Tensor,
    bias: &Tensor,
    input_silu: bool,
) -> Result<Tensor, GpuError> {
    let inputs = *x.shape.last().expect("a tensor has a shape");
    let rows = x.len() / inputs;
    let [outputs, w_inputs] = weight.shape[..] else {
        panic!(
            "linear weight must be [outputs, inputs], got {:?}",
            weight.shape
        )
    };
    assert_eq!(inputs, w_inputs, "linear input size mismatch");
    let mut shape = x.shape.clone();
    *shape.last_mut().expect("non-empty") = outputs;
    let y = Tensor::empty(gpu, "linear.y", &shape)?;
    let params = LinearParams {
        rows: rows as u32,
        inputs: inputs as u32,
        outputs: outputs as u32,
        input_silu: u32::from(input_silu),
    };
    launch(
        gpu,
        cache,
        encoder,
        &shaders::LINEAR,
        &params,
        &[&x.buffer, &weight.buffer, &bias.buffer, &y.buffer],
        grid(gpu, y.len()),
    );
    Ok(y)
}

/// How `b` lines up with `a` in [`add`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Broadcast {
    /// `b` holds one value per leading index (e.g. [N, C] over each H×W plane of NCHW).
    Leading,
    /// `b` repeats over the leading axes (e.g. [F, C] over [B, HW, F, C]).
    Trailing,
}

/// Records `a + b`, where `b` is shaped like `a` or broadcast as `broadcast` says.
pub fn add(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    a: &Tensor,
    b: &Tensor,
    broadcast: Broadcast,
) -> Result<Tensor, GpuError> {
    assert!(
        !b.is_empty() && a.len().is_multiple_of(b.len()),
        "cannot broadcast {:?} onto {:?}",
        b.shape,
        a.shape
    );
    let y = Tensor::empty(gpu, "add.y", &a.shape)?;
    let params = AddParams {
        len: a.len() as u32,
        per_value: match broadcast {
            Broadcast::Leading => (a.len() / b.len()) as u32,
            Broadcast::Trailing => 1,
        },
        b_len: b.len() as u32,
        reserved: 0,
    };
    launch(
        gpu,
        cache,
        encoder,
        &shaders::ADD,
        &params,
        &[&a.buffer, &b.buffer, &y.buffer],
        grid(gpu, y.len()),
    );
    Ok(y)
}

/// Records a permutation of a 4-D tensor's axes (output axis k is input axis `perm[k]`).
pub fn permute(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    x: &Tensor,
    shape: [usize; 4],
    perm: [usize; 4],
) -> Result<Tensor, GpuError> {
    assert_eq!(
        shape.iter().product::<usize>(),
        x.len(),
        "permute shape {shape:?} for {:?}",
        x.shape
    );
    let y = Tensor::empty(gpu, "permute.y", &perm.map(|k| shape[k]))?;
    let params = PermuteParams {
        shape: shape.map(|s| s as u32),
        perm: perm.map(|k| k as u32),
    };
    launch(
        gpu,
        cache,
        encoder,
        &shaders::PERMUTE,
        &params,
        &[&x.buffer, &y.buffer],
        grid(gpu, y.len()),
    );
    Ok(y)
}

/// Records multi-head attention; `q` rows and `kv` rows as described by `params`; the
/// output is [sequences, queries, channels].
pub fn attention(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    q: &Tensor,
    kv: &Tensor,
    params: AttentionParams,
) -> Result<Tensor, GpuError> {
    let shape = [
        params.sequences as usize,
        params.queries as usize,
        params.channels as usize,
    ];
    let y = Tensor::empty(gpu, "attention.y", &shape)?;
    let threads = (params.sequences * params.heads * params.queries) as usize;
    launch(
        gpu,
        cache,
        encoder,
        &shaders::ATTENTION,
        &params,
        &[&q.buffer, &kv.buffer, &y.buffer],
        grid(gpu, threads),
    );
    Ok(y)
}

/// Records the sinusoidal embedding of the timesteps in `t` (any shape) into `dim` values.
pub fn timestep_embedding(
    gpu: &GpuContext,
    cache: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    t: &Tensor,
    dim: usize,
) -> Result<Tensor, GpuError> {
    assert!(dim.is_multiple_of(2), "embedding size {dim} must be even");
    let y = Tensor::empty(gpu, "timestep_embedding.y", &[t.len(), dim])?;
    let params = EmbeddingParams {
        count: t.len() as u32,
        dim: dim as u32,
        reserved0: 0,
        reserved1: 0,
    };
    launch(
        gpu,
        cache,
        encoder,
        &shaders::TIMESTEP_EMBEDDING,
        &params,
        &[&t.buffer, &y.buffer],
        grid(gpu, t.len() * dim / 2),
    );
    Ok(y)
}
