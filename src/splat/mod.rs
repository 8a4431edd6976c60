//! Appearance (DESIGN §7): Gaussian splats from position maps — base splats in each
//! pixel's local surface frame, the foreground-aware map upscale, the projection with a
//! CPU reference renderer, the WGSL tile rasterizer, compositing, world alignment and the
//! 3DGS PLY format. The refiner is in `nn::refiner`; `engine::appearance` puts it all
//! together per frame.

pub mod align;
pub mod base;
pub mod composite;
pub mod frame;
pub mod kernels;
pub mod ply;
pub mod project;
pub mod raster;
pub mod upscale;
