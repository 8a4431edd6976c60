//! Showing a render target's image inside another render pass: the 3D viewport's texture
//! drawn into the window's egui pass over the viewport's rectangle, bilinear, no
//! blending (shaders/render/blit.wgsl). On a CPU driver egui's own image shader took
//! about a fifth of a window frame for this (docs/performance.md).

use crate::gpu::GpuContext;
use crate::gpu::shaders::Shader;
use crate::wgsl_shader as shader;

pub const BLIT: Shader = shader!("render/blit.wgsl", [], f16: false, subgroups: false);

/// Every shader of this file (gathered by `unica::shaders`).
pub const SHADERS: &[Shader] = &[BLIT];

/// A pipeline that draws a texture over the whole viewport of a pass of one format.
#[derive(Clone)]
pub struct Blit {
    pipeline: wgpu::RenderPipeline,
}

impl Blit {
    /// For passes whose colour target has `format` (one target, one sample, no depth).
    pub fn new(gpu: &GpuContext, format: wgpu::TextureFormat) -> Self {
        let pipeline = super::full_screen_pipeline(gpu, &BLIT, "blit", format, None);
        Self { pipeline }
    }

    /// What [`Blit::draw`] reads: `image`, a view of a texture with TEXTURE_BINDING.
    pub fn bind(&self, gpu: &GpuContext, image: &wgpu::TextureView) -> wgpu::BindGroup {
        gpu.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("blit"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(image),
            }],
        })
    }

    /// Records the image of `bound` ([`Blit::bind`]) over the pass's current viewport,
    /// interpolated bilinearly between texel centres.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, bound: &wgpu::BindGroup) {
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, bound, &[]);
        pass.draw(0..3, 0..1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{GpuOptions, readback};

    fn texture(
        gpu: &GpuContext,
        width: u32,
        height: u32,
        usage: wgpu::TextureUsages,
    ) -> wgpu::Texture {
        gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("blit test"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage,
            view_formats: &[],
        })
    }

    /// What a linear, clamp-to-edge sampler returns at pixel (x, y) of a `to`-sized
    /// viewport over `image` (`from`-sized, RGBA8), in 0..255.
    fn bilinear(image: &[u8], from: (u32, u32), to: (u32, u32), x: u32, y: u32) -> [f32; 4] {
        let coordinate = |pixel: u32, out: u32, size: u32| {
            let p = ((pixel as f32 + 0.5) / out as f32 * size as f32 - 0.5).max(0.0);
            let lo = (p.floor() as u32).min(size - 1);
            (lo, (lo + 1).min(size - 1), p.fract())
        };
        let (x0, x1, fx) = coordinate(x, to.0, from.0);
        let (y0, y1, fy) = coordinate(y, to.1, from.1);
        let at = |x: u32, y: u32, c: usize| image[((y * from.0 + x) * 4) as usize + c] as f32;
        std::array::from_fn(|c| {
            let top = at(x0, y0, c) * (1.0 - fx) + at(x1, y0, c) * fx;
            let bottom = at(x0, y1, c) * (1.0 - fx) + at(x1, y1, c) * fx;
            top * (1.0 - fy) + bottom * fy
        })
    }

    /// A 4 × 3 image blitted over viewports of its own size (each pixel its texel, exactly)
    /// and larger and smaller (a linear sampler's values from a CPU loop, within one
    /// level of 255 for rounding), with no blending over what the pass held.
    #[test]
    fn the_blit_is_a_linear_sampler_over_the_viewport() {
        let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
        let from = (4u32, 3u32);
        let pixels: Vec<u8> = (0..from.0 * from.1 * 4)
            .map(|i| (i * 37 % 251) as u8)
            .collect();
        let image = texture(
            &gpu,
            from.0,
            from.1,
            wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        );
        gpu.queue.write_texture(
            image.as_image_copy(),
            &pixels,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(from.0 * 4),
                rows_per_image: Some(from.1),
            },
            image.size(),
        );
        let blit = Blit::new(&gpu, wgpu::TextureFormat::Rgba8Unorm);
        let bound = blit.bind(&gpu, &image.create_view(&Default::default()));
        for to in [(4, 3), (11, 7), (2, 2)] {
            let target = texture(
                &gpu,
                to.0,
                to.1,
                wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            );
            let view = target.create_view(&Default::default());
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            {
                let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: None,
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &view,
                        depth_slice: None,
                        resolve_target: None,
                        ops: wgpu::Operations {
                            load: wgpu::LoadOp::Clear(wgpu::Color::WHITE),
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    depth_stencil_attachment: None,
                    timestamp_writes: None,
                    occlusion_query_set: None,
                    multiview_mask: None,
                });
                blit.draw(&mut pass, &bound);
            }
            gpu.submit([encoder.finish()]);
            let out = readback::rgba_texture(&gpu, &target).unwrap();
            for (x, y, got) in out.enumerate_pixels() {
                let want = bilinear(&pixels, from, to, x, y);
                let allowed = if to == from { 0.0 } else { 1.0 };
                for (c, (got, want)) in got.0.iter().zip(want).enumerate() {
                    let error = (*got as f32 - want).abs();
                    assert!(
                        error <= allowed,
                        "{to:?} ({x}, {y}) channel {c}: {got} against {want}"
                    );
                }
            }
        }
    }
}
