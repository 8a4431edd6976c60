//! GPU benchmarks printed as a table: `unica bench` and `cargo bench` run the same code.
//! Numbers come from stage timings (GPU timestamps where available) or wall-clock time to
//! GPU idle, never from tests. Rows: the element-wise kernel, then for each model
//! configuration and precision the UNet (a whole 4-frame group, the cached context pass,
//! one target-only step), the VAE decoder and a whole generated frame; the rasterizer;
//! and for a bundle the live frame by stage, model to pixels.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use crate::engine::bundle::Bundle;
use crate::gpu::kernel::{PipelineCache, Precision, ScaleAdd};
use crate::gpu::timing::Profiler;
use crate::gpu::{GpuContext, GpuError};
use crate::nn::sampler::{self, Sampling, Schedule};
use crate::nn::unet::{UNet, UNetConfig};
use crate::nn::vae::{Decoder, VaeConfig};
use crate::nn::{Recorder, Tensor, Weights};

mod live;

pub use live::{describe, frame_stages, live, soak};

/// Elements per element-wise run (64 MiB of f32 in and out).
const ELEMENTS: usize = 1 << 24;
const REPEATS: usize = 10;

/// What to time.
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// The tiny configuration of the parity fixtures (random weights).
    pub tiny: bool,
    /// The default configuration (the shipped Witch's shape, random weights).
    pub default: bool,
    /// A trained bundle as well.
    pub bundle: Option<PathBuf>,
    pub sampling: Sampling,
    /// Timed runs per row (after one warm-up run).
    pub repeat: usize,
    /// Precisions to time (f16 only where the adapter has SHADER_F16).
    pub precisions: Vec<Precision>,
    /// Splats for the rasterizer rows at 1280×720 and 1920×1080 (0: none).
    pub splats: usize,
    /// The splat level of the bundle's live-frame rows (`None`: the adapter's default).
    pub splat_level: Option<usize>,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            tiny: true,
            default: true,
            bundle: None,
            sampling: Sampling::new(10, 2.0),
            repeat: 3,
            precisions: vec![Precision::F32, Precision::F16],
            splats: 250_000,
            splat_level: None,
        }
    }
}

/// Runs the benchmarks on `gpu` and prints the tables to `out`.
pub fn run(gpu: &GpuContext, options: &BenchOptions, out: &mut impl Write) -> anyhow::Result<()> {
    writeln!(out, "adapter: {}", gpu.adapter_label())?;
    writeln!(
        out,
        "capabilities: f16 {}, subgroups {}, timestamps {}",
        gpu.caps.shader_f16, gpu.caps.subgroups, gpu.caps.timestamps
    )?;
    let precisions: Vec<Precision> = options
        .precisions
        .iter()
        .copied()
        .filter(|&p| p == Precision::F32 || gpu.caps.shader_f16)
        .collect();
    kernels(gpu, &precisions, out)?;
    models(gpu, options, &precisions, out)?;
    if options.splats > 0 {
        raster(gpu, options.splats, options.repeat, out)?;
    }
    if let Some(dir) = &options.bundle {
        let level = options
            .splat_level
            .unwrap_or_else(|| crate::engine::appearance::default_level(gpu));
        frame_stages(gpu, dir, Some(options.sampling), level, options.repeat, out)?;
    }
    Ok(())
}

/// The splat rasterizer on a cloud of `count` Gaussians filling a person-sized box in
/// front of the camera, at two screen sizes.
fn raster(
    gpu: &GpuContext,
    count: usize,
    repeat: usize,
    out: &mut impl Write,
) -> anyhow::Result<()> {
    use crate::render::OrbitCamera;
    use crate::splat::ply::Splat;
    use crate::splat::raster::Rasterizer;
    use glam::{Quat, Vec3};
    writeln!(
        out,
        "\nsplat rasterizer: {count} splats in a 0.6 × 1.8 × 0.4 m box, median of {repeat} after a warm-up"
    )?;
    writeln!(
        out,
        "{:<12} {:>10} {:>14}",
        "size", "median ms", "sort entries"
    )?;
    let mut noise = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        noise ^= noise << 13;
        noise ^= noise >> 7;
        noise ^= noise << 17;
        (noise >> 40) as f32 / (1u64 << 24) as f32
    };
    let splats: Vec<Splat> = (0..count)
        .map(|_| Splat {
            position: Vec3::new(next() * 0.6 - 0.3, next() * 1.8, next() * 0.4 - 0.2),
            f_dc: Vec3::new(next(), next(), next()) - Vec3::splat(0.5),
            opacity: 0.5 + 0.5 * next(),
            scale: Vec3::new(0.004, 0.004, 0.001) * (1.0 + next()),
            rotation: Quat::from_rotation_y(next() * 6.0),
        })
        .collect();
    let buffer = Rasterizer::upload(gpu, &splats)?;
    let orbit = OrbitCamera {
        target: Vec3::new(0.0, 0.9, 0.0),
        yaw: 0.3,
        pitch: 0.1,
        distance: 2.6,
    };
    let mut rasterizer = Rasterizer::default();
    for (width, height) in [(1280, 720), (1920, 1080)] {
        let camera = orbit.splat_camera(width, height);
        let mut ms = Vec::new();
        let mut entries = 0;
        for run in 0..=repeat.max(1) {
            let start = Instant::now();
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            let raster =
                rasterizer.record(gpu, &mut encoder, &buffer, count, &camera, Vec3::ZERO)?;
            gpu.submit([encoder.finish()]);
            gpu.wait_idle();
            if run > 0 {
                ms.push(start.elapsed().as_secs_f64() * 1e3);
            } else {
                let info = crate::gpu::readback::buffer(gpu, &raster.info, "info")?;
                entries = u32::from_le_bytes(info[..4].try_into().expect("4 bytes"));
            }
        }
        ms.sort_by(f64::total_cmp);
        writeln!(
            out,
            "{:<12} {:>10.2} {entries:>14}",
            format!("{width}x{height}"),
            ms[ms.len() / 2]
        )?;
    }
    Ok(())
}

fn kernels(gpu: &GpuContext, precisions: &[Precision], out: &mut impl Write) -> anyhow::Result<()> {
    writeln!(
        out,
        "{:<28} {:>10} {:>10} {:>10}",
        "kernel", "median ms", "min ms", "GB/s"
    )?;
    let mut cache = PipelineCache::default();
    let x: Vec<f32> = (0..ELEMENTS).map(|i| (i % 1000) as f32 * 1e-3).collect();
    for &precision in precisions {
        let kernel = ScaleAdd::new(gpu, &mut cache, &x, 2.0, 1.0, precision)?;
        let mut profiler = Profiler::new(gpu);
        for _ in 0..REPEATS + 1 {
            profiler.stage(gpu, "scale_add", |encoder, timer| {
                kernel.record(gpu, encoder, timer)
            });
        }
        // The first run includes pipeline warm-up; drop it.
        let mut ms: Vec<f64> = profiler
            .finish(gpu)?
            .into_iter()
            .skip(1)
            .map(|t| t.ms)
            .collect();
        ms.sort_by(f64::total_cmp);
        let median = ms[ms.len() / 2];
        let gbps = kernel.bytes_moved() as f64 / (median * 1e-3) / 1e9;
        let name = format!("scale_add {precision:?} x{ELEMENTS}");
        writeln!(
            out,
            "{name:<28} {median:>10.3} {:>10.3} {gbps:>10.2}",
            ms[0]
        )?;
    }
    Ok(())
}

/// A model to time: its UNet and decoder, and where its shapes come from.
struct Model {
    name: String,
    unet: UNet,
    decoder: Decoder,
    schedule: Schedule,
}

fn models(
    gpu: &GpuContext,
    options: &BenchOptions,
    precisions: &[Precision],
    out: &mut impl Write,
) -> anyhow::Result<()> {
    let s = options.sampling;
    writeln!(
        out,
        "\nmodels: wall-clock from recording to GPU idle, median of {} after a warm-up; \
         {} DDIM steps, CFG scale {} (batch {})",
        options.repeat,
        s.steps,
        s.cfg_scale,
        batch(s)
    )?;
    writeln!(
        out,
        "{:<8} {:<4} {:<36} {:>8} {:>10} {:>9}",
        "model", "prec", "what", "GFLOP", "median ms", "GFLOP/s"
    )?;
    let mut pipelines = PipelineCache::default();
    for &precision in precisions {
        let mut list = Vec::new();
        if options.tiny {
            list.push(random_model(
                gpu,
                precision,
                "tiny",
                &UNetConfig::TINY,
                &VaeConfig::TINY,
            )?);
        }
        if options.default {
            list.push(random_model(
                gpu,
                precision,
                "default",
                &UNetConfig::DEFAULT,
                &VaeConfig::DEFAULT,
            )?);
        }
        if let Some(dir) = &options.bundle {
            let b = Bundle::load(dir, gpu, precision)?;
            list.push(Model {
                name: b.manifest.avatar.to_lowercase(),
                unet: b.unet,
                decoder: b.decoder,
                schedule: b.schedule,
            });
        }
        for model in &list {
            for row in model_rows(gpu, &mut pipelines, precision, model, options)? {
                let gflop = row.flops as f64 / 1e9;
                writeln!(
                    out,
                    "{:<8} {:<4} {:<36} {:>8.3} {:>10.2} {:>9.1}",
                    model.name,
                    format!("{precision:?}").to_lowercase(),
                    row.what,
                    gflop,
                    row.ms,
                    gflop / (row.ms * 1e-3)
                )?;
            }
        }
    }
    Ok(())
}

fn random_model(
    gpu: &GpuContext,
    precision: Precision,
    name: &str,
    unet: &UNetConfig,
    vae: &VaeConfig,
) -> Result<Model, crate::nn::LoadError> {
    let w = Weights::random(gpu, precision);
    Ok(Model {
        name: name.into(),
        unet: UNet::load(&w.at("unet"), unet)?,
        decoder: Decoder::load(&w.at("decoder"), vae)?,
        schedule: Schedule::scaled_linear(1000, 0.00085, 0.012),
    })
}

fn batch(s: Sampling) -> usize {
    if s.cfg_scale == 1.0 { 1 } else { 2 }
}

struct Row {
    what: String,
    flops: u64,
    ms: f64,
}

/// Times `record` (recording, one submission, waiting for the GPU) `repeat` times after
/// a warm-up; the FLOPs are those it recorded.
/// Times recorded work on one adapter: the median of `repeat` runs after a warm-up.
struct Timer<'a> {
    gpu: &'a GpuContext,
    pipelines: &'a mut PipelineCache,
    precision: Precision,
    repeat: usize,
}

impl Timer<'_> {
    fn time(
        &mut self,
        what: String,
        record: impl Fn(&mut Recorder) -> Result<(), GpuError>,
    ) -> Result<Row, GpuError> {
        let mut ms = Vec::new();
        let mut flops = 0;
        for run in 0..=self.repeat.max(1) {
            let start = Instant::now();
            let mut r = Recorder::new(self.gpu, self.pipelines, self.precision);
            record(&mut r)?;
            flops = r.flops();
            r.submit();
            self.gpu.wait_idle();
            if run > 0 {
                ms.push(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        ms.sort_by(f64::total_cmp);
        Ok(Row {
            what,
            flops,
            ms: ms[ms.len() / 2],
        })
    }
}

fn model_rows(
    gpu: &GpuContext,
    pipelines: &mut PipelineCache,
    precision: Precision,
    model: &Model,
    options: &BenchOptions,
) -> Result<Vec<Row>, GpuError> {
    let cfg = &model.unet.cfg;
    let (s, n) = (options.sampling, batch(options.sampling));
    let latent = |frames: usize| -> Result<Tensor, GpuError> {
        let shape = [n, frames, cfg.latent, 16, 16];
        let values: Vec<f32> = (0..shape.iter().product())
            .map(|i| ((i % 97) as f32 - 48.0) / 48.0)
            .collect();
        Tensor::upload(gpu, "bench.latent", &shape, &values, precision)
    };
    let (group, context) = (latent(cfg.frames)?, latent(cfg.frames - 1)?);
    let target = latent(1)?.reshaped(&[n, cfg.latent, 16, 16]);
    let actions: Vec<usize> = (0..n)
        .map(|i| if i == 0 { 1 } else { cfg.null_action() })
        .collect();
    let mut timesteps = vec![0.0; n * cfg.frames];
    for t in timesteps
        .iter_mut()
        .skip(cfg.frames - 1)
        .step_by(cfg.frames)
    {
        *t = 700.0;
    }
    let mut timer = Timer {
        gpu,
        pipelines,
        precision,
        repeat: options.repeat,
    };
    let mut rows = vec![
        timer.time(format!("unet step: {}-frame group x{n}", cfg.frames), |r| {
            model.unet.groups(r, &group, &timesteps, &actions).map(drop)
        })?,
        timer.time(
            format!("unet context pass: {} frames x{n}", cfg.frames - 1),
            |r| model.unet.context(r, &context, &actions).map(drop),
        )?,
    ];
    // The target-only step, timed on its own against a cache made outside the timing.
    let cache = {
        let mut r = Recorder::new(gpu, timer.pipelines, precision);
        let cache = model.unet.context(&mut r, &context, &actions)?;
        r.submit();
        cache
    };
    rows.push(
        timer.time(format!("unet step: target frame x{n} (cached)"), |r| {
            model.unet.next(r, &target, 700.0, &cache).map(drop)
        })?,
    );
    let context1 = Tensor::upload(
        gpu,
        "bench.context",
        &[1, cfg.frames - 1, cfg.latent, 16, 16],
        &vec![0.1; (cfg.frames - 1) * cfg.latent * 256],
        precision,
    )?;
    let noise = Tensor::upload(
        gpu,
        "bench.noise",
        &[1, cfg.latent, 16, 16],
        &vec![0.5; cfg.latent * 256],
        precision,
    )?;
    rows.push(timer.time("vae decode x1".into(), |r| {
        model.decoder.forward(r, &noise).map(drop)
    })?);
    rows.push(timer.time(
        format!("generated frame: {} steps + decode", s.steps),
        |r| {
            let z =
                sampler::sample_next(r, &model.unet, &model.schedule, &context1, &[1], &noise, s)?;
            model.decoder.forward(r, &z).map(drop)
        },
    )?);
    Ok(rows)
}
