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
pub mod files;
pub mod gpu;
pub mod headless;
pub mod mesh;
pub mod nn;
pub mod posmap;
pub mod random;
pub mod render;
pub mod splat;
pub mod tensors;
