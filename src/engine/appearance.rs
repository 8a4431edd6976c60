//! From a generated frame's points to splats (docs/architecture.md, Appearance): base
//! splats in each pixel's local surface frame, the refiner's residuals (run on the 128²
//! points), and, at a finer splat level, the foreground-aware GPU upscale of the
//! positions, colours and residuals to that level's map, whose pixels become the splats.

use glam::Vec3;

use super::bundle::Bundle;
use crate::gpu::kernel::{PipelineCache, Precision};
use crate::gpu::{GpuContext, GpuError};
use crate::nn::{Recorder, Tensor};
use crate::posmap::MAP_SIZE;
use crate::splat::base::{self, RESIDUALS};
use crate::splat::frame::FEATURES;
use crate::splat::ply::Splat;
use crate::splat::serialise;
use crate::splat::upscale;

use super::surface::COLOR;

/// Map sizes splats can be drawn at: one splat per foreground pixel of that map.
pub const LEVELS: [usize; 4] = [128, 256, 512, 1024];

/// The splat level to use when none is asked for: 1024 (docs/architecture.md, Appearance)
/// on a GPU; 256 on a CPU driver such as lavapipe, where 250k splats take seconds per
/// frame.
pub fn default_level(gpu: &GpuContext) -> usize {
    if gpu.cpu_driver() { 256 } else { 1024 }
}

/// The foreground pixels of one level, their neighbours and colours.
struct Level {
    size: usize,
    pixels: Vec<u32>,
    neighbours: Vec<[Option<u32>; 4]>,
    colors: Vec<Vec3>,
}

pub struct Appearance {
    gpu: GpuContext,
    pipelines: PipelineCache,
    precision: Precision,
    scale: f32,
    waist: Vec<u32>,
    coarse: Level,
    /// The 128² foreground mask.
    mask: Vec<f32>,
    fine: Option<Level>,
    /// Draw the refiner's residuals (when the bundle has a refiner).
    pub refine: bool,
    /// The last frame's stage times.
    pub times: StageTimes,
}

/// Milliseconds of the last [`Appearance::splats`], by stage (readbacks included).
#[derive(Clone, Copy, Debug, Default)]
pub struct StageTimes {
    /// Base splats of the 128² points.
    pub base: f64,
    /// The refiner's features, network and readback.
    pub refiner: f64,
    /// Upscaling positions and residuals to the splat level, and the fine base splats.
    pub upscale: f64,
}

impl Appearance {
    /// Splats at map size `level` (one of [`LEVELS`]).
    pub fn new(
        gpu: &GpuContext,
        bundle: &Bundle,
        precision: Precision,
        level: usize,
    ) -> Result<Self, GpuError> {
        assert!(LEVELS.contains(&level), "splat level {level}");
        let pixels = bundle.pixels.clone();
        let colors = bundle
            .colors
            .clone()
            .unwrap_or_else(|| vec![COLOR; pixels.len()]);
        let mut mask = vec![0.0f32; MAP_SIZE * MAP_SIZE];
        for &p in &pixels {
            mask[p as usize] = 1.0;
        }
        let mut pipelines = PipelineCache::default();
        let fine = if level > MAP_SIZE {
            let (colors, fine_mask) =
                upscale(gpu, &mut pipelines, &mask, &map(&pixels, &colors), level)?;
            let fine_pixels: Vec<u32> = (0..level * level)
                .filter(|&i| fine_mask[i] > 0.0)
                .map(|i| i as u32)
                .collect();
            Some(Level {
                size: level,
                neighbours: base::neighbours(&fine_pixels, level),
                colors: gather(&colors, &fine_pixels, level),
                pixels: fine_pixels,
            })
        } else {
            None
        };
        Ok(Self {
            gpu: gpu.clone(),
            pipelines,
            precision,
            scale: bundle.manifest.normalisation.scale,
            waist: bundle.waist.clone(),
            coarse: Level {
                size: MAP_SIZE,
                neighbours: base::neighbours(&pixels, MAP_SIZE),
                pixels,
                colors,
            },
            mask,
            fine,
            refine: bundle.refiner.is_some(),
            times: StageTimes::default(),
        })
    }

    /// The number of splats a frame has.
    pub fn count(&self) -> usize {
        self.fine.as_ref().unwrap_or(&self.coarse).pixels.len()
    }

    pub fn level(&self) -> usize {
        self.fine.as_ref().unwrap_or(&self.coarse).size
    }

    /// The splats of one frame's world-space points (one per 128² foreground pixel).
    pub fn splats(&mut self, bundle: &Bundle, points: &[Vec3]) -> Result<Vec<Splat>, GpuError> {
        let clock = std::time::Instant::now();
        let lap = || clock.elapsed().as_secs_f64() * 1e3;
        let coarse = &self.coarse;
        let root =
            self.waist.iter().map(|&w| points[w as usize]).sum::<Vec3>() / self.waist.len() as f32;
        let unit: Vec<Vec3> = points
            .iter()
            .map(|&p| (p - root) * self.scale + Vec3::splat(0.5))
            .collect();
        let t = base::tangents(points, &coarse.neighbours);
        let (mut splats, normals) = base::base_splats(points, &coarse.colors, &t);
        self.times.base = lap();
        let residuals = match bundle.refiner.as_ref().filter(|_| self.refine) {
            Some(refiner) => {
                let features = base::features(&unit, &splats, &normals, t.median);
                let mut r = Recorder::new(&self.gpu, &mut self.pipelines, self.precision);
                let x = r.upload("refiner.features", &[unit.len(), FEATURES], &features)?;
                let o = serialise::host_orders(&unit, refiner.cfg.stride).upload(&self.gpu)?;
                let y: Tensor = refiner.forward(&mut r, &x, &o.fine, &o.coarse, &o.groups)?;
                r.submit();
                Some((y.read(&self.gpu)?, refiner.cfg.mean_bound / self.scale))
            }
            None => None,
        };
        self.times.refiner = lap() - self.times.base;
        let before_upscale = lap();
        let Some(fine) = &self.fine else {
            if let Some((residuals, bound)) = &residuals {
                base::refine(&mut splats, residuals, *bound);
            }
            self.times.upscale = 0.0;
            return Ok(splats);
        };
        let (gpu, pipelines, mask) = (&self.gpu, &mut self.pipelines, &self.mask);
        let size = fine.size;
        let mut up = |values: &[Vec3]| -> Result<Vec<Vec3>, GpuError> {
            let (upscaled, _) = upscale(gpu, pipelines, mask, &map(&coarse.pixels, values), size)?;
            Ok(gather(&upscaled, &fine.pixels, size))
        };
        let fine_points = up(points)?;
        let t = base::tangents(&fine_points, &fine.neighbours);
        let (mut splats, _) = base::base_splats(&fine_points, &fine.colors, &t);
        if let Some((residuals, bound)) = residuals {
            // 14 residual channels upscaled three at a time (one channel of padding).
            let mut fine_residuals = vec![0.0; fine.pixels.len() * RESIDUALS];
            for first in (0..RESIDUALS).step_by(3) {
                let part: Vec<Vec3> = residuals
                    .chunks_exact(RESIDUALS)
                    .map(|r| {
                        Vec3::from_array(
                            [0, 1, 2].map(|k| r.get(first + k).copied().unwrap_or(0.0)),
                        )
                    })
                    .collect();
                for (i, v) in up(&part)?.iter().enumerate() {
                    for (k, value) in v.to_array().into_iter().enumerate() {
                        if first + k < RESIDUALS {
                            fine_residuals[i * RESIDUALS + first + k] = value;
                        }
                    }
                }
            }
            base::refine(&mut splats, &fine_residuals, bound);
        }
        base::widen_splats(&mut splats, base::widen(size));
        self.times.upscale = lap() - before_upscale;
        Ok(splats)
    }
}

/// A [3, 128, 128] map with foreground `mask` upscaled on the GPU to `size`: (map, mask).
fn upscale(
    gpu: &GpuContext,
    pipelines: &mut PipelineCache,
    mask: &[f32],
    map: &[f32],
    size: usize,
) -> Result<(Vec<f32>, Vec<f32>), GpuError> {
    upscale::run(
        gpu,
        pipelines,
        map,
        mask,
        MAP_SIZE,
        MAP_SIZE,
        size / MAP_SIZE,
    )
}

/// Three values per foreground pixel as a [3, 128, 128] map (0 behind).
fn map(pixels: &[u32], values: &[Vec3]) -> Vec<f32> {
    let plane = MAP_SIZE * MAP_SIZE;
    let mut map = vec![0.0; 3 * plane];
    for (&p, v) in pixels.iter().zip(values) {
        for (k, value) in v.to_array().into_iter().enumerate() {
            map[k * plane + p as usize] = value;
        }
    }
    map
}

/// The values of a [3, size, size] map at `pixels`.
fn gather(map: &[f32], pixels: &[u32], size: usize) -> Vec<Vec3> {
    let plane = size * size;
    pixels
        .iter()
        .map(|&p| {
            let p = p as usize;
            Vec3::new(map[p], map[plane + p], map[2 * plane + p])
        })
        .collect()
}
