//! Flat arrays held in 2-D textures ("texels"): four values a texel, [`TEXEL_ROW`] texels
//! a row, read in WGSL with the prelude's `texel(t, i)` (texel `i`, values 4i … 4i + 3).
//!
//! Why: on a CPU driver (Mesa lavapipe) a storage-buffer load is a loop over the SIMD
//! lanes with two branches per lane and value, while a texture fetch is one vector
//! gather. A register-tiled product reading both operands as texels ran 8× faster than
//! the same kernel reading storage buffers (18 against 2.3 GFLOP/s, measured here). The
//! CPU-driver kernels therefore read their big operands as texels: constant arrays
//! (weights) get theirs once ([`Texels::upload`]), and a tensor written by an earlier
//! kernel is copied into its texels just before the kernel that reads it
//! ([`Texels::record_copy`]: a plain copy, no shader).

use super::precision::Precision;
use super::{GpuContext, GpuError};

/// Texels per texture row (a power of two: the WGSL side splits an index with a mask).
pub const TEXEL_ROW: u32 = 1024;

/// Values per texel.
pub const TEXEL_VALUES: usize = 4;

/// A flat array of `len` values (f32 or f16 as stored, or u32) in a texture.
#[derive(Clone, Debug)]
pub struct Texels {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    /// Texels holding values (the last may be part padding).
    pub texels: u32,
    /// Bytes per texel.
    texel_bytes: u32,
}

impl Texels {
    /// Room for `len` values of `precision`, uninitialised (WGSL: `texture_2d<f32>`).
    pub fn new(
        gpu: &GpuContext,
        label: &str,
        len: usize,
        precision: Precision,
    ) -> Result<Self, GpuError> {
        Self::with_format(gpu, label, len, Self::format(precision))
    }

    /// Room for `len` u32 values, uninitialised (WGSL: `texture_2d<u32>`, read with the
    /// prelude's `texel_u32`).
    pub fn new_u32(gpu: &GpuContext, label: &str, len: usize) -> Result<Self, GpuError> {
        Self::with_format(gpu, label, len, wgpu::TextureFormat::Rgba32Uint)
    }

    fn with_format(
        gpu: &GpuContext,
        label: &str,
        len: usize,
        format: wgpu::TextureFormat,
    ) -> Result<Self, GpuError> {
        let texel_bytes = format
            .block_copy_size(None)
            .expect("an uncompressed colour format");
        let texels = len.max(1).div_ceil(TEXEL_VALUES);
        let rows = texels.div_ceil(TEXEL_ROW as usize);
        let max = gpu.device.limits().max_texture_dimension_2d as usize;
        if rows > max {
            return Err(GpuError::BufferTooLarge {
                label: format!("{label} (texels)"),
                size: (texels * texel_bytes as usize) as u64,
                max: (max * TEXEL_ROW as usize) as u64 * u64::from(texel_bytes),
            });
        }
        let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: TEXEL_ROW.min(texels as u32),
                height: rows as u32,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(Self {
            texture,
            view,
            texels: texels as u32,
            texel_bytes,
        })
    }

    /// The texture format of a precision: four stored values a texel.
    pub fn format(precision: Precision) -> wgpu::TextureFormat {
        match precision {
            Precision::F32 => wgpu::TextureFormat::Rgba32Float,
            Precision::F16 => wgpu::TextureFormat::Rgba16Float,
        }
    }

    /// Bytes per texel.
    pub fn texel_bytes(&self) -> u32 {
        self.texel_bytes
    }

    /// Texels holding a copy of `values` (made now, through the queue).
    pub fn upload(
        gpu: &GpuContext,
        label: &str,
        values: &[f32],
        precision: Precision,
    ) -> Result<Self, GpuError> {
        let texels = Self::new(gpu, label, values.len(), precision)?;
        let mut bytes = precision.encode(values);
        let size = texels.texture.size();
        let row_bytes = size.width * texels.texel_bytes();
        bytes.resize((row_bytes * size.height) as usize, 0);
        gpu.queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture: &texels.texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            &bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row_bytes),
                rows_per_image: None,
            },
            size,
        );
        Ok(texels)
    }

    /// Records a copy of `source` (whole texels' worth of values as stored) into the
    /// texels.
    pub fn record_copy(&self, encoder: &mut wgpu::CommandEncoder, source: &wgpu::Buffer) {
        self.record_copy_range(encoder, source, 0, 0, self.texels);
    }

    /// Records a copy of `count` texels of `source` from byte `offset` (a whole number of
    /// texels) into texels `first` … `first + count - 1`: a partial first row, the full
    /// rows, a partial last row, each one copy.
    pub fn record_copy_range(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        source: &wgpu::Buffer,
        offset: u64,
        first: u32,
        count: u32,
    ) {
        let texel_bytes = self.texel_bytes();
        assert!(
            first + count <= self.texels
                && offset.is_multiple_of(u64::from(texel_bytes))
                && source.size() >= offset + u64::from(count) * u64::from(texel_bytes),
            "texels {first} + {count} of {} from byte {offset} of a {}-byte buffer",
            self.texels,
            source.size()
        );
        let row_bytes = TEXEL_ROW * texel_bytes;
        // (first texel, texels) of each copy, none crossing a row end except whole rows.
        let mut at = first;
        let end = first + count;
        while at < end {
            let x = at % TEXEL_ROW;
            let rows = if x == 0 { (end - at) / TEXEL_ROW } else { 0 };
            let (width, height) = if rows > 0 {
                (TEXEL_ROW, rows)
            } else {
                ((TEXEL_ROW - x).min(end - at), 1)
            };
            encoder.copy_buffer_to_texture(
                wgpu::TexelCopyBufferInfo {
                    buffer: source,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: offset + u64::from(at - first) * u64::from(texel_bytes),
                        bytes_per_row: Some(row_bytes),
                        rows_per_image: None,
                    },
                },
                wgpu::TexelCopyTextureInfo {
                    texture: &self.texture,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x,
                        y: at / TEXEL_ROW,
                        z: 0,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
            );
            at += width * height;
        }
    }
}
