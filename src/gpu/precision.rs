//! The element type kernels store (`Elem` in WGSL), f32 or f16, with its byte encoding.

use super::GpuContext;

/// Which element type kernels store (`Elem` in WGSL): f16 where the device has
/// SHADER_F16 and the caller wants it; arithmetic is f32 either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Precision {
    F32,
    F16,
}

impl Precision {
    /// Bytes per stored value.
    pub fn bytes(self) -> usize {
        match self {
            Self::F32 => 4,
            Self::F16 => 2,
        }
    }

    /// `values` as this precision's bytes (f16: rounded to nearest).
    pub fn encode(self, values: &[f32]) -> Vec<u8> {
        match self {
            Self::F32 => bytemuck::cast_slice(values).to_vec(),
            Self::F16 => {
                let halves: Vec<half::f16> =
                    values.iter().map(|&v| half::f16::from_f32(v)).collect();
                bytemuck::cast_slice(&halves).to_vec()
            }
        }
    }

    /// Stored bytes back to f32 values.
    pub fn decode(self, raw: &[u8]) -> Vec<f32> {
        match self {
            Self::F32 => bytemuck::pod_collect_to_vec(raw),
            Self::F16 => bytemuck::pod_collect_to_vec::<u8, half::f16>(raw)
                .iter()
                .map(|v| v.to_f32())
                .collect(),
        }
    }

    /// The best precision path the device supports (f16 storage halves bandwidth).
    pub fn preferred(gpu: &GpuContext) -> Self {
        if gpu.caps.shader_f16 {
            Self::F16
        } else {
            Self::F32
        }
    }
}
