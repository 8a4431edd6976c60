//! The live loop's buffers (the window of context latents and maps, the noise, the
//! PCA's texels, the drawn points and the frame state), made once when the engine loads.

use glam::Vec3;

use super::bundle::Bundle;
use super::kernels::{FrameState, HeadingTurns};
use super::recentre::Start;
use crate::gpu::kernel::Precision;
use crate::gpu::texels::Texels;
use crate::gpu::{GpuContext, GpuError};
use crate::nn::Tensor;

/// The loop's buffers, made once at load.
pub(super) struct Live {
    /// [1, F-1, C, h, w]: the window of clean context latents, the encoding of `maps`
    /// turned to the model's heading at the start of each frame.
    pub(super) context: Tensor,
    /// [F-1, 3, S, S]: the window's frames as maps (background 0) in the world's frame,
    /// normalised so the last frame's root is at 0.5.
    pub(super) maps: Tensor,
    /// Scratch maps: `maps` turned to the model's heading (encoded), then the slid maps
    /// (copied into `maps`).
    pub(super) next_maps: Tensor,
    /// The frame's [`HeadingTurns`], written before each frame.
    pub(super) heading: wgpu::Buffer,
    /// [S²]: each pixel's foreground point, or `recentre::BACKGROUND`.
    pub(super) point_of: wgpu::Buffer,
    /// [1, C, h, w]: the frame's starting noise, written before each frame.
    pub(super) noise: Tensor,
    pub(super) pixels: wgpu::Buffer,
    pub(super) waist: wgpu::Buffer,
    /// 3N clamped normalised values.
    pub(super) unit: wgpu::Buffer,
    /// The same as texels (copied after each frame's clamping), the PCA mean, the
    /// basis with rows padded to whole texels, and the coefficients: the PCA kernels
    /// read these (src/gpu/texels.rs).
    pub(super) unit_texels: Texels,
    pub(super) mean: Texels,
    pub(super) basis: Texels,
    pub(super) coefficients: wgpu::Buffer,
    pub(super) coefficient_texels: Texels,
    /// 3N world-space values: the frame's drawn points.
    pub(super) points: wgpu::Buffer,
    pub(super) state: wgpu::Buffer,
    pub(super) components: usize,
}

pub(super) fn initial_state(root: Vec3) -> FrameState {
    FrameState {
        root: [root.x, root.y, root.z, 0.0],
        standing: 1,
        ..bytemuck::Zeroable::zeroed()
    }
}

impl Live {
    pub(super) fn new(
        gpu: &GpuContext,
        bundle: &Bundle,
        start: &Start,
        precision: Precision,
        start_root: Vec3,
    ) -> Result<Self, GpuError> {
        let cfg = &bundle.unet.cfg;
        let side = bundle.manifest.map_size / 8;
        let shape = [1, cfg.frames - 1, cfg.latent, side, side];
        let context = Tensor::empty(gpu, "engine.context", &shape, precision)?;
        let u32s = |label: &str, values: &[u32]| {
            gpu.storage_buffer_init(
                label,
                bytemuck::cast_slice(values),
                wgpu::BufferUsages::empty(),
            )
        };
        let d = 3 * bundle.pixels.len();
        let components = bundle.pca_basis.len() / d.max(1);
        let state = initial_state(start_root);
        let size = bundle.manifest.map_size;
        let map_shape = [cfg.frames - 1, 3, size, size];
        Ok(Self {
            maps: Tensor::upload(gpu, "engine.maps", &map_shape, &start.maps, precision)?,
            next_maps: Tensor::empty(gpu, "engine.next_maps", &map_shape, precision)?,
            point_of: u32s("engine.point_of", &start.point_of)?,
            heading: gpu.storage_buffer_init(
                "engine.heading",
                bytemuck::bytes_of(&HeadingTurns::new(0, true)),
                wgpu::BufferUsages::empty(),
            )?,
            noise: Tensor::empty(gpu, "engine.noise", &[1, cfg.latent, side, side], precision)?,
            context,
            pixels: u32s("engine.pixels", &bundle.pixels)?,
            waist: u32s("engine.waist", &bundle.waist)?,
            // Whole texels (16 bytes): both are copied into texels.
            unit: gpu.storage_buffer(
                "engine.unit",
                (4 * d.max(1) as u64).next_multiple_of(16),
                wgpu::BufferUsages::COPY_SRC,
            )?,
            unit_texels: Texels::new(gpu, "engine.unit", d, Precision::F32)?,
            mean: Texels::upload(gpu, "engine.pca_mean", &bundle.pca_mean, Precision::F32)?,
            basis: Texels::upload(
                gpu,
                "engine.pca_basis",
                &padded_rows(&bundle.pca_basis, d),
                Precision::F32,
            )?,
            coefficients: gpu.storage_buffer(
                "engine.pca_coefficients",
                (4 * components.max(1) as u64).next_multiple_of(16),
                wgpu::BufferUsages::COPY_SRC,
            )?,
            coefficient_texels: Texels::new(
                gpu,
                "engine.pca_coefficients",
                components,
                Precision::F32,
            )?,
            points: gpu.storage_buffer(
                "engine.points",
                4 * d as u64,
                // Written once by `Engine::draw_standing`, read back by tests.
                wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            )?,
            state: gpu.storage_buffer_init(
                "engine.state",
                bytemuck::bytes_of(&state),
                wgpu::BufferUsages::COPY_SRC,
            )?,
            components,
        })
    }
}

/// `values` in rows of `width`, each padded with zeros to a multiple of 4 (whole texels).
fn padded_rows(values: &[f32], width: usize) -> Vec<f32> {
    if width == 0 {
        return Vec::new();
    }
    let padded = width.next_multiple_of(4);
    let mut out = Vec::with_capacity(values.len() / width * padded);
    for row in values.chunks(width) {
        out.extend_from_slice(row);
        out.resize(out.len() + padded - row.len(), 0.0);
    }
    out
}
