//! A tensor in a GPU storage buffer (f32 or f16 storage), NCHW for images.

use std::sync::{Arc, OnceLock};

use crate::gpu::kernel::Precision;
use crate::gpu::texels::Texels;
use crate::gpu::{GpuContext, GpuError, readback};

/// Values in a storage buffer; cloning shares the buffer (and its constant texels).
#[derive(Clone, Debug)]
pub struct Tensor {
    pub buffer: wgpu::Buffer,
    pub shape: Vec<usize>,
    pub precision: Precision,
    /// A copy as texels, made on first use by [`Tensor::constant_texels`].
    constant: Arc<OnceLock<Texels>>,
}

impl Tensor {
    /// Size in bytes, padded to 16 so f16 tensors of odd length still bind and copy, and
    /// every tensor copies into whole texels (four values; see [`Texels`]).
    fn bytes(len: usize, precision: Precision) -> u64 {
        ((len.max(1) * precision.bytes()) as u64).next_multiple_of(16)
    }

    /// A tensor over an existing buffer (at least the values' bytes long).
    pub fn from_buffer(buffer: wgpu::Buffer, shape: &[usize], precision: Precision) -> Self {
        let len: usize = shape.iter().product();
        assert!(
            buffer.size() >= (len * precision.bytes()) as u64,
            "a {}-byte buffer for a {shape:?} tensor",
            buffer.size()
        );
        Self {
            buffer,
            shape: shape.to_vec(),
            precision,
            constant: Arc::default(),
        }
    }

    /// The values as texels, for a tensor that never changes after it is written (the
    /// weights): copied once, on first use, in a submission of its own.
    pub fn constant_texels(&self, gpu: &GpuContext) -> Result<&Texels, GpuError> {
        if let Some(texels) = self.constant.get() {
            return Ok(texels);
        }
        let texels = Texels::new(gpu, "constant texels", self.len(), self.precision)?;
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("constant texels"),
            });
        texels.record_copy(&mut encoder, &self.buffer);
        gpu.submit([encoder.finish()]);
        Ok(self.constant.get_or_init(|| texels))
    }

    pub fn upload(
        gpu: &GpuContext,
        label: &str,
        shape: &[usize],
        values: &[f32],
        precision: Precision,
    ) -> Result<Self, GpuError> {
        assert_eq!(
            shape.iter().product::<usize>(),
            values.len(),
            "{label}: shape and data disagree"
        );
        let tensor = Self::empty(gpu, label, shape, precision)?;
        let mut bytes = precision.encode(values);
        bytes.resize(Self::bytes(values.len(), precision) as usize, 0);
        gpu.queue.write_buffer(&tensor.buffer, 0, &bytes);
        Ok(tensor)
    }

    pub fn empty(
        gpu: &GpuContext,
        label: &str,
        shape: &[usize],
        precision: Precision,
    ) -> Result<Self, GpuError> {
        let bytes = Self::bytes(shape.iter().product(), precision);
        let usage = wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        Ok(Self {
            buffer: gpu.storage_buffer(label, bytes, usage)?,
            shape: shape.to_vec(),
            precision,
            constant: Arc::default(),
        })
    }

    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The same values under another shape of the same size.
    pub fn reshaped(&self, shape: &[usize]) -> Self {
        assert_eq!(
            shape.iter().product::<usize>(),
            self.len(),
            "reshape {:?} to {shape:?}",
            self.shape
        );
        Self {
            shape: shape.to_vec(),
            ..self.clone()
        }
    }

    /// Reads the values back as f32 (tests, tools; never inside a generated frame).
    pub fn read(&self, gpu: &GpuContext) -> Result<Vec<f32>, GpuError> {
        let raw = readback::buffer(gpu, &self.buffer, "tensor")?;
        Ok(self
            .precision
            .decode(&raw[..self.len() * self.precision.bytes()]))
    }
}
