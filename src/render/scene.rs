//! The scene renderer: uploads meshes, owns the pipelines, and draws one frame into a
//! [`RenderTarget`] (colour + depth) from an [`OrbitCamera`].

use glam::{Vec3, Vec4};

use super::OrbitCamera;
use crate::gpu::GpuContext;
use crate::gpu::kernel::Precision;
use crate::gpu::shaders::Shader;
use crate::gpu::timing::PassTimer;
use crate::gpu_struct;
use crate::mesh::Mesh;

/// Colour format of render targets (sRGB: shaders write linear colour).
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Linear background colour.
pub const BACKGROUND: wgpu::Color = wgpu::Color {
    r: 0.13,
    g: 0.135,
    b: 0.15,
    a: 1.0,
};

gpu_struct! {
    /// Per-frame scene constants shared with `scene.wgsl`.
    pub struct SceneUniforms {
        pub view_proj: glam::Mat4,
        /// xyz: unit direction toward the light; w: its intensity.
        pub light_dir: glam::Vec4,
        pub sky_ambient: glam::Vec4,
        pub ground_ambient: glam::Vec4,
    }
}

/// The scene's shader (WGSL in `shaders/render/`).
pub const SCENE: Shader =
    crate::wgsl_shader!("render/scene.wgsl", [SceneUniforms], f16: false, subgroups: false);

/// The render stage's shaders.
pub const ALL: &[Shader] = &[SCENE];

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Vertex {
    position: [f32; 3],
    normal: [f32; 3],
    color: [f32; 3],
}

const VERTEX_LAYOUT: wgpu::VertexBufferLayout<'static> = wgpu::VertexBufferLayout {
    array_stride: std::mem::size_of::<Vertex>() as u64,
    step_mode: wgpu::VertexStepMode::Vertex,
    attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Float32x3, 2 => Float32x3],
};

/// A mesh (or line set) on the GPU.
pub struct GpuMesh {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
}

/// Colour and depth textures of one size; the colour can be sampled and copied out.
pub struct RenderTarget {
    pub color: wgpu::Texture,
    pub color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
}

impl RenderTarget {
    pub fn new(gpu: &GpuContext, width: u32, height: u32) -> Self {
        let max = gpu.device.limits().max_texture_dimension_2d;
        let size = wgpu::Extent3d {
            width: width.clamp(1, max),
            height: height.clamp(1, max),
            depth_or_array_layers: 1,
        };
        let texture = |label, format, usage| {
            gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage,
                view_formats: &[],
            })
        };
        let color = texture(
            "viewport colour",
            COLOR_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        );
        let depth = texture(
            "viewport depth",
            DEPTH_FORMAT,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        Self {
            color_view: color.create_view(&Default::default()),
            depth_view: depth.create_view(&Default::default()),
            color,
        }
    }

    pub fn size(&self) -> (u32, u32) {
        (self.color.width(), self.color.height())
    }
}

pub struct SceneRenderer {
    triangles: wgpu::RenderPipeline,
    lines: wgpu::RenderPipeline,
    uniforms: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    grid: GpuMesh,
}

impl SceneRenderer {
    pub fn new(gpu: &GpuContext) -> Self {
        let device = &gpu.device;
        let module = SCENE.module(device, Precision::F32);
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("scene"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("scene"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |topology, fragment: &str| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(fragment),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs_main"),
                    buffers: &[Some(VERTEX_LAYOUT)],
                    compilation_options: Default::default(),
                },
                primitive: wgpu::PrimitiveState {
                    topology,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Less),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fragment),
                    targets: &[Some(COLOR_FORMAT.into())],
                    compilation_options: Default::default(),
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let uniforms = gpu.create_buffer(&wgpu::BufferDescriptor {
            label: Some("scene uniforms"),
            size: std::mem::size_of::<SceneUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bind_group = gpu.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout: &layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: uniforms.as_entire_binding(),
            }],
        });
        Self {
            triangles: pipeline(wgpu::PrimitiveTopology::TriangleList, "fs_lit"),
            lines: pipeline(wgpu::PrimitiveTopology::LineList, "fs_unlit"),
            grid: upload(gpu, &grid_lines(), "grid"),
            uniforms,
            bind_group,
        }
    }

    /// Puts a triangle mesh on the GPU.
    pub fn upload(&self, gpu: &GpuContext, mesh: &Mesh) -> GpuMesh {
        upload(gpu, mesh, "mesh")
    }

    /// Clears `target` and draws the grid and `meshes` as seen by `camera`, with
    /// `options`' choice of grid, background and light.
    #[allow(clippy::too_many_arguments)]
    pub fn draw(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        target: &RenderTarget,
        camera: &OrbitCamera,
        meshes: &[&GpuMesh],
        options: &DrawOptions,
        timer: Option<PassTimer<'_>>,
    ) {
        let (w, h) = target.size();
        let light = options.light.unwrap_or_else(|| light_direction(camera));
        let uniforms = SceneUniforms {
            view_proj: camera.view_projection(w as f32 / h as f32),
            light_dir: light.normalize().extend(0.8),
            sky_ambient: Vec4::new(0.6, 0.62, 0.68, 0.0),
            ground_ambient: Vec4::new(0.25, 0.22, 0.2, 0.0),
        };
        gpu.queue
            .write_buffer(&self.uniforms, 0, bytemuck::bytes_of(&uniforms));
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("scene"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &target.color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(options.background),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &target.depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: timer.as_ref().map(PassTimer::render),
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        let mut draw = |pipeline: &wgpu::RenderPipeline, mesh: &GpuMesh| {
            pass.set_pipeline(pipeline);
            pass.set_vertex_buffer(0, mesh.vertices.slice(..));
            pass.set_index_buffer(mesh.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..mesh.index_count, 0, 0..1);
        };
        if options.grid {
            draw(&self.lines, &self.grid);
        }
        for mesh in meshes {
            draw(&self.triangles, mesh);
        }
    }
}

/// What a frame shows besides the meshes.
#[derive(Clone, Copy, Debug)]
pub struct DrawOptions {
    pub grid: bool,
    pub background: wgpu::Color,
    /// Direction toward the light; `None` puts a key light above and beside the camera,
    /// so what is seen is lit.
    pub light: Option<Vec3>,
}

impl Default for DrawOptions {
    fn default() -> Self {
        Self {
            grid: true,
            background: BACKGROUND,
            light: None,
        }
    }
}

/// Direction toward the light in a character's own frame (it faces +Z): the light the
/// dataset's renders are lit by, which the refiner learns the neural avatar's colours
/// from. The teacher is drawn with it wherever the neural avatar may stand beside it,
/// so the two match in colour (issue #17).
pub const CHARACTER_LIGHT: Vec3 = Vec3::new(0.35, 0.8, 0.5);

/// [`CHARACTER_LIGHT`] for a character turned `yaw` radians about +Y.
pub fn character_light(yaw: f32) -> Vec3 {
    glam::Quat::from_rotation_y(yaw) * CHARACTER_LIGHT
}

fn light_direction(camera: &OrbitCamera) -> Vec3 {
    let toward_eye = (camera.eye() - camera.target).normalize_or(Vec3::Z);
    let side = toward_eye.cross(Vec3::Y).normalize_or(Vec3::X);
    (toward_eye + 1.2 * Vec3::Y + 0.5 * side).normalize()
}

impl GpuMesh {
    /// Replaces the vertices of a mesh with the same topology (a new pose).
    pub fn write_vertices(&self, gpu: &GpuContext, mesh: &Mesh) {
        let vertices = vertices(mesh);
        let bytes: &[u8] = bytemuck::cast_slice(&vertices);
        if bytes.len() as u64 == self.vertices.size() {
            gpu.queue.write_buffer(&self.vertices, 0, bytes);
        } else {
            log::error!("a posed mesh has a different vertex count; not drawn");
        }
    }
}

fn vertices(mesh: &Mesh) -> Vec<Vertex> {
    (0..mesh.positions.len())
        .map(|i| Vertex {
            position: mesh.positions[i].into(),
            normal: mesh.normals[i].into(),
            color: mesh.colors[i].into(),
        })
        .collect()
}

fn upload(gpu: &GpuContext, mesh: &Mesh, label: &str) -> GpuMesh {
    let vertices = vertices(mesh);
    let buffer = |contents: &[u8], usage: wgpu::BufferUsages| {
        let buffer = gpu.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: (contents.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT),
            usage: usage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut padded = contents.to_vec();
        padded.resize(buffer.size() as usize, 0);
        gpu.queue.write_buffer(&buffer, 0, &padded);
        buffer
    };
    GpuMesh {
        vertices: buffer(
            bytemuck::cast_slice(&vertices),
            wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
        ),
        indices: buffer(
            bytemuck::cast_slice(&mesh.indices),
            wgpu::BufferUsages::INDEX,
        ),
        index_count: mesh.indices.len() as u32,
    }
}

/// The ground grid as a line list: 10 m square, lines every 0.5 m, the X axis red and
/// the Z axis blue.
fn grid_lines() -> Mesh {
    let mut mesh = Mesh::default();
    let half = 5.0;
    let steps = 20;
    let mut line = |a: Vec3, b: Vec3, color: Vec3| {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend([a, b]);
        mesh.normals.extend([Vec3::Y; 2]);
        mesh.colors.extend([color; 2]);
        mesh.indices.extend([base, base + 1]);
    };
    for i in 0..=steps {
        let t = -half + i as f32 * (2.0 * half / steps as f32);
        let (x_color, z_color) = if i == steps / 2 {
            (Vec3::new(0.1, 0.1, 0.6), Vec3::new(0.6, 0.1, 0.1))
        } else {
            (Vec3::splat(0.24), Vec3::splat(0.24))
        };
        line(Vec3::new(t, 0.0, -half), Vec3::new(t, 0.0, half), x_color);
        line(Vec3::new(-half, 0.0, t), Vec3::new(half, 0.0, t), z_color);
    }
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_character_light_turns_with_the_character() {
        assert!(character_light(0.0).abs_diff_eq(CHARACTER_LIGHT, 1e-6));
        // A quarter turn to the left (+Y up) takes the character's +Z to +X.
        let turned = character_light(std::f32::consts::FRAC_PI_2);
        assert!(
            turned.abs_diff_eq(Vec3::new(0.5, 0.8, -0.35), 1e-6),
            "{turned}"
        );
    }
}
