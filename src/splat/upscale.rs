//! Foreground-aware upscaling of 3-channel maps (docs/architecture.md, Appearance: 128² →
//! 1024²): the GPU kernel (shaders/upscale_map.wgsl) and its CPU reference, the same
//! arithmetic in f32.

use crate::gpu::kernel::{Grid, PipelineCache, Precision, dispatch, uniform};
use crate::gpu::shaders::Shader;
use crate::gpu::{GpuContext, GpuError};
use crate::gpu_struct;
use crate::wgsl_shader as shader;

pub const UPSCALE_MAP: Shader =
    shader!("splat/upscale_map.wgsl", [UpscaleParams], f16: false, subgroups: false);

/// Every shader of this file (gathered by `splat::shaders`).
pub const SHADERS: &[Shader] = &[UPSCALE_MAP];

gpu_struct! {
    /// A `width × height` map upscaled by `factor`.
    pub struct UpscaleParams {
        pub width: u32,
        pub height: u32,
        pub factor: u32,
        pub reserved: u32,
    }
}

/// The CPU reference: `map` [3, h, w] and `mask` [h, w] → (map [3, h·f, w·f], mask).
pub fn upscale_reference(
    map: &[f32],
    mask: &[f32],
    width: usize,
    height: usize,
    factor: usize,
) -> (Vec<f32>, Vec<f32>) {
    let (w_out, h_out) = (width * factor, height * factor);
    let plane = width * height;
    let mut out = vec![0.0; 3 * w_out * h_out];
    let mut out_mask = vec![0.0; w_out * h_out];
    for oy in 0..h_out {
        for ox in 0..w_out {
            let sx = ((ox as f32 + 0.5) / factor as f32 - 0.5).clamp(0.0, (width - 1) as f32);
            let sy = ((oy as f32 + 0.5) / factor as f32 - 0.5).clamp(0.0, (height - 1) as f32);
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
            let (fx, fy) = (sx - x0 as f32, sy - y0 as f32);
            let corners = [
                y0 * width + x0,
                y0 * width + x1,
                y1 * width + x0,
                y1 * width + x1,
            ];
            let weights = [
                (1.0 - fx) * (1.0 - fy),
                fx * (1.0 - fy),
                (1.0 - fx) * fy,
                fx * fy,
            ];
            let mut m = 0.0;
            let mut v = [0.0f32; 3];
            for (c, wt) in corners.iter().zip(weights) {
                let wm = wt * mask[*c];
                m += wm;
                for (k, vk) in v.iter_mut().enumerate() {
                    *vk += wm * map[k * plane + c];
                }
            }
            let i = oy * w_out + ox;
            if m > 0.25 {
                out_mask[i] = 1.0;
                for (k, vk) in v.iter().enumerate() {
                    out[k * w_out * h_out + i] = vk / m;
                }
            }
        }
    }
    (out, out_mask)
}

/// Records the upscaling of `map` [3, h, w] with `mask` [h, w] (f32 storage buffers);
/// returns (map, mask) buffers at `factor` times the size.
#[allow(clippy::too_many_arguments)]
pub fn record(
    gpu: &GpuContext,
    pipelines: &mut PipelineCache,
    encoder: &mut wgpu::CommandEncoder,
    map: &wgpu::Buffer,
    mask: &wgpu::Buffer,
    width: usize,
    height: usize,
    factor: usize,
) -> Result<(wgpu::Buffer, wgpu::Buffer), GpuError> {
    let pixels = width * height * factor * factor;
    let usage = wgpu::BufferUsages::COPY_SRC;
    let out_map = gpu.storage_buffer("upscale.map", 12 * pixels as u64, usage)?;
    let out_mask = gpu.storage_buffer("upscale.mask", 4 * pixels as u64, usage)?;
    let params = UpscaleParams {
        width: width as u32,
        height: height as u32,
        factor: factor as u32,
        reserved: 0,
    };
    let params = uniform(gpu, &params);
    let pipeline = pipelines.get(&gpu.device, &UPSCALE_MAP, Precision::F32);
    let grid = Grid::for_elements(
        pixels as u32,
        gpu.device.limits().max_compute_workgroups_per_dimension,
    );
    dispatch(
        gpu,
        encoder,
        pipeline,
        &[&params, map, mask, &out_map, &out_mask],
        grid,
        None,
    );
    Ok((out_map, out_mask))
}

/// Upscales a host `map` [3, h, w] with its `mask` [h, w] on the GPU in one submission
/// and reads both back (tools, load-time layouts and the CPU reference path; never inside
/// a generated frame).
pub fn run(
    gpu: &GpuContext,
    pipelines: &mut PipelineCache,
    map: &[f32],
    mask: &[f32],
    width: usize,
    height: usize,
    factor: usize,
) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
    let usage = wgpu::BufferUsages::empty();
    let map = gpu.storage_buffer_init("upscale.in_map", bytemuck::cast_slice(map), usage)?;
    let mask = gpu.storage_buffer_init("upscale.in_mask", bytemuck::cast_slice(mask), usage)?;
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("upscale"),
        });
    let (out, out_mask) = record(
        gpu,
        pipelines,
        &mut encoder,
        &map,
        &mask,
        width,
        height,
        factor,
    )?;
    gpu.submit([encoder.finish()]);
    let read = |b: &wgpu::Buffer, label: &str| -> Result<Vec<f32>, GpuError> {
        Ok(bytemuck::pod_collect_to_vec(&crate::gpu::readback::buffer(
            gpu, b, label,
        )?))
    };
    Ok((
        read(&out, "upscaled map")?,
        read(&out_mask, "upscaled mask")?,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_constant_foreground_stays_constant_and_the_mask_grows_by_half_a_pixel() {
        // A 4×4 map whose 2×2 centre is foreground with value (1, 2, 3), upscaled ×4:
        // every kept pixel is exactly (1, 2, 3); the kept region is the centre block
        // widened until the interpolated mask falls to 0.25.
        let (w, h) = (4, 4);
        let mut mask = vec![0.0; 16];
        let mut map = vec![0.0; 48];
        for p in [5, 6, 9, 10] {
            mask[p] = 1.0;
            for k in 0..3 {
                map[k * 16 + p] = (k + 1) as f32;
            }
        }
        let (out, out_mask) = upscale_reference(&map, &mask, w, h, 4);
        let kept: Vec<usize> = (0..256).filter(|&i| out_mask[i] == 1.0).collect();
        for &i in &kept {
            assert_eq!([out[i], out[256 + i], out[512 + i]], [1.0, 2.0, 3.0]);
        }
        // Along a row through the centre the mask weight is 1 at source x in [1, 2] and
        // falls linearly outside, > 0.25 until 0.75 px beyond: source x in (0.25, 2.75),
        // i.e. output x in (3, 13) → columns 3..=12 with the half-pixel offset.
        let row: Vec<usize> = (0..16).filter(|&x| out_mask[7 * 16 + x] == 1.0).collect();
        assert_eq!(row, (3..13).collect::<Vec<_>>());
        assert_eq!(out_mask[0], 0.0);
    }
}
