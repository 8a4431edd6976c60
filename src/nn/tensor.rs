//! A tensor in a GPU storage buffer (f32 or f16 storage), NCHW for images.

use crate::gpu::kernel::Precision;
use crate::gpu::{GpuContext, GpuError, readback};

/// Values in a storage buffer; cloning shares the buffer.
#[derive(Clone, Debug)]
pub struct Tensor {
    pub buffer: wgpu::Buffer,
    pub shape: Vec<usize>,
    pub precision: Precision,
}

impl Tensor {
    /// Size in bytes, padded to 4 so f16 tensors of odd length still bind and copy.
    fn bytes(len: usize, precision: Precision) -> u64 {
        ((len.max(1) * precision.bytes()) as u64).next_multiple_of(4)
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
