//! The models on the GPU: tensors in storage buffers, the WGSL kernels, the VAE, the
//! action-conditioned UNet, the splat refiner's network and the DDIM sampler with
//! classifier-free guidance, each loaded from named weights (the bundle that holds them
//! is `engine::bundle`) — pinned to the PyTorch trainer by parity tests (tests/nn/).

pub mod layers;
pub mod ops;
pub mod refiner;
pub mod sampler;
mod tensor;
pub mod unet;
pub mod vae;
pub mod weights;

pub use ops::{Broadcast, Kernels, Recorder};
pub use tensor::Tensor;
pub use weights::{LoadError, Weights};
