//! The geometry model on the GPU: tensors in storage buffers, the WGSL kernels, the VAE
//! and the action-conditioned UNet loaded from a bundle, and the DDIM sampler with
//! classifier-free guidance — pinned to the PyTorch trainer by parity tests (tests/nn/).

pub mod bundle;
pub mod layers;
pub mod ops;
pub mod refiner;
pub mod sampler;
pub mod serialise;
mod tensor;
pub mod unet;
pub mod vae;
pub mod weights;

pub use bundle::Bundle;
pub use ops::{Broadcast, Kernels, Recorder};
pub use tensor::Tensor;
pub use weights::{LoadError, Weights};
