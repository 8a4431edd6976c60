//! The rasterizer's, compositor's and upscale's shaders (WGSL in `shaders/splat/`) with
//! the structs they share with Rust (declared beside their dispatch code).

use super::composite::CompositeParams;
use super::raster::{GpuSplat, ProjectedSplat, RadixParams, ScanParams, SplatFrame};
use super::upscale::UpscaleParams;
use crate::gpu::shaders::Shader;
use crate::wgsl_shader as shader;

pub const SPLAT_PROJECT: Shader = shader!("splat/splat_project.wgsl", [SplatFrame, GpuSplat, ProjectedSplat], f16: false, subgroups: false);
pub const SCAN_BLOCKS: Shader =
    shader!("splat/scan_blocks.wgsl", [ScanParams], f16: false, subgroups: false);
pub const SCAN_ADD: Shader =
    shader!("splat/scan_add.wgsl", [ScanParams], f16: false, subgroups: false);
pub const SPLAT_KEYS: Shader =
    shader!("splat/splat_keys.wgsl", [SplatFrame, ProjectedSplat], f16: false, subgroups: false);
pub const RADIX_HISTOGRAM: Shader =
    shader!("splat/radix_histogram.wgsl", [RadixParams], f16: false, subgroups: false);
pub const RADIX_SCATTER: Shader =
    shader!("splat/radix_scatter.wgsl", [RadixParams], f16: false, subgroups: false);
pub const SPLAT_RANGES: Shader =
    shader!("splat/splat_ranges.wgsl", [SplatFrame], f16: false, subgroups: false);
pub const SPLAT_RENDER: Shader =
    shader!("splat/splat_render.wgsl", [SplatFrame, ProjectedSplat], f16: false, subgroups: false)
        .with_uints(&[("TILE", super::project::TILE)]);
pub const SPLAT_COMPOSITE: Shader =
    shader!("splat/splat_composite.wgsl", [CompositeParams], f16: false, subgroups: false);
pub const UPSCALE_MAP: Shader =
    shader!("splat/upscale_map.wgsl", [UpscaleParams], f16: false, subgroups: false);

/// The rasterizer's, compositor's and upscale's shaders.
pub const ALL: &[Shader] = &[
    SPLAT_PROJECT,
    SCAN_BLOCKS,
    SCAN_ADD,
    SPLAT_KEYS,
    RADIX_HISTOGRAM,
    RADIX_SCATTER,
    SPLAT_RANGES,
    SPLAT_RENDER,
    SPLAT_COMPOSITE,
    UPSCALE_MAP,
];
