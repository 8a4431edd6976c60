//! The 3D viewport: the scene rendered into an off-screen texture, shown in egui's pass by
//! a paint callback ([`crate::render::blit`]: egui's own image shader cost a CPU driver
//! about a fifth of a window frame), and the mouse mapped onto the orbit camera (left
//! orbit, right/middle pan, wheel zoom). Render-to-texture rather than drawing the scene
//! in the callback: the recorder, screenshots and headless renders read exactly the same
//! pixels, and our passes can carry timestamp queries.

use eframe::egui;

use crate::gpu::GpuContext;
use std::time::Instant;

use crate::gpu::timing::StageTiming;
use crate::render::blit::Blit;
use crate::render::composite::Compositor;
use crate::render::scene::{COLOR_FORMAT, DrawOptions};
use crate::render::{GpuMesh, OrbitCamera, RenderTarget, SceneRenderer};
use crate::splat::raster::Rasterizer;

/// A stage's CPU recording time since `clock` (the window waits for no GPU work).
fn recorded(name: &str, clock: Instant) -> StageTiming {
    StageTiming {
        name: name.into(),
        ms: clock.elapsed().as_secs_f64() * 1e3,
        clock: "cpu, recording",
    }
}

/// Radians of orbit per point dragged.
const ORBIT_SPEED: f32 = 0.008;
/// Zoom factor per point scrolled (exponential).
const ZOOM_SPEED: f32 = 0.002;

pub struct Viewport {
    pub renderer: SceneRenderer,
    pub camera: OrbitCamera,
    target: Option<RenderTarget>,
    /// The target's image as the window's pass draws it (made with the target).
    shown: Option<ShownTarget>,
    /// Made when splats are first drawn.
    splatting: Option<(Rasterizer, Compositor)>,
    /// The last splat image and what it was drawn from: redrawn only when the camera,
    /// the size or the splats change, so HUD-only frames cost no rasterization.
    cached: Option<Cached>,
    /// What the target holds (camera, size, scene generation, splats): when nothing
    /// changed the viewport records nothing (a CPU driver spends a window frame's time
    /// drawing it).
    drawn: Option<SceneKey>,
    /// The 3D image's size as a share of the viewport's pixels along each axis (the
    /// window shows it scaled up). Defaults by adapter ([`default_resolution_scale`]);
    /// the HUD changes it; a recording draws at full size whatever it is.
    pub resolution_scale: f32,
}

/// The 3D resolution scale a window starts with: 1 on a GPU; on a CPU driver 0.5, a
/// quarter of the pixels, since there the viewport's draws take the cores the model
/// needs (docs/performance.md has the measurements).
pub fn default_resolution_scale(gpu: &GpuContext) -> f32 {
    if gpu.cpu_driver() { 0.5 } else { 1.0 }
}

type SceneKey = (
    OrbitCamera,
    (u32, u32),
    (u64, u64, usize),
    Option<(wgpu::Buffer, usize, u64)>,
);

/// Splats to draw: a buffer of `GpuSplat`s, how many, and a generation that changes
/// whenever the buffer's contents do (e.g. the generated frame's number).
pub type Splats<'a> = (&'a wgpu::Buffer, usize, u64);

/// What one window frame shows: the meshes and a generation that changes whenever they
/// do, the splats, and labels (a world point and its text).
pub struct Scene<'a> {
    pub meshes: &'a [&'a GpuMesh],
    pub generation: (u64, u64, usize),
    pub splats: Option<Splats<'a>>,
    pub labels: &'a [(glam::Vec3, &'a str)],
    /// Direction toward the light; `None`: a key light beside the camera.
    pub light: Option<glam::Vec3>,
    /// Draw at the viewport's full pixel size whatever the resolution scale (a
    /// recording is on).
    pub full_size: bool,
}

struct Cached {
    key: (OrbitCamera, (u32, u32), wgpu::Buffer, usize, u64),
    image: wgpu::Buffer,
    divisor: u32,
}

/// The viewport's image drawn in the window's egui pass (a paint callback).
#[derive(Clone)]
struct ShownTarget {
    blit: Blit,
    bound: wgpu::BindGroup,
}

impl eframe::egui_wgpu::CallbackTrait for ShownTarget {
    fn paint(
        &self,
        _info: egui::PaintCallbackInfo,
        pass: &mut wgpu::RenderPass<'static>,
        _resources: &eframe::egui_wgpu::CallbackResources,
    ) {
        self.blit.draw(pass, &self.bound);
    }
}

/// While the camera moves, splats are rasterized at 1/DIVISOR of the size along each
/// axis (a sixteenth of the pixels); the full size follows once it stops.
const MOVING_DIVISOR: u32 = 4;

impl Viewport {
    pub fn new(gpu: &GpuContext) -> Self {
        Self {
            renderer: SceneRenderer::new(gpu),
            camera: OrbitCamera::default(),
            target: None,
            shown: None,
            splatting: None,
            cached: None,
            drawn: None,
            resolution_scale: default_resolution_scale(gpu),
        }
    }

    /// Whether the last image is final: false while splats drawn small during a camera
    /// move still wait for their full-size redraw.
    pub fn settled(&self) -> bool {
        self.cached.as_ref().is_none_or(|c| c.divisor == 1)
    }

    /// The last rendered image (what the recorder saves).
    pub fn target(&self) -> Option<&RenderTarget> {
        self.target.as_ref()
    }

    /// Renders `meshes` and then `splats` over them at the size of the available area,
    /// shows it, and applies mouse input to the camera. `scene` changes whenever the
    /// meshes do; with the same camera, size, scene and splats as the last frame the image
    /// is kept as it is. Returns each stage's CPU recording time (the GPU work is
    /// submitted, not waited for); none when nothing was drawn.
    pub fn show(
        &mut self,
        ui: &mut egui::Ui,
        gpu: &GpuContext,
        window_format: wgpu::TextureFormat,
        scene: Scene,
    ) -> Vec<StageTiming> {
        let Scene {
            meshes,
            generation: scene,
            splats,
            labels,
            light,
            full_size,
        } = scene;
        let size = ui.available_size();
        let scale = if full_size {
            1.0
        } else {
            self.resolution_scale.clamp(0.1, 1.0)
        };
        let ppp = ui.ctx().pixels_per_point() * scale;
        let (w, h) = (
            (size.x * ppp).round().max(1.0) as u32,
            (size.y * ppp).round().max(1.0) as u32,
        );
        if self.target.as_ref().map(RenderTarget::size) != Some((w, h)) {
            let target = RenderTarget::new(gpu, w, h);
            let blit = match self.shown.take() {
                Some(shown) => shown.blit,
                None => Blit::new(gpu, window_format),
            };
            let bound = blit.bind(gpu, &target.color_view);
            self.shown = Some(ShownTarget { blit, bound });
            self.target = Some(target);
        }
        let (Some(target), Some(shown)) = (&self.target, self.shown.clone()) else {
            return Vec::new();
        };

        let key = (
            self.camera,
            (w, h),
            scene,
            splats.map(|(b, n, g)| (b.clone(), n, g)),
        );
        // A splat image drawn small while the camera moved is redrawn at full size.
        let settled = self.cached.as_ref().is_none_or(|c| c.divisor == 1);
        if self.drawn.as_ref() == Some(&key) && settled {
            return self.respond(ui, shown, size, labels);
        }
        self.drawn = Some(key);
        // One encoder and one submission, never waited for: on a CPU driver a wait would
        // hold the window until the model's work queued before it had run too. The HUD
        // gets the CPU time of recording each stage.
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("viewport"),
            });
        let mut timings = Vec::new();
        let clock = Instant::now();
        let options = DrawOptions {
            light,
            ..DrawOptions::default()
        };
        self.renderer.draw(
            gpu,
            &mut encoder,
            target,
            &self.camera,
            meshes,
            &options,
            None,
        );
        timings.push(recorded("viewport", clock));
        if let Some((buffer, count, generation)) = splats {
            let clock = Instant::now();
            let (rasterizer, compositor) = self
                .splatting
                .get_or_insert_with(|| (Rasterizer::default(), Compositor::new(gpu, COLOR_FORMAT)));
            let key = (self.camera, (w, h), buffer.clone(), count, generation);
            let cached = &mut self.cached;
            // Drawn small only while the camera alone moves (a drag, a wheel turn). A camera
            // following the avatar moves once with each generated frame, which comes with new
            // splats: drawn small, then full size, that was two window frames per generated
            // frame, each taken from the model on a CPU driver.
            let moving = cached.as_ref().is_some_and(|c| {
                let (camera, size, buffer, count, generation) = &c.key;
                *camera != self.camera
                    && (size, buffer, count, generation) == (&key.1, &key.2, &key.3, &key.4)
            });
            let full = cached.as_ref().is_some_and(|c| c.divisor == 1);
            let fresh = cached.as_ref().is_some_and(|c| c.key == key);
            if !(fresh && (full || moving)) {
                let divisor = if moving { MOVING_DIVISOR } else { 1 };
                let camera = self
                    .camera
                    .splat_camera(w.div_ceil(divisor), h.div_ceil(divisor));
                match rasterizer.record(gpu, &mut encoder, buffer, count, &camera, glam::Vec3::ZERO)
                {
                    Ok(raster) => {
                        *cached = Some(Cached {
                            key,
                            image: raster.image.clone(),
                            divisor,
                        })
                    }
                    Err(e) => {
                        log::error!("splats: {e}");
                        *cached = None;
                    }
                }
            }
            if let Some(c) = cached.as_ref() {
                compositor.draw(gpu, &mut encoder, target, &c.image, c.divisor);
            }
            timings.push(recorded("splats", clock));
        } else {
            self.cached = None;
        }
        gpu.submit([encoder.finish()]);
        self.respond(ui, shown, size, labels);
        timings
    }

    /// Shows the target with the labels over it and applies the mouse to the camera.
    fn respond(
        &mut self,
        ui: &mut egui::Ui,
        shown: ShownTarget,
        size: egui::Vec2,
        labels: &[(glam::Vec3, &str)],
    ) -> Vec<StageTiming> {
        let (rect, response) = ui.allocate_exact_size(size, egui::Sense::click_and_drag());
        ui.painter()
            .add(eframe::egui_wgpu::Callback::new_paint_callback(rect, shown));
        let view_projection = self.camera.view_projection(rect.width() / rect.height());
        let painter = ui.painter_at(rect);
        for &(point, text) in labels {
            if let Some((x, y)) =
                screen_point(view_projection, (rect.width(), rect.height()), point)
            {
                painter.text(
                    rect.min + egui::vec2(x, y),
                    egui::Align2::CENTER_TOP,
                    text,
                    egui::FontId::proportional(15.0),
                    egui::Color32::WHITE,
                );
            }
        }
        self.handle_mouse(ui, &response);
        Vec::new()
    }

    fn handle_mouse(&mut self, ui: &egui::Ui, response: &egui::Response) {
        let delta = response.drag_delta();
        if response.dragged_by(egui::PointerButton::Primary) {
            self.camera
                .orbit(-delta.x * ORBIT_SPEED, delta.y * ORBIT_SPEED);
        } else if response.dragged_by(egui::PointerButton::Secondary)
            || response.dragged_by(egui::PointerButton::Middle)
        {
            let height = response.rect.height().max(1.0);
            self.camera.pan(delta.x / height, delta.y / height);
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                self.camera.zoom((scroll * ZOOM_SPEED).exp());
            }
        }
    }
}

/// Where a world point lands in a `size` (width, height) rectangle, from its top-left
/// corner; `None` behind the camera.
pub fn screen_point(
    view_projection: glam::Mat4,
    size: (f32, f32),
    point: glam::Vec3,
) -> Option<(f32, f32)> {
    let clip = view_projection * point.extend(1.0);
    if clip.w <= 1e-6 {
        return None;
    }
    let ndc = clip.truncate() / clip.w;
    Some(((ndc.x * 0.5 + 0.5) * size.0, (0.5 - ndc.y * 0.5) * size.1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec3};

    #[test]
    fn labels_land_where_the_camera_sees_their_points() {
        // A 90° camera at the origin looking down -z with a square aspect: the point
        // (1, 1, -1) is on the top-right corner; (0, 0, -2) in the centre; behind: none.
        let projection = glam::camera::rh::proj::directx::perspective(
            std::f32::consts::FRAC_PI_2,
            1.0,
            0.1,
            10.0,
        );
        let vp = projection * Mat4::IDENTITY;
        let size = (200.0, 100.0);
        let (x, y) = screen_point(vp, size, Vec3::new(1.0, 1.0, -1.0)).unwrap();
        assert!((x - 200.0).abs() < 1e-3 && y.abs() < 1e-3, "{x} {y}");
        let (x, y) = screen_point(vp, size, Vec3::new(0.0, 0.0, -2.0)).unwrap();
        assert!(
            (x - 100.0).abs() < 1e-3 && (y - 50.0).abs() < 1e-3,
            "{x} {y}"
        );
        let (x, y) = screen_point(vp, size, Vec3::new(-0.5, -0.25, -1.0)).unwrap();
        assert!(
            (x - 50.0).abs() < 1e-3 && (y - 62.5).abs() < 1e-3,
            "{x} {y}"
        );
        assert!(screen_point(vp, size, Vec3::new(0.0, 0.0, 1.0)).is_none());
    }
}
