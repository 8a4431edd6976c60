//! unica: a WASD-driven 3D avatar whose geometry comes from an action-conditioned latent
//! diffusion model run as wgpu compute shaders, drawn free-view (see README.md).

pub mod action;
pub mod app;
pub mod autorig;
pub mod avatar;
pub mod bench;
pub mod cli;
pub mod dataset;
pub mod engine;
pub mod eval;
pub mod files;
pub mod gpu;
pub mod headless;
pub mod make;
pub mod mesh;
pub mod nn;
pub mod posmap;
pub mod random;
pub mod render;
pub mod splat;
pub mod tensors;

/// Every WGSL shader of the crate, gathered from the stages that own them (tests check
/// that this covers every file under `shaders/` and that each parses and validates).
pub fn shaders() -> Vec<gpu::shaders::Shader> {
    [
        gpu::kernel::SHADERS,
        &nn::ops::shaders(),
        &splat::shaders(),
        engine::kernels::ALL,
        render::scene::ALL,
        render::composite::SHADERS,
        render::blit::SHADERS,
    ]
    .concat()
}
