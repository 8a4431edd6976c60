//! Copying GPU buffers and textures back to the host (tests, recording, screenshots).
//! Every readback blocks until the copy is done; none happens inside a generated frame.

use super::{GpuContext, GpuError};

/// The whole contents of `buffer` (needs COPY_SRC).
pub fn buffer(gpu: &GpuContext, buffer: &wgpu::Buffer, label: &str) -> Result<Vec<u8>, GpuError> {
    let staging = gpu.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback staging"),
        size: buffer.size(),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, buffer.size());
    gpu.submit([encoder.finish()]);
    map(gpu, &staging, label)
}

fn map(gpu: &GpuContext, staging: &wgpu::Buffer, label: &str) -> Result<Vec<u8>, GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    staging
        .slice(..)
        .map_async(wgpu::MapMode::Read, move |result| {
            let _ = tx.send(result);
        });
    gpu.wait_idle();
    let failed = |reason: String| GpuError::Readback {
        label: label.into(),
        reason,
    };
    rx.recv()
        .map_err(|_| failed("the map callback never ran".into()))?
        .map_err(|e| failed(e.to_string()))?;
    gpu.counters.readback(staging.size());
    let data = staging
        .slice(..)
        .get_mapped_range()
        .map_err(|e| failed(e.to_string()))?
        .to_vec();
    staging.unmap();
    Ok(data)
}

/// An RGBA8 texture's pixels, tightly packed rows (needs COPY_SRC, format Rgba8Unorm[Srgb]).
pub fn rgba_texture(
    gpu: &GpuContext,
    texture: &wgpu::Texture,
) -> Result<image::RgbaImage, GpuError> {
    let (width, height) = (texture.width(), texture.height());
    let row = width * 4;
    let padded_row = row.next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
    let staging = gpu.create_buffer(&wgpu::BufferDescriptor {
        label: Some("texture readback"),
        size: padded_row as u64 * height as u64,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    encoder.copy_texture_to_buffer(
        texture.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &staging,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded_row),
                rows_per_image: Some(height),
            },
        },
        texture.size(),
    );
    gpu.submit([encoder.finish()]);
    let padded = map(gpu, &staging, "texture")?;
    let mut pixels = Vec::with_capacity((row * height) as usize);
    for y in 0..height as usize {
        let start = y * padded_row as usize;
        pixels.extend_from_slice(&padded[start..start + row as usize]);
    }
    Ok(image::RgbaImage::from_raw(width, height, pixels).expect("buffer sized for the image"))
}
