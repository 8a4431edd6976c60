//! The neural avatar in the window: the engine runs on its own thread so the UI never
//! waits for the model. The UI publishes the held action and the live settings; the
//! worker reads them as it starts each generated frame (a key press changes the next
//! frame, nothing queues), paces itself to the data rate and reports each frame. The
//! frame's splats never leave the GPU: the engine writes them into its splat buffer,
//! which the window's rasterizer reads (the worker hands over the buffer, not splats).
//! On a CPU driver the engine submits a frame in small parts, each waited for on the
//! worker's thread, so the window's own frames interleave with the model's work; on a GPU
//! a frame is one submission.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::Vec3;

use crate::action::{Action, KeyScript};
use crate::avatar::locomotion::FRAME_RATE;
use crate::engine::appearance;
use crate::engine::surface::MapSurface;
use crate::engine::{Engine, EngineOptions};
use crate::gpu::GpuContext;
use crate::nn::sampler::Sampling;

/// What the UI may change while the avatar runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub sampling: Sampling,
    pub pca: bool,
    /// Draw splats (made on the worker), else the triangulated surface.
    pub splats: bool,
    /// Apply the bundle's refiner (when it has one).
    pub refine: bool,
    /// Splat level: the map size whose foreground pixels become splats.
    pub level: usize,
}

/// A generated frame as the window needs it.
pub struct Drawn {
    /// Frames generated so far.
    pub frames: u64,
    /// The world root (read back asynchronously: up to a frame late).
    pub root: Vec3,
    pub clamped_total: usize,
    /// The surface points, read back only when the surface is drawn instead of splats.
    pub points: Option<Vec<Vec3>>,
    /// The engine's splat buffer and its count (it changes with the splat level).
    pub splats: Option<(wgpu::Buffer, usize)>,
    /// The whole frame (report to report), ms.
    pub frame_ms: f64,
}

/// What the worker reports.
pub enum Update {
    /// Loaded: the map's surface, the standing start in world space and its root, the
    /// defaults.
    Ready {
        surface: Box<MapSurface>,
        standing: Vec<Vec3>,
        /// The engine's splat buffer (holding the standing start) and its count.
        splats: Option<(wgpu::Buffer, usize)>,
        root: Vec3,
        settings: Settings,
        /// The bundle has a refiner.
        refiner: bool,
        /// The bundle's own sampler (its manifest's): the teacher's DDIM settings, and
        /// whether a distilled one-pass student runs by default.
        bundled: Sampling,
    },
    /// A generated frame and the seconds since the one before.
    Frame(Box<Drawn>, f64),
    Failed(String),
}

/// The model's share of time beside the window, on a machine where the model and the
/// window share the same cores (a CPU driver). The window draws only when something
/// changed (app/mod.rs), so it asks for turns: after at least [`MODEL_SLICE`] of model
/// work (one dispatch may run longer), if the window has started a frame since the last
/// slice, the worker waits until the window has recorded it (at most [`WINDOW_WAIT`]),
/// so the window's work runs before the model's next part; otherwise the model carries
/// on. Measured on lavapipe (docs/performance.md): a window redrawing unchanged pictures
/// at 16-20 fps left the model about a twentieth of its rate alone, and a fixed window
/// share of twice the model's slice after each drawn frame left it 55 %.
const MODEL_SLICE: Duration = Duration::from_millis(6);
const WINDOW_WAIT: Duration = Duration::from_millis(250);

/// Wakes the window (a new generated frame is there to draw).
pub type Wake = Arc<dyn Fn() + Send + Sync>;

/// What a neural avatar starts from: its bundle folder, the teacher's DDIM steps instead
/// of the bundle's sampler (`--steps`), a key script, and how to wake the window.
pub struct NeuralStart {
    pub dir: PathBuf,
    pub steps: Option<usize>,
    /// With a key script, generated frame `i` takes the script's action `i` (the held
    /// action is ignored), so a scripted run is the same however fast the model runs.
    pub script: Option<KeyScript>,
    pub wake: Wake,
}

pub struct NeuralAvatar {
    pub dir: PathBuf,
    /// Window frames drawn, counted by [`NeuralAvatar::window_frame`].
    window_frames: Arc<AtomicU64>,
    /// Window frames started, counted by [`NeuralAvatar::window_started`].
    window_started: Arc<AtomicU64>,
    action: Arc<AtomicU32>,
    settings: Arc<Mutex<Option<Settings>>>,
    stop: Arc<AtomicBool>,
    updates: Receiver<Update>,
    /// Generated frames per second, smoothed over the last frames.
    pub fps: f64,
    /// The worker reported a failure (or vanished).
    failed: bool,
}

impl NeuralAvatar {
    /// Starts loading `dir` on a worker thread (`steps`: DDIM steps, else the bundle's).
    /// With a key `script`, generated frame `i` takes the script's action `i` (the held
    /// action is ignored), so a scripted run is the same however fast the model runs.
    pub fn start(gpu: &GpuContext, start: NeuralStart) -> Self {
        let NeuralStart {
            dir,
            steps,
            script,
            wake,
        } = start;
        let action = Arc::new(AtomicU32::new(Action::Idle.id()));
        let settings: Arc<Mutex<Option<Settings>>> = Arc::default();
        let stop = Arc::new(AtomicBool::new(false));
        let window_frames = Arc::new(AtomicU64::new(0));
        let window_started = Arc::new(AtomicU64::new(0));
        let (send, updates) = channel();
        let worker = Worker {
            steps,
            script,
            wake,
            window_frames: window_frames.clone(),
            window_started: window_started.clone(),
            gpu: gpu.clone(),
            dir: dir.clone(),
            action: action.clone(),
            settings: settings.clone(),
            stop: stop.clone(),
        };
        std::thread::Builder::new()
            .name("neural avatar".into())
            .spawn(move || {
                let wake = worker.wake.clone();
                if let Err(e) = worker.run(&send) {
                    send.send(Update::Failed(e.to_string())).ok();
                }
                // A failure, or the end of the thread, is news for the window too.
                wake();
            })
            .expect("spawning a thread");
        Self {
            dir,
            window_frames,
            window_started,
            action,
            settings,
            stop,
            updates,
            fps: 0.0,
            failed: false,
        }
    }

    /// The window starts drawing a frame: the worker gives it a turn after its current
    /// model slice.
    pub fn window_started(&self) {
        self.window_started.fetch_add(1, Ordering::Relaxed);
    }

    /// The window has recorded its frame's GPU work (the turn it asked for is over).
    pub fn window_frame(&self) {
        self.window_frames.fetch_add(1, Ordering::Relaxed);
    }

    pub fn set_action(&self, action: Action) {
        self.action.store(action.id(), Ordering::Relaxed);
    }

    pub fn set_settings(&self, settings: Settings) {
        *self.settings.lock().expect("settings lock") = Some(settings);
    }

    /// Everything the worker reported since the last call; frames but the newest are
    /// dropped (the UI shows the latest). A worker that ended without a word (it
    /// panicked) is reported as stopped.
    pub fn poll(&mut self) -> Vec<Update> {
        let mut out = Vec::new();
        loop {
            match self.updates.try_recv() {
                Ok(Update::Frame(frame, interval)) => {
                    if interval > 0.0 {
                        let rate = 1.0 / interval;
                        self.fps = if self.fps == 0.0 {
                            rate
                        } else {
                            0.8 * self.fps + 0.2 * rate
                        };
                    }
                    if let Some(Update::Frame(..)) = out.last() {
                        out.pop();
                    }
                    out.push(Update::Frame(frame, interval));
                }
                Ok(Update::Failed(e)) => {
                    self.failed = true;
                    out.push(Update::Failed(e));
                }
                Ok(update) => out.push(update),
                Err(TryRecvError::Empty) => return out,
                Err(TryRecvError::Disconnected) => {
                    if !self.failed && !self.stop.load(Ordering::Relaxed) {
                        self.failed = true;
                        out.push(Update::Failed(
                            "the model's thread ended unexpectedly".into(),
                        ));
                    }
                    return out;
                }
            }
        }
    }
}

impl Drop for NeuralAvatar {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

struct Worker {
    steps: Option<usize>,
    script: Option<KeyScript>,
    wake: Wake,
    window_frames: Arc<AtomicU64>,
    window_started: Arc<AtomicU64>,
    gpu: GpuContext,
    dir: PathBuf,
    action: Arc<AtomicU32>,
    settings: Arc<Mutex<Option<Settings>>>,
    stop: Arc<AtomicBool>,
}

impl Worker {
    fn run(self, send: &std::sync::mpsc::Sender<Update>) -> anyhow::Result<()> {
        // Loading submits seconds of work on a CPU driver; let the window open and
        // configure its surface first (wgpu waits for an idle GPU to do that).
        let opened = Instant::now();
        while self.window_frames.load(Ordering::Relaxed) < 1
            && opened.elapsed() < Duration::from_secs(5)
            && !self.stop.load(Ordering::Relaxed)
        {
            std::thread::sleep(Duration::from_millis(10));
        }
        let level = appearance::default_level(&self.gpu);
        // Split frames let the window's frames in between the model's parts where both
        // share the CPU's cores (lavapipe). On a GPU each waited part would leave it idle
        // (a submit and wait costs about 0.07 ms on an H200, docs/gpu; a frame has about 45
        // parts of `SPLIT_STEPS`): there the frame is one submission, recorded while the last ran.
        let options = EngineOptions {
            split: self.gpu.cpu_driver(),
            splat_level: Some(level),
            ..EngineOptions::default()
        };
        let mut engine = Engine::new(&self.gpu, &self.dir, &options)?;
        if let Some(steps) = self.steps {
            let sampling = engine.bundle.manifest.sampler.ddim(steps);
            sampling
                .check(engine.bundle.schedule.steps())
                .map_err(|e| anyhow::anyhow!("--steps: {e}"))?;
            engine.set_sampling(sampling);
        }
        let (frames, started, stop) = (
            self.window_frames.clone(),
            self.window_started.clone(),
            self.stop.clone(),
        );
        let mut seen = started.load(Ordering::Relaxed);
        let mut slice = Instant::now();
        engine.set_pacer(move || {
            let spent = slice.elapsed();
            if spent < MODEL_SLICE {
                return;
            }
            let asked = started.load(Ordering::Relaxed);
            if asked != seen {
                // The window started a frame since the last slice: the model waits until
                // it has recorded it, so its work is queued before the model's next part.
                let waited = Instant::now();
                while frames.load(Ordering::Relaxed) < asked
                    && waited.elapsed() < WINDOW_WAIT
                    && !stop.load(Ordering::Relaxed)
                {
                    std::thread::sleep(Duration::from_millis(1));
                }
                seen = asked;
            }
            slice = Instant::now();
        });
        let mut settings = Settings {
            sampling: engine.sampling(),
            pca: true,
            splats: true,
            refine: engine.refine(),
            level,
        };
        let standing = engine.standing_points();
        engine.draw_standing()?;
        let ready = Update::Ready {
            surface: Box::new(engine.surface()),
            splats: engine.splats().map(|(b, n)| (b.clone(), n)),
            standing,
            root: engine.root(),
            settings,
            refiner: engine.bundle.refiner.is_some(),
            bundled: engine.bundle.manifest.sampler,
        };
        if send.send(ready).is_err() {
            return Ok(());
        }
        (self.wake)();
        let period = Duration::from_secs_f64(1.0 / f64::from(FRAME_RATE));
        let mut next = Instant::now();
        let mut last = next;
        while !self.stop.load(Ordering::Relaxed) {
            let mut new_buffer = false;
            if let Some(new) = self.settings.lock().expect("settings lock").take() {
                engine.set_sampling(new.sampling);
                engine.set_pca(new.pca);
                let before = engine.splat_level();
                engine.set_refine(new.refine)?;
                engine.set_splats(Some(new.level))?;
                new_buffer = before != engine.splat_level() || new.refine != settings.refine;
                settings = new;
            }
            let action = match &self.script {
                Some(script) => script.action_at(engine.frames() as usize),
                None => Action::from_id(self.action.load(Ordering::Relaxed)),
            };
            engine.frame(action)?;
            engine.poll();
            let points = if settings.splats {
                None
            } else {
                Some(engine.read_points()?)
            };
            let now = Instant::now();
            let interval = now.duration_since(last).as_secs_f64();
            last = now;
            let state = engine.state();
            let drawn = Drawn {
                frames: engine.frames(),
                root: engine.root(),
                clamped_total: state.clamped_total as usize,
                points,
                splats: engine
                    .splats()
                    .filter(|_| new_buffer)
                    .map(|(b, n)| (b.clone(), n)),
                frame_ms: interval * 1e3,
            };
            if send.send(Update::Frame(Box::new(drawn), interval)).is_err() {
                return Ok(());
            }
            (self.wake)();
            // Never faster than the data rate; when slower, run as fast as it can.
            next += period;
            let now = Instant::now();
            if next > now {
                std::thread::sleep(next - now);
            } else {
                next = now;
            }
        }
        Ok(())
    }
}
