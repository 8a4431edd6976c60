//! Appearance (DESIGN §7): Gaussian splats from position maps. Built so far: the world
//! alignment, the 3DGS PLY format, the projection with a CPU reference renderer, the
//! WGSL tile rasterizer and the foreground-aware map upscale; fitted base splats and the
//! refiner are open work (issue #6).

pub mod align;
pub mod base;
pub mod composite;
pub mod ply;
pub mod project;
pub mod raster;
pub mod upscale;
