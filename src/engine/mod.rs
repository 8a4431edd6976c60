//! The live neural avatar (DESIGN §6): a ring of three context latents on the GPU → the
//! UNet + DDIM with CFG → decode → the new frame's root shift is real motion (world root
//! accumulated) → the window is recentred in latent space and slid → PCA cleans what is
//! drawn (never fed back). No readback inside a generated frame: the only one is the
//! decoded map at its end, which the caller draws. Headless, a frame is one submission;
//! beside a window (`EngineOptions::split`) it is submitted step by step, so the
//! window's frames never wait for more than one step. `appearance` turns a frame's
//! points into splats.

pub mod appearance;
pub mod pca;
mod recentre;
pub mod surface;

use std::path::Path;
use std::time::Instant;

use glam::Vec3;

use crate::action::Action;
use crate::gpu::GpuContext;
use crate::gpu::kernel::{PipelineCache, Precision};
use crate::nn::sampler::Sampling;
use crate::nn::{Bundle, LoadError, Recorder, Tensor};
use crate::random::Rng;
use recentre::ShiftBasis;

/// How the engine runs.
#[derive(Clone, Debug)]
pub struct EngineOptions {
    pub precision: Precision,
    /// Seed of the sampler's noise: same seed and keys, same frames.
    pub seed: u64,
    /// DDIM steps and CFG scale; `None` takes the bundle's defaults.
    pub sampling: Option<Sampling>,
    /// Clean what is drawn with the bundle's PCA.
    pub pca: bool,
    /// Submit each generated frame in parts (context pass, each step, decode).
    pub split: bool,
}

impl Default for EngineOptions {
    fn default() -> Self {
        Self {
            precision: Precision::F32,
            seed: 0,
            sampling: None,
            pca: true,
            split: false,
        }
    }
}

/// One generated frame, ready to draw.
#[derive(Clone, Debug)]
pub struct Frame {
    pub index: u64,
    pub action: Action,
    /// One world-space surface point per foreground map pixel (PCA-cleaned when on).
    pub points: Vec<Vec3>,
    /// The world root after this frame.
    pub root: Vec3,
    /// Map values outside [0, 1] (or NaN) clamped in this frame, and since the start.
    pub clamped: usize,
    pub clamped_total: usize,
    /// Milliseconds: recording + GPU work + readback, then the CPU's share.
    pub gpu_ms: f64,
    pub cpu_ms: f64,
}

/// A generated frame's latent and root shift, applied to the window when the next frame
/// is recorded (so each frame is one submission).
struct Pending {
    latent: Tensor,
    shift: Vec3,
}

pub struct Engine {
    gpu: GpuContext,
    pipelines: PipelineCache,
    precision: Precision,
    pub bundle: Bundle,
    sampling: Sampling,
    pca: bool,
    split: bool,
    /// [1, F-1, C, h, w]: the window of clean context latents.
    context: Tensor,
    pending: Option<Pending>,
    basis: ShiftBasis,
    world_root: Vec3,
    noise: Rng,
    frames: u64,
    clamped_total: usize,
}

impl Engine {
    /// Loads the bundle in `dir` and starts from its standing start, the floor under the
    /// lowest point of that pose.
    pub fn new(gpu: &GpuContext, dir: &Path, options: &EngineOptions) -> Result<Self, LoadError> {
        let bundle = Bundle::load(dir, gpu, options.precision)?;
        let sampling = options.sampling.unwrap_or(bundle.manifest.sampler);
        sampling
            .check(bundle.schedule.steps())
            .map_err(|problem| LoadError::Manifest {
                path: dir.display().to_string(),
                problem,
            })?;
        let mut pipelines = PipelineCache::default();
        let basis = ShiftBasis::measure(gpu, &mut pipelines, options.precision, &bundle)?;
        let cfg = &bundle.unet.cfg;
        let side = bundle.manifest.map_size / 8;
        let context = bundle
            .context
            .reshaped(&[1, cfg.frames - 1, cfg.latent, side, side]);
        let scale = bundle.manifest.normalisation.scale;
        let lowest = basis
            .standing
            .iter()
            .map(|p| p.y)
            .fold(f32::INFINITY, f32::min);
        let world_root = Vec3::new(0.0, (0.5 - lowest) / scale, 0.0);
        Ok(Self {
            gpu: gpu.clone(),
            pipelines,
            precision: options.precision,
            sampling,
            pca: options.pca,
            split: options.split,
            context,
            pending: None,
            basis,
            world_root,
            noise: Rng::new(options.seed),
            frames: 0,
            clamped_total: 0,
            bundle,
        })
    }

    pub fn root(&self) -> Vec3 {
        self.world_root
    }

    /// The surface and base splats of this bundle's map, laid out on the standing start.
    pub fn surface(&self) -> surface::MapSurface {
        surface::MapSurface::new(
            &self.bundle.pixels,
            &self.standing_points(),
            self.bundle.colors.as_deref(),
        )
    }

    /// The standing start's last frame in world space (what is shown before the first
    /// generated frame).
    pub fn standing_points(&self) -> Vec<Vec3> {
        let scale = self.bundle.manifest.normalisation.scale;
        self.basis
            .standing
            .iter()
            .map(|&p| (p - Vec3::splat(0.5)) / scale + self.world_root)
            .collect()
    }

    pub fn sampling(&self) -> Sampling {
        self.sampling
    }

    pub fn set_sampling(&mut self, sampling: Sampling) {
        self.sampling = sampling;
    }

    pub fn set_pca(&mut self, on: bool) {
        self.pca = on;
    }

    /// Generates the next frame under `action`.
    pub fn step(&mut self, action: Action) -> Result<Frame, crate::gpu::GpuError> {
        let clock = Instant::now();
        let cfg = &self.bundle.unet.cfg;
        let side = self.bundle.manifest.map_size / 8;
        let noise_values = self.noise.gaussian(cfg.latent * side * side);
        let mut r = if self.split {
            Recorder::split(&self.gpu, &mut self.pipelines, self.precision)
        } else {
            Recorder::new(&self.gpu, &mut self.pipelines, self.precision)
        };
        if let Some(pending) = self.pending.take() {
            self.context =
                self.basis
                    .slide(&mut r, &self.context, &pending.latent, pending.shift)?;
        }
        let noise = r.upload("engine.noise", &[1, cfg.latent, side, side], &noise_values)?;
        let latent = self.bundle.generate(
            &mut r,
            &self.context,
            action.id() as usize,
            &noise,
            self.sampling,
        )?;
        let map = self.bundle.decode(&mut r, &latent)?;
        r.submit();
        let values = map.read(&self.gpu)?;
        let gpu_ms = clock.elapsed().as_secs_f64() * 1e3;

        let clock = Instant::now();
        let plane = values.len() / 3;
        let mut clamped = 0;
        let unit: Vec<Vec3> = self
            .bundle
            .pixels
            .iter()
            .map(|&p| {
                let v = Vec3::new(
                    values[p as usize],
                    values[plane + p as usize],
                    values[2 * plane + p as usize],
                );
                // NaN (counted) becomes the cube's centre; the rest is clamped (counted).
                Vec3::from_array(v.to_array().map(|x| {
                    let kept = if x.is_nan() { 0.5 } else { x.clamp(0.0, 1.0) };
                    clamped += usize::from(kept != x);
                    kept
                }))
            })
            .collect();
        let root = self
            .bundle
            .waist
            .iter()
            .map(|&w| unit[w as usize])
            .sum::<Vec3>()
            / self.bundle.waist.len() as f32;
        let shift = root - Vec3::splat(0.5);
        let scale = self.bundle.manifest.normalisation.scale;
        let drawn = if self.pca {
            pca::project_points(&unit, shift, &self.bundle.pca_mean, &self.bundle.pca_basis)
        } else {
            unit
        };
        let points = drawn
            .iter()
            .map(|&p| (p - Vec3::splat(0.5)) / scale + self.world_root)
            .collect();
        self.world_root += shift / scale;
        self.pending = Some(Pending { latent, shift });
        self.frames += 1;
        self.clamped_total += clamped;
        Ok(Frame {
            index: self.frames - 1,
            action,
            points,
            root: self.world_root,
            clamped,
            clamped_total: self.clamped_total,
            gpu_ms,
            cpu_ms: clock.elapsed().as_secs_f64() * 1e3,
        })
    }
}
