//! Model weights by name from a safetensors file (a bundle or a parity fixture), each
//! checked for name, dtype and shape as it is loaded; the first wrong one is named.

use crate::gpu::kernel::Precision;
use crate::gpu::{GpuContext, GpuError};
use crate::tensors::{TensorError, TensorFile};

use super::Tensor;

/// Why a model could not be loaded; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error(transparent)]
    Tensor(#[from] TensorError),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("{path}: {problem}")]
    Manifest { path: String, problem: String },
}

/// The tensors under one name prefix of a file, uploaded in one precision.
pub struct Weights<'a> {
    file: &'a TensorFile,
    gpu: &'a GpuContext,
    precision: Precision,
    prefix: String,
}

impl<'a> Weights<'a> {
    pub fn new(file: &'a TensorFile, gpu: &'a GpuContext, precision: Precision) -> Self {
        Self {
            file,
            gpu,
            precision,
            prefix: String::new(),
        }
    }

    /// The tensors under `name.` (PyTorch's submodule naming).
    pub fn at(&self, name: &str) -> Weights<'a> {
        Weights {
            prefix: format!("{}{name}.", self.prefix),
            ..*self
        }
    }

    /// A tensor's values on the host, which must have exactly `shape`.
    pub fn host(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, LoadError> {
        let wanted: Vec<Option<usize>> = shape.iter().map(|&s| Some(s)).collect();
        let full = format!("{}{name}", self.prefix);
        Ok(self.file.f32(&full, &wanted)?.0)
    }

    /// A tensor of exactly `shape` on the GPU.
    pub fn tensor(&self, name: &str, shape: &[usize]) -> Result<Tensor, LoadError> {
        let values = self.host(name, shape)?;
        let label = format!("{}{name}", self.prefix);
        Ok(Tensor::upload(
            self.gpu,
            &label,
            shape,
            &values,
            self.precision,
        )?)
    }

    /// The first `rows` rows (along the first axis) of a tensor of `shape`, on the GPU.
    pub fn rows(&self, name: &str, shape: &[usize], rows: usize) -> Result<Tensor, LoadError> {
        let values = self.host(name, shape)?;
        let per_row: usize = shape[1..].iter().product();
        let mut kept = shape.to_vec();
        kept[0] = rows;
        let label = format!("{}{name}", self.prefix);
        Ok(Tensor::upload(
            self.gpu,
            &label,
            &kept,
            &values[..rows * per_row],
            self.precision,
        )?)
    }
}
