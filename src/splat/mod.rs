//! Appearance (docs/architecture.md, Appearance): Gaussian splats from position maps —
//! base splats in each pixel's local surface frame, the foreground-aware map upscale, the
//! projection with a CPU reference renderer, the WGSL tile rasterizer, world
//! alignment and the splat file formats (3DGS PLY, SuperSplat's compressed PLY,
//! antimatter15 .splat, Z-up files). The refiner is in `nn::refiner`;
//! `engine::appearance` puts it all together per frame.

pub mod align;
pub mod base;
pub mod compressed_ply;
pub mod dotsplat;
pub mod files;
pub mod frame;
pub mod ply;
pub mod ply_layout;
pub mod project;
pub mod raster;
pub mod serialise;
pub mod upscale;

/// Every shader of the splat stage, from the files that dispatch them.
pub fn shaders() -> Vec<crate::gpu::shaders::Shader> {
    [raster::SHADERS, upscale::SHADERS, frame::ALL].concat()
}
