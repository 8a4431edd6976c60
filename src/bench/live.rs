//! The live loop's benchmarks: `unica bench --live` (generated frames as the app makes
//! them, with the GPU work counted and a profile of one frame), `--soak` (a long run's
//! speed, values and memory) and the bundle's stage table of `unica bench`.

use std::io::Write;
use std::time::Instant;

use crate::gpu::GpuContext;
use crate::gpu::plan::{Plan, StepProfile};
use crate::nn::sampler::Sampling;

/// A long headless run of the live loop (geometry only): frames per second, values that
/// left [0, 1], non-finite values, resident memory before and after, and per key segment
/// the heading of the world path against the key's direction.
pub fn soak(
    gpu: &GpuContext,
    dir: &std::path::Path,
    frames: usize,
    sampling: Option<Sampling>,
    out: &mut impl Write,
) -> anyhow::Result<()> {
    use crate::action::Action;
    use crate::engine::{Engine, EngineOptions};
    let options = EngineOptions {
        sampling,
        ..EngineOptions::default()
    };
    let mut engine = Engine::new(gpu, dir, &options)?;
    writeln!(out, "adapter: {}", gpu.adapter_label())?;
    let s = engine.sampling();
    writeln!(
        out,
        "soak: {frames} frames of {}, {} DDIM steps, CFG {}, keys repeating {SOAK_KEYS}",
        dir.display(),
        s.steps,
        s.cfg_scale
    )?;
    let keys = crate::action::KeyScript::parse(&SOAK_KEYS.repeat(frames.div_ceil(270)))?;
    let rss_start = resident_mib();
    let (mut clamped, mut non_finite) = (0usize, 0usize);
    let mut roots = vec![engine.root()];
    let bar = indicatif::ProgressBar::new(frames as u64);
    let start = Instant::now();
    for i in 0..frames {
        let frame = engine.step(keys.action_at(i))?;
        clamped += frame.clamped;
        non_finite += frame.points.iter().filter(|p| !p.is_finite()).count();
        roots.push(frame.root);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let rss_end = resident_mib();
    writeln!(
        out,
        "{:.2} generated frames per second ({seconds:.0} s)",
        frames as f64 / seconds
    )?;
    writeln!(
        out,
        "clamped values: {clamped}; non-finite points: {non_finite}"
    )?;
    let mib = |m: Option<f64>| m.map_or("n/a".into(), |m| format!("{m:.0} MiB"));
    writeln!(
        out,
        "resident memory: {} after loading, {} at the end",
        mib(rss_start),
        mib(rss_end)
    )?;
    // Heading of each movement segment after its first 15 frames (the turn), against
    // the key's direction: W +Z (0°), A +X (90°), S -Z (180°), D -X (-90°).
    let mut errors = Vec::new();
    let mut start_frame = 0;
    for i in 1..=frames {
        if i == frames || keys.action_at(i) != keys.action_at(start_frame) {
            let action = keys.action_at(start_frame);
            let want = match action {
                Action::Forward => Some(0.0f32),
                Action::Left => Some(90.0),
                Action::Backward => Some(180.0),
                Action::Right => Some(-90.0),
                Action::Idle => None,
            };
            if let (Some(want), true) = (want, i >= start_frame + 25) {
                let leg = roots[i] - roots[start_frame + 15];
                let heading = leg.x.atan2(leg.z).to_degrees();
                let error = (heading - want + 540.0).rem_euclid(360.0) - 180.0;
                errors.push(error.abs());
            }
            start_frame = i;
        }
    }
    errors.sort_by(f32::total_cmp);
    if let (Some(median), Some(worst)) = (errors.get(errors.len() / 2), errors.last()) {
        writeln!(
            out,
            "path heading error over {} movement segments: median {median:.1}°, worst {worst:.1}°",
            errors.len()
        )?;
    }
    Ok(())
}

/// The soak's key cycle (270 frames): every direction, turns between them, and a stop.
const SOAK_KEYS: &str = "60W 60D 60S 60A 30I ";

/// This process's resident memory (Linux), MiB.
fn resident_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// The whole live frame of a bundle on this adapter: the engine's frame plan (model,
/// clamping, PCA, splats at the splat level; waited for) and the rasterizer (projection,
/// sort, blending) at 1280×720; then generated frames per second.
pub fn frame_stages(
    gpu: &GpuContext,
    dir: &std::path::Path,
    sampling: Option<Sampling>,
    level: usize,
    repeat: usize,
    out: &mut impl Write,
) -> anyhow::Result<()> {
    use crate::action::Action;
    use crate::engine::{Engine, EngineOptions};
    use crate::render::OrbitCamera;
    use crate::splat::raster::Rasterizer;
    let options = EngineOptions {
        sampling,
        splat_level: Some(level),
        ..EngineOptions::default()
    };
    let mut engine = Engine::new(gpu, dir, &options)?;
    let s = engine.sampling();
    let count = engine.splats().map_or(0, |(_, n)| n);
    writeln!(
        out,
        "\nlive frame of {}: {} DDIM steps, CFG {}, splat level {level} ({count} splats), \
         refiner {}; median ms of {repeat} frames after a warm-up",
        dir.display(),
        s.steps,
        s.cfg_scale,
        if engine.refine() {
            "on"
        } else {
            "off (none in the bundle)"
        },
    )?;
    let mut rasterizer = Rasterizer::default();
    let stages = ["frame plan (model + splats)", "raster 1280x720"];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); stages.len()];
    for run in 0..=repeat.max(1) {
        let clock = Instant::now();
        engine.frame(Action::Forward)?;
        engine.finish();
        let model = clock.elapsed().as_secs_f64() * 1e3;
        let orbit = OrbitCamera {
            target: engine.root(),
            ..OrbitCamera::default()
        };
        let camera = orbit.splat_camera(1280, 720);
        let (buffer, count) = engine.splats().expect("splats asked for");
        let clock = Instant::now();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        rasterizer.record(gpu, &mut encoder, buffer, count, &camera, glam::Vec3::ZERO)?;
        gpu.submit([encoder.finish()]);
        gpu.wait_idle();
        let raster = clock.elapsed().as_secs_f64() * 1e3;
        if run > 0 {
            for (list, ms) in times.iter_mut().zip([model, raster]) {
                list.push(ms);
            }
        }
    }
    let median = |list: &mut Vec<f64>| {
        list.sort_by(f64::total_cmp);
        list[list.len() / 2]
    };
    let mut total = 0.0;
    for (name, list) in stages.iter().zip(&mut times) {
        let ms = median(list);
        total += ms;
        writeln!(out, "{name:<32} {ms:>10.2}")?;
    }
    writeln!(out, "{:<32} {total:>10.2}", "whole frame")?;
    writeln!(out, "generated frames per second: {:.2}", 1e3 / total)?;
    stage_lines(&mut engine, out)
}

/// What the window adds to each generated frame: the last frame's splats rasterized as
/// the viewport draws them (the default orbit camera on the avatar; 640 × 400 is the 3D
/// view of a 1280 × 800 window at the half size a CPU driver draws), one line per size:
/// `window raster WxH: ms=X dispatches=D sort_entries=E splats=S` (median of 5 after a
/// warm-up, each submitted and waited for alone).
fn window_raster_lines(
    gpu: &GpuContext,
    engine: &crate::engine::Engine,
    out: &mut impl Write,
) -> anyhow::Result<()> {
    use crate::splat::raster::Rasterizer;
    let Some((buffer, count)) = engine.splats() else {
        return Ok(());
    };
    let orbit = crate::render::OrbitCamera {
        target: engine.root(),
        ..Default::default()
    };
    for (width, height) in [(640, 400), (1280, 800)] {
        let camera = orbit.splat_camera(width, height);
        let mut rasterizer = Rasterizer::default();
        let mut times = Vec::new();
        let mut entries = 0;
        let mut dispatches = 0;
        for run in 0..6 {
            let before = gpu.counts();
            let clock = Instant::now();
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            let raster =
                rasterizer.record(gpu, &mut encoder, buffer, count, &camera, glam::Vec3::ONE)?;
            gpu.submit([encoder.finish()]);
            gpu.wait_idle();
            if run > 0 {
                times.push(clock.elapsed().as_secs_f64() * 1e3);
            }
            dispatches = (gpu.counts() - before).dispatches;
            let info = crate::gpu::readback::buffer(gpu, &raster.info, "sort entries")?;
            entries = bytemuck::pod_read_unaligned::<u32>(&info[..4]);
        }
        times.sort_by(f64::total_cmp);
        writeln!(
            out,
            "window raster {width}x{height}: ms={:.1} dispatches={dispatches} \
             sort_entries={entries} splats={count}",
            times[times.len() / 2]
        )?;
    }
    Ok(())
}

/// One more frame, each stage of its plan submitted and waited for alone: one line per
/// stage, `stage NAME: dispatches=D ms=X gpu_ms=Y gflop=F gflops=G` (ms: wall clock
/// around the submission and the wait; gpu_ms: the GPU's timestamps, "-" where the
/// device has none; GFLOP/s from gpu_ms where there is one; FLOPs as the trainer counts
/// them, stages without counted FLOPs print 0).
fn stage_lines(engine: &mut crate::engine::Engine, out: &mut impl Write) -> anyhow::Result<()> {
    writeln!(
        out,
        "one more frame, each stage submitted and waited for alone ({:?} kernels):",
        engine.kernels()
    )?;
    for stage in engine.profile_stages(crate::action::Action::Forward)? {
        let gflop = stage.flops as f64 / 1e9;
        let gpu_ms = stage.gpu_ms.map_or("-".into(), |ms| format!("{ms:.2}"));
        writeln!(
            out,
            "stage {}: dispatches={} ms={:.1} gpu_ms={gpu_ms} gflop={:.3} gflops={:.2}",
            stage.name,
            stage.dispatches,
            stage.ms,
            gflop,
            gflop / (stage.gpu_ms.unwrap_or(stage.ms) / 1e3)
        )?;
    }
    Ok(())
}

/// The sampler in words: "one pass (distilled)" or "10 DDIM steps, CFG 3.5".
pub fn describe(s: Sampling) -> String {
    match s.kind {
        crate::nn::sampler::SamplerKind::OnePass => "one UNet pass (distilled student)".into(),
        crate::nn::sampler::SamplerKind::Ddim => {
            format!("{} DDIM steps, CFG {}", s.steps, s.cfg_scale)
        }
    }
}

/// `unica bench --live N`: N generated frames after a warm-up frame, made as the app
/// makes them — key → the engine's frame plan (model, clamping, PCA, splats at `level`
/// into the rasterizer's buffer) — with the GPU layer's counts per frame. cpu_ms is the
/// time spent in `Engine::frame` on this thread (it never waits inside a frame): the
/// submission, then the recording of the next frame while the GPU runs this one;
/// wall_ms is the whole run, ended by waiting for the GPU, per frame.
pub fn live(
    gpu: &GpuContext,
    dir: &std::path::Path,
    sampling: Sampling,
    level: usize,
    frames: usize,
    out: &mut impl Write,
) -> anyhow::Result<()> {
    use crate::action::Action;
    use crate::engine::{Engine, EngineOptions};
    let options = EngineOptions {
        sampling: Some(sampling),
        splat_level: Some(level),
        ..EngineOptions::default()
    };
    let mut engine = Engine::new(gpu, dir, &options)?;
    writeln!(out, "adapter: {}", gpu.adapter_label())?;
    let (dispatches, flops) = engine.plan_counts(Action::Forward);
    writeln!(
        out,
        "live: {}, splat level {level} ({} splats, refiner {}); frame plan: \
         {dispatches} dispatches, {} copies, {:.2} GFLOP",
        describe(sampling),
        engine.splats().map_or(0, |(_, n)| n),
        if engine.refine() { "on" } else { "off" },
        engine.plan_copies(),
        flops as f64 / 1e9
    )?;
    if let Some(idle) = engine.sampling().idle_plan() {
        let (idle_dispatches, idle_flops) = engine.plan_counts(Action::Idle);
        writeln!(
            out,
            "idle frames (CFG {}{}): {idle_dispatches} dispatches, {:.2} GFLOP",
            idle.cfg_scale,
            if idle.cfg_scale == 1.0 {
                ", unguided, one batch"
            } else {
                ""
            },
            idle_flops as f64 / 1e9
        )?;
    }
    if let (Some(brake), Some((brake_dispatches, brake_flops))) =
        (engine.sampling().brake(), engine.brake_plan_counts())
    {
        writeln!(
            out,
            "braking Idle frames (the first {} after a key, CFG {}): {brake_dispatches} dispatches, \
             {:.2} GFLOP",
            engine.sampling().idle_brake_frames,
            brake.cfg_scale,
            brake_flops as f64 / 1e9
        )?;
    }
    if let (Some(turn), Some((turn_dispatches, turn_flops))) =
        (engine.sampling().turn_brake(), engine.turn_plan_counts())
    {
        writeln!(
            out,
            "turning frames (the first {} under a key of a new direction, CFG {}): \
             {turn_dispatches} dispatches, {:.2} GFLOP",
            engine.sampling().turn_brake_frames,
            turn.cfg_scale,
            turn_flops as f64 / 1e9
        )?;
    }
    let keys = [
        Action::Forward,
        Action::Forward,
        Action::Right,
        Action::Idle,
    ];
    engine.frame(keys[0])?;
    engine.finish();
    let before = gpu.counts();
    let bar = indicatif::ProgressBar::new(frames as u64);
    let mut cpu_ms = 0.0;
    let start = Instant::now();
    for i in 1..=frames {
        let clock = Instant::now();
        engine.frame(keys[i % keys.len()])?;
        cpu_ms += clock.elapsed().as_secs_f64() * 1e3;
        // As the app paces itself: the next frame is submitted once this one has run
        // (wgpu itself blocks a submission that runs two frames ahead).
        engine.finish();
        bar.inc(1);
    }
    let wall_ms = start.elapsed().as_secs_f64() * 1e3 / frames as f64;
    bar.finish_and_clear();
    let c = gpu.counts() - before;
    let n = frames as f64;
    let per = |v: u64| {
        let x = v as f64 / n;
        if x.fract() == 0.0 {
            format!("{x:.0}")
        } else {
            format!("{x:.2}")
        }
    };
    writeln!(
        out,
        "per generated frame: unet_passes={} dispatches={} submissions={} readbacks={} \
         readback_bytes={} buffers_created={} bind_groups_created={} cpu_ms={:.2} wall_ms={:.1} \
         fps={:.2}",
        sampling.unet_passes(),
        per(c.dispatches),
        per(c.submissions),
        per(c.readbacks),
        per(c.readback_bytes),
        per(c.buffers),
        per(c.bind_groups),
        cpu_ms / n,
        wall_ms,
        1e3 / wall_ms
    )?;
    let state = engine.state();
    writeln!(
        out,
        "after {} frames: world root ({:.3}, {:.3}, {:.3}) m, {} values clamped",
        state.frames, state.root[0], state.root[1], state.root[2], state.clamped_total
    )?;
    window_raster_lines(gpu, &engine, out)?;
    stage_lines(&mut engine, out)?;
    writeln!(
        out,
        "one more frame, each dispatch or copy submitted and waited for alone (ms by shader):"
    )?;
    let steps = engine.profile(Action::Forward)?;
    let profile = Plan::profile(&steps);
    let total: f64 = profile.iter().map(|p| p.ms).sum();
    let gpu_total: Option<f64> = profile.iter().map(|p| p.gpu_ms).sum();
    let gpu = |ms: Option<f64>| ms.map_or(String::new(), |ms| format!(" {ms:>10.3} ms on the GPU"));
    for p in &profile {
        let what = if p.name.starts_with("copy") {
            "copies    "
        } else {
            "dispatches"
        };
        let (name, count, ms) = (p.name, p.count, p.ms);
        writeln!(
            out,
            "  {name:<32} {count:>5} {what} {ms:>10.1} ms{}",
            gpu(p.gpu_ms)
        )?;
    }
    writeln!(
        out,
        "  {:<32} {:>5}            {total:>10.1} ms{}",
        "all",
        "",
        gpu(gpu_total)
    )?;
    slowest_steps(&steps, out)
}

/// The slowest single dispatches of a profile (by GPU time where the device has
/// timestamps): where the next saving is, with the workgroup grid that says how much of
/// the device the dispatch fills.
fn slowest_steps(steps: &[StepProfile], out: &mut impl Write) -> anyhow::Result<()> {
    const SHOWN: usize = 24;
    let key = |s: &StepProfile| s.gpu_ms.unwrap_or(s.ms);
    let mut slowest: Vec<&StepProfile> = steps.iter().collect();
    slowest.sort_by(|a, b| key(b).total_cmp(&key(a)));
    writeln!(
        out,
        "the {SHOWN} slowest steps of that frame (step number in the frame, workgroups x×y):"
    )?;
    for s in slowest.iter().take(SHOWN) {
        let grid = s
            .grid
            .map_or(String::from("-"), |g| format!("{}x{}", g.x, g.y));
        let gpu = s.gpu_ms.map_or(String::new(), |ms| {
            format!(" {:>8.1} µs on the GPU", ms * 1e3)
        });
        writeln!(
            out,
            "  #{:<4} {:<34} {grid:>10} {:>8.1} µs{gpu}",
            s.index,
            s.name,
            s.ms * 1e3
        )?;
    }
    Ok(())
}
