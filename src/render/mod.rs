//! Drawing the scene with wgpu render pipelines: lit meshes and the ground grid, into an
//! off-screen target that the viewport shows, the recorder saves and headless renders read.

pub mod blit;
pub mod camera;
pub mod composite;
pub mod offscreen;
pub mod scene;

pub use camera::OrbitCamera;
pub use scene::{COLOR_FORMAT, GpuMesh, RenderTarget, SceneRenderer, SceneUniforms};

use crate::gpu::GpuContext;
use crate::gpu::kernel::Precision;
use crate::gpu::shaders::Shader;

/// A pipeline that draws `shader`'s full-screen triangle (`vs_main`, three vertices, no
/// vertex buffers) with `fs_main` into one colour target of `format`, blended with
/// `blend` (none: replaced), one sample, no depth: the splat composite and the blit.
fn full_screen_pipeline(
    gpu: &GpuContext,
    shader: &Shader,
    label: &str,
    format: wgpu::TextureFormat,
    blend: Option<wgpu::BlendState>,
) -> wgpu::RenderPipeline {
    let module = shader.module(&gpu.device, Precision::F32);
    gpu.device
        .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(label),
            layout: None,
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_main"),
                buffers: &[],
                compilation_options: Default::default(),
            },
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_main"),
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend,
                    write_mask: wgpu::ColorWrites::ALL,
                })],
                compilation_options: Default::default(),
            }),
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            multiview_mask: None,
            cache: None,
        })
}
