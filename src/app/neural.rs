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
use crate::engine::{Engine, EngineOptions, Frame};
use crate::gpu::GpuContext;
use crate::nn::sampler::Sampling;

/// What the UI may change while the avatar runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    pub sampling: Sampling,
    pub pca: bool,
}

/// What the worker reports.
pub enum Update {
    /// Loaded: the foreground pixels, their colours if the bundle has them, the standing
    /// start in world space, the defaults.
    Ready {
        pixels: Vec<u32>,
        colors: Option<Vec<Vec3>>,
        standing: Vec<Vec3>,
        settings: Settings,
    },
    Frame(Box<Frame>),
    Failed(String),
}

pub struct NeuralAvatar {
    pub dir: PathBuf,
    action: Arc<AtomicU32>,
    settings: Arc<Mutex<Option<Settings>>>,
    stop: Arc<AtomicBool>,
    updates: Receiver<Update>,
    /// Generated frames per second, measured over the last frames.
    pub fps: f64,
    last_frame: Option<Instant>,
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
            last_frame: None,
        }
    }

    pub fn set_action(&self, action: Action) {
        self.action.store(action.id(), Ordering::Relaxed);
    }

    pub fn set_settings(&self, settings: Settings) {
        *self.settings.lock().expect("settings lock") = Some(settings);
    }

    /// Everything the worker reported since the last call; frames but the newest are
    /// dropped (the UI shows the latest).
    pub fn poll(&mut self) -> Vec<Update> {
        let mut out = Vec::new();
        loop {
            match self.updates.try_recv() {
                Ok(Update::Frame(frame)) => {
                    let now = Instant::now();
                    if let Some(last) = self.last_frame {
                        let rate = 1.0 / now.duration_since(last).as_secs_f64().max(1e-6);
                        self.fps = if self.fps == 0.0 {
                            rate
                        } else {
                            0.8 * self.fps + 0.2 * rate
                        };
                    }
                    self.last_frame = Some(now);
                    if let Some(Update::Frame(_)) = out.last() {
                        out.pop();
                    }
                    out.push(Update::Frame(frame));
                }
                Ok(update) => out.push(update),
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return out,
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
        let defaults = Settings {
            sampling: engine.sampling(),
            pca: true,
        };
        let ready = Update::Ready {
            pixels: engine.bundle.pixels.clone(),
            colors: engine.bundle.colors.clone(),
            standing: engine.standing_points(),
            settings: defaults,
        };
        if send.send(ready).is_err() {
            return Ok(());
        }
        let period = Duration::from_secs_f64(1.0 / f64::from(FRAME_RATE));
        let mut next = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            if let Some(settings) = self.settings.lock().expect("settings lock").take() {
                engine.set_sampling(settings.sampling);
                engine.set_pca(settings.pca);
            }
            let action = Action::from_id(self.action.load(Ordering::Relaxed));
            let frame = engine.step(action)?;
            if send.send(Update::Frame(Box::new(frame))).is_err() {
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
