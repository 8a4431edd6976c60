//! Headless rendering of posed meshes or Gaussian splats to images: one device, one
//! target, one mesh buffer reused frame after frame (teacher renders, dataset ground
//! truth, the neural avatar).

use crate::gpu::{GpuContext, GpuError, readback};
use crate::mesh::Mesh;

use super::composite::Compositor;
use super::scene::{COLOR_FORMAT, DrawOptions};
use super::{GpuMesh, OrbitCamera, RenderTarget, SceneRenderer};
use crate::splat::raster::Rasterizer;

pub struct Offscreen {
    gpu: GpuContext,
    renderer: SceneRenderer,
    target: RenderTarget,
    mesh: Option<(usize, GpuMesh)>,
    /// Made when splats are first drawn.
    splatting: Option<(Rasterizer, Compositor)>,
}

impl Offscreen {
    pub fn new(gpu: GpuContext, width: u32, height: u32) -> Self {
        Self {
            renderer: SceneRenderer::new(&gpu),
            target: RenderTarget::new(&gpu, width, height),
            gpu,
            mesh: None,
            splatting: None,
        }
    }

    pub fn gpu(&self) -> &GpuContext {
        &self.gpu
    }

    /// Draws the grid and `count` splats (uploaded with `Rasterizer::upload`) from
    /// `camera` and reads the image back.
    pub fn render_splats(
        &mut self,
        splats: &wgpu::Buffer,
        count: usize,
        camera: &OrbitCamera,
        options: &DrawOptions,
    ) -> Result<image::RgbaImage, GpuError> {
        let mut encoder = self.scene(camera, &[], options);
        let (rasterizer, compositor) = self.splatting.get_or_insert_with(|| {
            (
                Rasterizer::default(),
                Compositor::new(&self.gpu, COLOR_FORMAT),
            )
        });
        let (w, h) = self.target.size();
        let splat_camera = camera.splat_camera(w, h);
        let raster = rasterizer.record(
            &self.gpu,
            &mut encoder,
            splats,
            count,
            &splat_camera,
            glam::Vec3::ZERO,
        )?;
        compositor.draw(&self.gpu, &mut encoder, &self.target, &raster.image, 1);
        self.gpu.submit([encoder.finish()]);
        readback::rgba_texture(&self.gpu, &self.target.color)
    }

    /// Draws `mesh` from `camera` and reads the image back.
    pub fn render(
        &mut self,
        mesh: &Mesh,
        camera: &OrbitCamera,
        options: &DrawOptions,
    ) -> Result<image::RgbaImage, GpuError> {
        match &self.mesh {
            Some((count, gpu_mesh)) if *count == mesh.positions.len() => {
                gpu_mesh.write_vertices(&self.gpu, mesh)
            }
            _ => self.mesh = Some((mesh.positions.len(), self.renderer.upload(&self.gpu, mesh))),
        }
        let (_, gpu_mesh) = self.mesh.as_ref().expect("uploaded above");
        let encoder = self.scene(camera, &[gpu_mesh], options);
        self.gpu.submit([encoder.finish()]);
        readback::rgba_texture(&self.gpu, &self.target.color)
    }

    /// An encoder with the scene (grid and `meshes`) drawn into the target.
    fn scene(
        &self,
        camera: &OrbitCamera,
        meshes: &[&GpuMesh],
        options: &DrawOptions,
    ) -> wgpu::CommandEncoder {
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        let target = &self.target;
        let gpu = &self.gpu;
        self.renderer
            .draw(gpu, &mut encoder, target, camera, meshes, options, None);
        encoder
    }
}
