//! The neural avatar in the window: the engine runs on its own thread so the UI never
//! waits for the model. The UI publishes the held action and the live settings; the
//! worker reads them as it starts each generated frame (a key press changes the next
//! frame, nothing queues), paces itself to the data rate and hands back the newest frame.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError, channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use glam::Vec3;

use crate::action::Action;
use crate::avatar::locomotion::FRAME_RATE;
use crate::engine::appearance::{self, Appearance};
use crate::engine::surface::MapSurface;
use crate::engine::{Engine, EngineOptions, Frame};
use crate::gpu::GpuContext;
use crate::nn::sampler::Sampling;
use crate::splat::ply::Splat;

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

/// A generated frame with its splats (when they are drawn) and their time, ms.
pub struct Drawn {
    pub frame: Frame,
    pub splats: Option<Vec<Splat>>,
    pub splat_ms: f64,
}

/// What the worker reports.
pub enum Update {
    /// Loaded: the map's surface, the standing start in world space and its root, the
    /// defaults.
    Ready {
        surface: Box<MapSurface>,
        standing: Vec<Vec3>,
        splats: Vec<Splat>,
        root: Vec3,
        settings: Settings,
        /// The bundle has a refiner.
        refiner: bool,
    },
    /// A generated frame and the seconds since the one before.
    Frame(Box<Drawn>, f64),
    Failed(String),
}

pub struct NeuralAvatar {
    pub dir: PathBuf,
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
    /// Starts loading `dir` on a worker thread.
    pub fn start(gpu: &GpuContext, dir: &Path) -> Self {
        let action = Arc::new(AtomicU32::new(Action::Idle.id()));
        let settings: Arc<Mutex<Option<Settings>>> = Arc::default();
        let stop = Arc::new(AtomicBool::new(false));
        let (send, updates) = channel();
        let worker = Worker {
            gpu: gpu.clone(),
            dir: dir.to_path_buf(),
            action: action.clone(),
            settings: settings.clone(),
            stop: stop.clone(),
        };
        std::thread::Builder::new()
            .name("neural avatar".into())
            .spawn(move || {
                let failed = |e: String| send.send(Update::Failed(e)).ok();
                if let Err(e) = worker.run(&send) {
                    failed(e.to_string());
                }
            })
            .expect("spawning a thread");
        Self {
            dir: dir.to_path_buf(),
            action,
            settings,
            stop,
            updates,
            fps: 0.0,
            failed: false,
        }
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
    gpu: GpuContext,
    dir: PathBuf,
    action: Arc<AtomicU32>,
    settings: Arc<Mutex<Option<Settings>>>,
    stop: Arc<AtomicBool>,
}

impl Worker {
    fn run(self, send: &std::sync::mpsc::Sender<Update>) -> anyhow::Result<()> {
        let options = EngineOptions {
            split: true,
            ..EngineOptions::default()
        };
        let mut engine = Engine::new(&self.gpu, &self.dir, &options)?;
        let level = appearance::default_level(&self.gpu);
        let mut look = Appearance::new(&self.gpu, &engine.bundle, options.precision, level)?;
        let mut settings = Settings {
            sampling: engine.sampling(),
            pca: true,
            splats: true,
            refine: look.refine,
            level,
        };
        let standing = engine.standing_points();
        let ready = Update::Ready {
            surface: Box::new(engine.surface()),
            splats: look.splats(&engine.bundle, &standing)?,
            standing,
            root: engine.root(),
            settings,
            refiner: engine.bundle.refiner.is_some(),
        };
        if send.send(ready).is_err() {
            return Ok(());
        }
        let period = Duration::from_secs_f64(1.0 / f64::from(FRAME_RATE));
        let mut next = Instant::now();
        let mut last = next;
        while !self.stop.load(Ordering::Relaxed) {
            if let Some(new) = self.settings.lock().expect("settings lock").take() {
                engine.set_sampling(new.sampling);
                engine.set_pca(new.pca);
                if new.level != settings.level {
                    look =
                        Appearance::new(&self.gpu, &engine.bundle, options.precision, new.level)?;
                }
                look.refine = new.refine;
                settings = new;
            }
            let action = Action::from_id(self.action.load(Ordering::Relaxed));
            let frame = engine.step(action)?;
            let clock = Instant::now();
            let splats = if settings.splats {
                Some(look.splats(&engine.bundle, &frame.points)?)
            } else {
                None
            };
            let splat_ms = clock.elapsed().as_secs_f64() * 1e3;
            let now = Instant::now();
            let interval = now.duration_since(last).as_secs_f64();
            last = now;
            let drawn = Drawn {
                frame,
                splats,
                splat_ms,
            };
            if send.send(Update::Frame(Box::new(drawn), interval)).is_err() {
                return Ok(());
            }
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
