//! Drawing rasterized splats into a render target over what is already there (the
//! scene's grid and meshes): see shaders/render/splat_composite.wgsl.

use super::RenderTarget;
use crate::gpu::GpuContext;
use crate::gpu::kernel::uniform;
use crate::gpu::shaders::Shader;
use crate::gpu_struct;
use crate::wgsl_shader as shader;

pub const SPLAT_COMPOSITE: Shader =
    shader!("render/splat_composite.wgsl", [CompositeParams], f16: false, subgroups: false);

/// Every shader of this file (gathered by `unica::shaders`).
pub const SHADERS: &[Shader] = &[SPLAT_COMPOSITE];

gpu_struct! {
    /// The splat image's size.
    pub struct CompositeParams {
        pub width: u32,
        pub height: u32,
        /// Window pixels per image pixel along each axis (a reduced-size raster).
        pub divisor: u32,
        pub reserved: u32,
    }
}

pub struct Compositor {
    pipeline: wgpu::RenderPipeline,
}

impl Compositor {
    pub fn new(gpu: &GpuContext, format: wgpu::TextureFormat) -> Self {
        let blend = wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::One,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        };
        let blend = wgpu::BlendState {
            color: blend,
            alpha: blend,
        };
        let pipeline = super::full_screen_pipeline(
            gpu,
            &SPLAT_COMPOSITE,
            "splat composite",
            format,
            Some(blend),
        );
        Self { pipeline }
    }

    /// Records drawing `image` (the rasterizer's output at the target's size divided by
    /// `divisor`, rounded up) over `target`, each image pixel covering divisor² pixels.
    pub fn draw(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        target: &RenderTarget,
        image: &wgpu::Buffer,
        divisor: u32,
    ) {
        let divisor = divisor.max(1);
        let (width, height) = target.size();
        let (width, height) = (width.div_ceil(divisor), height.div_ceil(divisor));
        let params = uniform(
            gpu,
            &CompositeParams {
                width,
                height,
                divisor,
                reserved: 0,
            },
        );
        let bind_group = gpu.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("splat composite"),
            layout: &self.pipeline.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: params.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: image.as_entire_binding(),
                },
            ],
        });
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("splat composite"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &target.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Load,
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: None,
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.draw(0..3, 0..1);
    }
}
