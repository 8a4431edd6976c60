//! The geometry model on the GPU: tensors in storage buffers and the WGSL kernels of the
//! VAE and UNet, pinned to the PyTorch trainer by parity tests (tests/nn.rs). Started:
//! 2-D convolution and nearest upsampling; the rest of the engine is open work.

use crate::gpu::kernel::{Grid, PipelineCache, dispatch};
use crate::gpu::{GpuContext, GpuError, readback, shaders};
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

fn uniform<T: bytemuck::Pod>(gpu: &GpuContext, value: &T) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    gpu.device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("nn params"),
            contents: bytemuck::bytes_of(value),
            usage: wgpu::BufferUsages::UNIFORM,
        })
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
    let params = uniform(gpu, &params);
    // A bias binding must exist even without a bias; the weight stands in (unread).
    let bias = bias.map_or(&weight.buffer, |b| &b.buffer);
    let pipeline = cache.get(&gpu.device, &shaders::CONV2D, "main");
    dispatch(
        &gpu.device,
        encoder,
        pipeline,
        &[&params, &x.buffer, &weight.buffer, bias, &y.buffer],
        grid(gpu, y.len()),
        None,
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
    let params = uniform(
        gpu,
        &UpsampleParams {
            planes: (n * c) as u32,
            h_in: h as u32,
            w_in: w as u32,
            reserved: 0,
        },
    );
    let pipeline = cache.get(&gpu.device, &shaders::UPSAMPLE_NEAREST, "main");
    dispatch(
        &gpu.device,
        encoder,
        pipeline,
        &[&params, &x.buffer, &y.buffer],
        grid(gpu, y.len()),
        None,
    );
    Ok(y)
}
