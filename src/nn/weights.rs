//! Model weights by name from a safetensors file (a bundle or a parity fixture), each
//! checked for name, dtype and shape as it is loaded; the first wrong one is named. For
//! benchmarks of a configuration without trained weights, a seeded random source.

use crate::gpu::kernel::Precision;
use crate::gpu::{GpuContext, GpuError};
use crate::tensors::{TensorError, TensorFile};

use super::Tensor;
use super::ops::PackedConv;

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

#[derive(Clone, Copy)]
enum Source<'a> {
    File(&'a TensorFile),
    /// Uniform values in ±0.1 from a generator seeded by each tensor's name.
    Random,
}

/// The tensors under one name prefix of a source, uploaded in one precision.
pub struct Weights<'a> {
    source: Source<'a>,
    gpu: &'a GpuContext,
    precision: Precision,
    prefix: String,
}

impl<'a> Weights<'a> {
    pub fn new(file: &'a TensorFile, gpu: &'a GpuContext, precision: Precision) -> Self {
        Self {
            source: Source::File(file),
            gpu,
            precision,
            prefix: String::new(),
        }
    }

    /// Deterministic random weights of whatever shape is asked for (benchmarks).
    pub fn random(gpu: &'a GpuContext, precision: Precision) -> Self {
        Self {
            source: Source::Random,
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
        let full = format!("{}{name}", self.prefix);
        match self.source {
            Source::File(file) => {
                let wanted: Vec<Option<usize>> = shape.iter().map(|&s| Some(s)).collect();
                let values = file.f32(&full, &wanted)?.0;
                match values.iter().position(|v| !v.is_finite()) {
                    Some(i) => Err(LoadError::Manifest {
                        path: file.path().display().to_string(),
                        problem: format!("tensor '{full}' holds {} at index {i}", values[i]),
                    }),
                    None => Ok(values),
                }
            }
            Source::Random => Ok(random_values(&full, shape.iter().product())),
        }
    }

    /// A 1-D int32 tensor of `len` strictly increasing indices, each below `bound`, on the
    /// host (a random source gives 0..len).
    pub fn indices(&self, name: &str, len: usize, bound: usize) -> Result<Vec<u32>, LoadError> {
        let full = format!("{}{name}", self.prefix);
        let file = match self.source {
            Source::File(file) => file,
            Source::Random => return Ok((0..len as u32).collect()),
        };
        let (values, _) = file.i32(&full, &[Some(len)])?;
        let fail = |problem: String| LoadError::Manifest {
            path: file.path().display().to_string(),
            problem: format!("tensor '{full}' {problem}"),
        };
        if let Some(i) = values.windows(2).position(|w| w[0] >= w[1]) {
            return Err(fail(format!(
                "is not increasing at index {} ({} then {})",
                i + 1,
                values[i],
                values[i + 1]
            )));
        }
        below(values, bound).map_err(fail)
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

impl<'a> Weights<'a> {
    /// The GPU the tensors go to.
    pub fn gpu(&self) -> &'a GpuContext {
        self.gpu
    }

    /// The precision the tensors are stored in.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// The first `keep` output channels of a k×k convolution's weights of shape
    /// [c_out, c_in, k, k], in both layouts [`PackedConv`] keeps.
    pub fn packed_conv(
        &self,
        name: &str,
        [c_out, c_in, kernel]: [usize; 3],
        keep: usize,
    ) -> Result<PackedConv, LoadError> {
        let values = self.host(name, &[c_out, c_in, kernel, kernel])?;
        let label = format!("{}{name}", self.prefix);
        Ok(PackedConv::new(
            self.gpu,
            &label,
            &values[..keep * c_in * kernel * kernel],
            [keep, c_in, kernel],
            self.precision,
        )?)
    }
}

/// `count` values uniform in ±0.1 from a 64-bit LCG seeded by an FNV-1a hash of `name`.
fn random_values(name: &str, count: usize) -> Vec<f32> {
    let mut state = name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    });
    (0..count)
        .map(|_| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.2
        })
        .collect()
}

/// Index values as u32, each checked to lie in 0..`bound`; otherwise what is wrong
/// ("holds V, outside 0..B"), for the caller to name the tensor.
pub(crate) fn below(values: Vec<i32>, bound: usize) -> Result<Vec<u32>, String> {
    match values.iter().find(|&&v| v < 0 || v as usize >= bound) {
        Some(bad) => Err(format!("holds {bad}, outside 0..{bound}")),
        None => Ok(values.into_iter().map(|v| v as u32).collect()),
    }
}
