//! Headless rendering of posed meshes to images: one device, one target, one mesh buffer
//! reused frame after frame (teacher renders, dataset ground truth).

use crate::gpu::{GpuContext, GpuError, readback};
use crate::mesh::Mesh;

use super::scene::DrawOptions;
use super::{GpuMesh, OrbitCamera, RenderTarget, SceneRenderer};

pub struct Offscreen {
    gpu: GpuContext,
    renderer: SceneRenderer,
    target: RenderTarget,
    mesh: Option<(usize, GpuMesh)>,
}

impl Offscreen {
    pub fn new(gpu: GpuContext, width: u32, height: u32) -> Self {
        Self {
            renderer: SceneRenderer::new(&gpu),
            target: RenderTarget::new(&gpu, width, height),
            gpu,
            mesh: None,
        }
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
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.renderer.draw_with(
            &self.gpu,
            &mut encoder,
            &self.target,
            camera,
            &[gpu_mesh],
            options,
            None,
        );
        self.gpu.queue.submit([encoder.finish()]);
        readback::rgba_texture(&self.gpu, &self.target.color)
    }
}
