//! The live neural avatar (docs/architecture.md, The live loop): the window of three
//! context maps, turned to the model's heading (the bundle's `heading`: the last movement
//! key's direction turned to W's, or not turned) and encoded into context latents → the
//! UNet + DDIM with CFG → decode → turned back, clamped, the new frame's root shift → PCA
//! cleans what is drawn (never fed back) → world-space points, while the window of maps
//! slides and is recentred on the new root, and the world root accumulates the root
//! motion (the shift, or where the bundle says `root_motion: decoded` the new root minus
//! the last context latent's, decoded too). All of it is one captured [`Plan`] made at
//! load (and again when the sampling or PCA setting changes): a generated frame writes
//! its noise and action ids, submits the plan and creates nothing. The plan's commands
//! for the next frame are recorded right after a frame is submitted, while the GPU runs
//! it. The only readback is the 64-byte [`FrameState`] (world root, shift, motion,
//! clamp counts), mapped asynchronously and picked up by [`Engine::poll`]. Beside a window
//! (`EngineOptions::split`) the plan is submitted part by part (context pass, each step,
//! decode), each part waited for on the caller's thread, so the window's own submissions
//! interleave. A guided sampler whose Idle frames are guided at another scale
//! (`Sampling::for_action`) gets a second plan for them: one batch where Idle is unguided
//! (the conditional prediction alone, half the UNet work), else the guided batch at
//! Idle's scale; one that brakes (`Sampling::for_frame`: the first Idle frames after a
//! key at a braking scale) a third, the guided batch at that scale; one that brakes
//! turns (the first frames under a key of a new direction) a fourth. `appearance` turns a
//! frame's points into splats.

pub mod appearance;
pub mod bundle;
mod capture;
pub mod kernels;
mod live;
pub mod pca;
pub mod recentre;
pub mod surface;

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use glam::Vec3;

use crate::action::Action;
use crate::gpu::kernel::{PipelineCache, Precision};
use crate::gpu::plan::{StageProfile, StepProfile};
use crate::gpu::{GpuContext, GpuError, readback};
use crate::nn::ops::{Indices, Plan};
use crate::nn::sampler::{KeyRun, Sampling};
use crate::nn::{LoadError, Recorder};
use crate::random::Rng;
use crate::splat::frame::SplatFrame;
use crate::splat::ply::Splat;
use crate::splat::raster::GpuSplat;
use bundle::{Bundle, Heading};
use kernels::{FrameState, HeadingTurns};
use live::{Live, initial_state};
use recentre::Start;

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
    /// Make the frame's splats at this level (128, 256, 512 or 1024) into the
    /// rasterizer's buffer as part of the frame; `None`: geometry only.
    pub splat_level: Option<usize>,
    /// Apply the bundle's refiner to the splats (when it has one).
    pub refine: bool,
    /// The kernel variant the frame plans record; `None`: by adapter (or
    /// `UNICA_KERNELS`).
    pub kernels: Option<crate::nn::Kernels>,
}

impl Default for EngineOptions {
    fn default() -> Self {
        Self {
            precision: Precision::F32,
            seed: 0,
            sampling: None,
            pca: true,
            split: false,
            splat_level: None,
            refine: true,
            kernels: None,
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

/// A captured frame and the action ids it reads.
struct FramePlan {
    plan: Plan,
    actions: Indices,
    guided: bool,
    sampling: Sampling,
    pca: bool,
    /// The splat level and refiner setting it draws with (None: no splats).
    look: Option<(usize, bool)>,
}

/// The captured plans: every frame's, Idle's where its guidance differs, braking Idle's
/// where the sampler brakes.
#[derive(Default)]
struct Plans {
    keys: Option<FramePlan>,
    /// The plan Idle frames run when the sampler guides them at another scale than the
    /// keys (`Sampling::for_action`): one batch where Idle is unguided.
    idle: Option<FramePlan>,
    /// The plan of the first Idle frames after a key when the sampler brakes
    /// (`Sampling::brake`).
    brake: Option<FramePlan>,
    /// The plan of the first frames of a turn when the sampler brakes turns
    /// (`Sampling::turn_brake`).
    turn: Option<FramePlan>,
}

/// Which captured plan a frame runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Which {
    Keys,
    Idle,
    Brake,
    Turn,
}

impl Plans {
    /// The plan a frame under `action` runs, once prepared, `run` being where it stands
    /// in the keys: the braking plan for the first Idle frames after a key where there
    /// is one, the Idle plan for other Idle frames where there is one, the turning plan
    /// for the first frames of a turn where there is one, else the frame plan.
    fn which(&self, action: Action, run: KeyRun) -> Which {
        let keys = self.keys.as_ref().expect("prepared");
        if action != Action::Idle {
            return match &self.turn {
                Some(_) if keys.sampling.turn_brakes(run) => Which::Turn,
                _ => Which::Keys,
            };
        }
        match (&self.brake, &self.idle) {
            (Some(_), _) if keys.sampling.brakes(run) => Which::Brake,
            (_, Some(_)) => Which::Idle,
            _ => Which::Keys,
        }
    }

    fn plan(&self, which: Which) -> &FramePlan {
        let plan = match which {
            Which::Keys => &self.keys,
            Which::Idle => &self.idle,
            Which::Brake => &self.brake,
            Which::Turn => &self.turn,
        };
        plan.as_ref().expect("prepared")
    }

    fn get(&self, action: Action, run: KeyRun) -> &FramePlan {
        self.plan(self.which(action, run))
    }
}

/// The next frame's work, recorded while the GPU runs the frame before it (unsplit
/// frames): the plan it was recorded from, and its commands.
struct Ahead {
    which: Which,
    commands: wgpu::CommandBuffer,
}

/// A mapped readback of the frame state in flight.
struct Slot {
    staging: wgpu::Buffer,
    /// Set by the map callback: Ok when the bytes can be read.
    arrived: Arc<Mutex<Option<Result<(), wgpu::BufferAsyncError>>>>,
    busy: bool,
}

pub struct Engine {
    gpu: GpuContext,
    pipelines: PipelineCache,
    precision: Precision,
    pub bundle: Bundle,
    sampling: Sampling,
    pca: bool,
    split: bool,
    /// The kernel variant the frame plans record.
    kernels: crate::nn::Kernels,
    live: Live,
    plans: Plans,
    /// The next frame's commands, recorded after this frame's submission on the guess
    /// that its plan stays (dropped when the frame runs another plan, or the plans are
    /// captured again).
    ahead: Option<Ahead>,
    /// Where the latest frame stands in the keys.
    run: KeyRun,
    /// The model's heading: the last movement key's quarter turns from W
    /// (`Action::quarter`) where the bundle's heading is canonical, else 0.
    heading: u32,
    /// The frame's splats (when asked for) and whether they use the refiner.
    splats: Option<SplatFrame>,
    refine: bool,
    /// Called between the parts of a split frame (see [`Engine::set_pacer`]).
    pacer: Option<Box<dyn FnMut() + Send>>,
    start: Start,
    slots: Vec<Slot>,
    /// The latest frame state read back, and the frames submitted.
    state: FrameState,
    start_root: Vec3,
    noise: Rng,
    frames: u64,
}

/// Steps (dispatches and copies) per submission when a frame is submitted in parts beside
/// a window. Each part waits for the queue, and so for the window's frame before it:
/// beside a window on a 2-core CPU driver one part runs per window frame, so the count
/// of parts, not the kernels, sets the model's pace there. 6 steps (≈ 5 ms of model work
/// on lavapipe) measured 4 generated frames in 600 window frames with the window at 16
/// fps (1 step: 0-2 frames at 20 fps; 8: 5 at 15.6; 16: 9 at 13.2).
pub const SPLIT_STEPS: usize = 6;

/// Frame-state readbacks in flight at most (older ones are skipped, not waited for).
const SLOTS: usize = 3;

impl Engine {
    /// Loads the bundle in `dir` and starts from its standing start, the floor under the
    /// lowest point of that pose.
    pub fn new(gpu: &GpuContext, dir: &Path, options: &EngineOptions) -> Result<Self, LoadError> {
        let bundle = Bundle::load(dir, gpu, options.precision)?;
        let sampling = options.sampling.unwrap_or(bundle.live_sampling());
        sampling
            .check(bundle.schedule.steps())
            .and_then(|()| {
                bundle
                    .unet_for(sampling)
                    .map(|_| ())
                    .map_err(|e| e.to_string())
            })
            .map_err(|problem| LoadError::Manifest {
                path: dir.display().to_string(),
                problem,
            })?;
        let mut pipelines = PipelineCache::default();
        let start = Start::decode(gpu, &mut pipelines, options.precision, &bundle)?;
        let scale = bundle.manifest.normalisation.scale;
        let lowest = start
            .standing
            .iter()
            .map(|p| p.y)
            .fold(f32::INFINITY, f32::min);
        let start_root = Vec3::new(0.0, (0.5 - lowest) / scale, 0.0);
        let live = Live::new(gpu, &bundle, &start, options.precision, start_root)?;
        let slots = (0..SLOTS)
            .map(|_| Slot {
                staging: gpu.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("engine.state readback"),
                    size: std::mem::size_of::<FrameState>() as u64,
                    usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                    mapped_at_creation: false,
                }),
                arrived: Arc::new(Mutex::new(None)),
                busy: false,
            })
            .collect();
        let mut engine = Self {
            gpu: gpu.clone(),
            pipelines,
            precision: options.precision,
            sampling,
            pca: options.pca,
            split: options.split,
            kernels: options
                .kernels
                .unwrap_or_else(|| crate::nn::Kernels::for_adapter(gpu)),
            live,
            plans: Plans::default(),
            ahead: None,
            run: KeyRun::default(),
            heading: 0,
            splats: None,
            refine: options.refine,
            pacer: None,
            start,
            slots,
            state: initial_state(start_root),
            start_root,
            noise: Rng::new(options.seed),
            frames: 0,
            bundle,
        };
        if let Some(level) = options.splat_level {
            engine.set_splats(Some(level))?;
        }
        engine.prepare()?;
        Ok(engine)
    }

    /// The world root after the latest frame whose state has been read back.
    pub fn root(&self) -> Vec3 {
        Vec3::from_slice(&self.state.root[..3])
    }

    /// The latest frame state read back (see [`Engine::poll`]).
    pub fn state(&self) -> FrameState {
        self.state
    }

    /// Frames submitted so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The surface and base splats of this bundle's map, laid out on the standing start.
    pub fn surface(&self) -> surface::MapSurface {
        surface::MapSurface::new(
            &self.bundle.pixels,
            &self.standing_points(),
            self.bundle.colors.as_deref(),
        )
    }

    /// Draws the standing start's last frame into the splat buffer (where splats are on)
    /// through the frame plan's own splat stage, so the avatar is drawn before the first
    /// generated frame: its points are written where a frame's decoded points go and the
    /// splat stage runs on them, in one submission.
    pub fn draw_standing(&mut self) -> Result<(), GpuError> {
        let values: Vec<f32> = self
            .standing_points()
            .iter()
            .flat_map(|p| p.to_array())
            .collect();
        let Some(splats) = &self.splats else {
            return Ok(());
        };
        self.gpu
            .queue
            .write_buffer(&self.live.points, 0, bytemuck::cast_slice(&values));
        let mut r = Recorder::new(&self.gpu, &mut self.pipelines, self.precision);
        r.set_kernels(self.kernels);
        let refiner = self.bundle.refiner.as_ref();
        capture::record_splats(&mut r, splats, refiner, &self.live, self.precision)?;
        r.submit();
        Ok(())
    }

    /// The standing start's last frame in world space (what is shown before the first
    /// generated frame).
    pub fn standing_points(&self) -> Vec<Vec3> {
        let scale = self.bundle.manifest.normalisation.scale;
        self.start
            .standing
            .iter()
            .map(|&p| (p - Vec3::splat(0.5)) / scale + self.start_root)
            .collect()
    }

    pub fn sampling(&self) -> Sampling {
        self.sampling
    }

    /// Takes effect from the next frame (the plan is captured again then).
    pub fn set_sampling(&mut self, sampling: Sampling) {
        self.sampling = sampling;
    }

    /// Takes effect from the next frame (the plan is captured again then).
    pub fn set_pca(&mut self, on: bool) {
        self.pca = on;
    }

    /// A split frame calls `pacer` on the submitting thread after each part has run, so
    /// a caller can give the GPU (and, on a CPU driver, the CPU) to other work — the
    /// window — between parts.
    pub fn set_pacer(&mut self, pacer: impl FnMut() + Send + 'static) {
        self.pacer = Some(Box::new(pacer));
    }

    /// Makes the frame's splats at `level` (128, 256, 512 or 1024) from the next frame on,
    /// or none; the level's buffers are made here, once.
    pub fn set_splats(&mut self, level: Option<usize>) -> Result<(), GpuError> {
        let same = match (&self.splats, level) {
            (Some(s), Some(l)) => s.level() == l && s.refines() == self.refine(),
            (None, None) => true,
            _ => false,
        };
        if same {
            return Ok(());
        }
        self.splats = match level {
            Some(level) => {
                let b = &self.bundle;
                let colors = b
                    .colors
                    .clone()
                    .unwrap_or_else(|| vec![surface::COLOR; b.pixels.len()]);
                let refiner = b
                    .refiner
                    .as_ref()
                    .filter(|_| self.refine)
                    .map(|r| (r.cfg.mean_bound, r.cfg.stride));
                Some(SplatFrame::new(
                    &self.gpu,
                    &b.pixels,
                    &b.waist,
                    &colors,
                    b.manifest.normalisation.scale,
                    level,
                    refiner,
                    self.precision,
                    self.kernels == crate::nn::Kernels::Gpu,
                )?)
            }
            None => None,
        };
        Ok(())
    }

    /// Draws the refiner's residuals (when the bundle has a refiner) from the next frame.
    pub fn set_refine(&mut self, on: bool) -> Result<(), GpuError> {
        self.refine = on;
        let level = self.splats.as_ref().map(SplatFrame::level);
        self.set_splats(level)
    }

    /// Whether the refiner is applied (asked for, and the bundle has one).
    pub fn refine(&self) -> bool {
        self.refine && self.bundle.refiner.is_some()
    }

    /// The rasterizer's input buffer and its splat count (when splats are made): written
    /// by each frame's work, read by later submissions.
    pub fn splats(&self) -> Option<(&wgpu::Buffer, usize)> {
        self.splats.as_ref().map(|s| (&s.splats, s.count()))
    }

    /// The splat level in force.
    pub fn splat_level(&self) -> Option<usize> {
        self.splats.as_ref().map(SplatFrame::level)
    }

    /// The latest frame's splats read back (PLY export, tests; outside the frame loop:
    /// waits for the GPU).
    pub fn read_splats(&self) -> Result<Vec<Splat>, GpuError> {
        let Some((buffer, count)) = self.splats() else {
            return Ok(Vec::new());
        };
        let raw = readback::buffer(&self.gpu, buffer, "splats")?;
        let splats: Vec<GpuSplat> = bytemuck::pod_collect_to_vec(&raw);
        Ok(splats.iter().take(count).map(GpuSplat::to_splat).collect())
    }

    /// Runs the frame plan once more, each dispatch in its own submission waited for, and
    /// returns each step's milliseconds in plan order (a profile for benchmarks: it
    /// advances the loop by one frame under `action`).
    pub fn profile(&mut self, action: Action) -> Result<Vec<StepProfile>, GpuError> {
        self.frame(action)?;
        self.finish();
        let plan = self.plans.get(action, self.run);
        Ok(plan.plan.profile_steps(&self.gpu))
    }

    /// Generates a frame (as [`Engine::frame`]), then runs its plan once more stage by
    /// stage, each waited for alone: dispatches, milliseconds and FLOPs per stage
    /// (`unet-context`, `unet-target` over all steps, `vae-decode`, `geometry`,
    /// `splats`, `refiner`).
    pub fn profile_stages(&mut self, action: Action) -> Result<Vec<StageProfile>, GpuError> {
        self.frame(action)?;
        self.finish();
        let plan = self.plans.get(action, self.run);
        Ok(plan.plan.profile_stages(&self.gpu))
    }

    /// The kernel variant the frame plans record (by adapter, or `UNICA_KERNELS`,
    /// unless the options chose one).
    pub fn kernels(&self) -> crate::nn::Kernels {
        self.kernels
    }

    /// The compute dispatches and FLOPs of the plan the next frame under `action` runs
    /// (0 before the plans are captured).
    pub fn plan_counts(&self, action: Action) -> (usize, u64) {
        if self.plans.keys.is_none() {
            return (0, 0);
        }
        let p = self.plans.get(action, self.run.then(action));
        (p.plan.dispatches(), p.plan.flops())
    }

    /// The dispatches and FLOPs of the braking Idle frames' plan, where the sampler
    /// brakes (and the plans are captured).
    pub fn brake_plan_counts(&self) -> Option<(usize, u64)> {
        let p = self.plans.brake.as_ref()?;
        Some((p.plan.dispatches(), p.plan.flops()))
    }

    /// Idle frames since the last key, the latest frame counted (`sampler::idle_run`;
    /// None before any key).
    pub fn after_key(&self) -> Option<u32> {
        self.run.after_key
    }

    /// Frames of the turn under way, the latest frame counted (`sampler::turn_run`).
    pub fn after_turn(&self) -> Option<u32> {
        self.run.after_turn
    }

    /// The dispatches and FLOPs of the turning frames' plan, where the sampler brakes
    /// turns (and the plans are captured).
    pub fn turn_plan_counts(&self) -> Option<(usize, u64)> {
        let p = self.plans.turn.as_ref()?;
        Some((p.plan.dispatches(), p.plan.flops()))
    }

    /// The frame plan's copies (buffer to buffer and buffer to texels; no shader runs).
    pub fn plan_copies(&self) -> usize {
        self.plans.keys.as_ref().map_or(0, |p| p.plan.copies())
    }

    /// The buffer of the latest frame's drawn points: 3N f32, world space (N =
    /// `bundle.pixels.len()`), in the bundle's pixel order. Valid once that frame's work
    /// has run (later submissions see it).
    pub fn points_buffer(&self) -> &wgpu::Buffer {
        &self.live.points
    }

    /// Captures the frame plan for the current settings if it is missing or stale (at
    /// load, and after a settings change; never otherwise).
    pub fn prepare(&mut self) -> Result<(), GpuError> {
        let look = self.splats.as_ref().map(|s| (s.level(), s.refines()));
        let fresh =
            self.plans.keys.as_ref().is_some_and(|p| {
                p.sampling == self.sampling && p.pca == self.pca && p.look == look
            });
        if !fresh {
            self.ahead = None;
            let sampling = self.sampling;
            self.plans = Plans {
                keys: Some(self.capture(sampling)?),
                idle: match sampling.idle_plan() {
                    Some(idle) => Some(self.capture(idle)?),
                    None => None,
                },
                brake: match sampling.brake() {
                    Some(brake) => Some(self.capture(brake)?),
                    None => None,
                },
                turn: match sampling.turn_brake() {
                    Some(turn) => Some(self.capture(turn)?),
                    None => None,
                },
            };
        }
        Ok(())
    }

    /// Records and submits the next frame under `action` and starts reading its state
    /// back; returns without waiting for the GPU (split: waits for each part but the
    /// last, on this thread, so other work on the queue interleaves). The frame's points
    /// are in [`Engine::points_buffer`] once its work has run.
    pub fn frame(&mut self, action: Action) -> Result<(), GpuError> {
        self.prepare()?;
        self.poll();
        let live = &self.live;
        let mut noise = self.noise.gaussian(live.noise.len());
        for v in &mut noise {
            *v *= self.sampling.noise_scale;
        }
        let mut bytes = self.precision.encode(&noise);
        bytes.resize(live.noise.buffer.size() as usize, 0);
        self.gpu.queue.write_buffer(&live.noise.buffer, 0, &bytes);
        self.run = self.run.then(action);
        if self.bundle.manifest.heading == Heading::Canonical
            && let Some(quarters) = action.quarter()
        {
            self.heading = quarters;
        }
        let turns = HeadingTurns::new(self.heading, action == Action::Idle);
        self.gpu
            .queue
            .write_buffer(&live.heading, 0, bytemuck::bytes_of(&turns));
        // The model sees the action turned with the window.
        let model_action = action.turned(turns.to_model);
        let which = self.plans.which(action, self.run);
        let plan = self.plans.plan(which);
        let ids = if plan.guided {
            let null = self.bundle.unet.cfg.null_action();
            let partner = plan.sampling.partner(model_action.id() as usize, null);
            vec![model_action.id(), partner as u32]
        } else {
            vec![model_action.id()]
        };
        plan.actions.write(&self.gpu, &ids);
        let commands = if self.split {
            self.ahead = None;
            self.submit_parts(which)
        } else {
            match self.ahead.take() {
                Some(ahead) if ahead.which == which => ahead.commands,
                _ => self.record(which),
            }
        };
        // The frame state's readback rides in the frame's submission, in a small
        // encoder of its own: which slot is free is known only now.
        let slot = self.slots.iter().position(|s| !s.busy);
        let mut encoder = self.new_encoder();
        let size = std::mem::size_of::<FrameState>() as u64;
        if let Some(k) = slot {
            encoder.copy_buffer_to_buffer(&self.live.state, 0, &self.slots[k].staging, 0, size);
        }
        // The frame's dispatches are counted once, when its last commands are submitted
        // (recording counts nothing: a recording ahead may be dropped).
        let dispatches = self.plans.plan(which).plan.dispatches();
        self.gpu.counters.dispatches(dispatches as u64);
        self.gpu.submit([commands, encoder.finish()]);
        if let Some(k) = slot {
            let slot = &mut self.slots[k];
            slot.busy = true;
            let arrived = slot.arrived.clone();
            self.gpu.counters.readback(size);
            slot.staging
                .slice(..)
                .map_async(wgpu::MapMode::Read, move |result| {
                    *arrived.lock().expect("state slot") = Some(result);
                });
        }
        self.frames += 1;
        if !self.split {
            // Recording takes about 1 ms of CPU for the frame's 251 dispatches (NVIDIA
            // H200, docs/gpu run 4): done now, it overlaps the GPU's run of this frame
            // instead of delaying the next. The next frame is guessed to run under the
            // same key; a wrong guess records again.
            let next = self.plans.which(action, self.run.then(action));
            let commands = self.record(next);
            self.ahead = Some(Ahead {
                which: next,
                commands,
            });
        }
        Ok(())
    }

    fn new_encoder(&self) -> wgpu::CommandEncoder {
        self.gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("engine frame"),
            })
    }

    /// The whole of plan `which` recorded into one command buffer (its dispatches are
    /// counted when it is submitted).
    fn record(&self, which: Which) -> wgpu::CommandBuffer {
        let plan = &self.plans.plan(which).plan;
        let mut encoder = self.new_encoder();
        for k in 0..plan.parts() {
            plan.record_part(&mut encoder, k);
        }
        encoder.finish()
    }

    /// A split frame: submits each part of plan `which` but the last and waits for it
    /// (calling the pacer after each), and returns the last part's commands (the caller
    /// counts the frame's dispatches).
    fn submit_parts(&mut self, which: Which) -> wgpu::CommandBuffer {
        let parts = self.plans.plan(which).plan.parts();
        for k in 0..parts - 1 {
            let mut encoder = self.new_encoder();
            let plan = &self.plans.plan(which).plan;
            plan.record_part(&mut encoder, k);
            let index = self.gpu.submit([encoder.finish()]);
            let _ = self.gpu.device.poll(wgpu::PollType::Wait {
                submission_index: Some(index),
                timeout: None,
            });
            if let Some(pacer) = self.pacer.as_mut() {
                pacer();
            }
        }
        let mut encoder = self.new_encoder();
        self.plans
            .plan(which)
            .plan
            .record_part(&mut encoder, parts - 1);
        encoder.finish()
    }

    /// Picks up frame states that have arrived (never waits); true if one did.
    pub fn poll(&mut self) -> bool {
        let _ = self.gpu.device.poll(wgpu::PollType::Poll);
        self.collect()
    }

    fn collect(&mut self) -> bool {
        let mut newest: Option<FrameState> = None;
        for slot in self.slots.iter_mut().filter(|s| s.busy) {
            let Some(result) = slot.arrived.lock().expect("state slot").take() else {
                continue;
            };
            slot.busy = false;
            if result.is_ok()
                && let Ok(view) = slot.staging.slice(..).get_mapped_range()
            {
                let state: FrameState = bytemuck::pod_read_unaligned(&view[..]);
                if newest.is_none_or(|n| state.frames > n.frames) {
                    newest = Some(state);
                }
            }
            slot.staging.unmap();
        }
        match newest {
            Some(state) if state.frames >= self.state.frames => {
                self.state = state;
                true
            }
            _ => false,
        }
    }

    /// Waits until every submitted frame has run and its state, if read back, arrived.
    pub fn finish(&mut self) {
        self.gpu.wait_idle();
        self.collect();
    }

    /// The latest frame's points read back (the surface view, tools; waits for the GPU).
    pub fn read_points(&self) -> Result<Vec<Vec3>, GpuError> {
        let values: Vec<f32> = bytemuck::pod_collect_to_vec(&readback::buffer(
            &self.gpu,
            &self.live.points,
            "points",
        )?);
        Ok(values
            .chunks_exact(3)
            .take(self.bundle.pixels.len())
            .map(|v| Vec3::new(v[0], v[1], v[2]))
            .collect())
    }

    /// Generates the next frame under `action` and waits for it, reading its points
    /// back (tools and tests; the window and the live bench use [`Engine::frame`]).
    pub fn step(&mut self, action: Action) -> Result<Frame, GpuError> {
        let clock = Instant::now();
        self.frame(action)?;
        let cpu_ms = clock.elapsed().as_secs_f64() * 1e3;
        let values: Vec<f32> = bytemuck::pod_collect_to_vec(&readback::buffer(
            &self.gpu,
            &self.live.points,
            "points",
        )?);
        self.finish();
        let points = values
            .chunks_exact(3)
            .take(self.bundle.pixels.len())
            .map(|v| Vec3::new(v[0], v[1], v[2]))
            .collect();
        Ok(Frame {
            index: self.frames - 1,
            action,
            points,
            root: self.root(),
            clamped: self.state.clamped as usize,
            clamped_total: self.state.clamped_total as usize,
            gpu_ms: clock.elapsed().as_secs_f64() * 1e3,
            cpu_ms,
        })
    }
}
