//! The desktop app: an egui window with the 3D viewport, orbit camera, HUD, menus, WASD
//! input and the recorder. The only module that knows about windows.

mod hud;
mod lost;
pub mod neural;
pub mod recorder;
mod resize;
mod scripted;
pub mod shown;
pub mod viewport;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use eframe::egui;

use crate::action::{Action, HeldKeys, KeyScript};
use crate::avatar::locomotion::FRAME_RATE;
use crate::gpu::timing::StageTiming;
use crate::gpu::{self, GpuContext, GpuOptions};
use crate::render::OrbitCamera;
use recorder::SessionRecorder;
use shown::Shown;
use viewport::Viewport;

/// A neural avatar offered in View → Avatar: its bundle folder and its teacher.
#[derive(Clone, Debug, PartialEq)]
pub struct ShippedAvatar {
    pub name: String,
    pub bundle: PathBuf,
    pub character: PathBuf,
}

/// How the app was started (see `unica --help`).
#[derive(Clone, Debug, Default)]
pub struct AppOptions {
    /// Neural avatar bundle to play; `None` shows the character's teacher.
    pub bundle: Option<PathBuf>,
    /// The avatars View → Avatar offers.
    pub avatars: Vec<ShippedAvatar>,
    /// A splat file to show instead of an avatar (`unica view`).
    pub splats: Option<PathBuf>,
    /// The up axis of `splats`.
    pub splat_up: crate::splat::files::Up,
    /// Character file: the teacher (beside the neural avatar when there is a bundle);
    /// `None` without a bundle shows the placeholder.
    pub character: Option<PathBuf>,
    /// Animation libraries whose clips join the character's (`--clips`).
    pub clips: Vec<PathBuf>,
    /// Drive the action from this script instead of the keyboard.
    pub keys: Option<KeyScript>,
    /// Render this many frames, then exit (the window then redraws continuously, so
    /// that the count advances).
    pub exit_after: Option<u64>,
    /// Close after this many seconds, whatever was drawn (the window yields as usual).
    pub exit_after_seconds: Option<f64>,
    /// The neural avatar's DDIM steps (`None`: the bundle's); the HUD changes them live.
    pub steps: Option<usize>,
    /// Save a screenshot of the window when exiting after `exit_after` frames.
    pub screenshot: Option<PathBuf>,
    /// Folder that F9 records into.
    pub record_dir: PathBuf,
    /// Start recording as the window opens.
    pub record: bool,
    /// Recording rate in frames per second.
    pub record_fps: f64,
    /// Resize the window through this many sizes down to 1 × 1 and back, then hide and
    /// show it (`--stress-resize`, for tests).
    pub stress_resize: Option<usize>,
    /// Destroy the GPU device this many seconds after opening (`--stress-lose-device`,
    /// for tests): the device is lost as when a driver resets.
    pub stress_lose_device: Option<f64>,
    pub gpu: GpuOptions,
}

/// The window's size when it opens, in points.
const OPENING_SIZE: [f32; 2] = [1280.0, 800.0];

/// Opens the window and runs until it is closed.
pub fn run(options: AppOptions) -> anyhow::Result<()> {
    // Fail with the same one-line advice as the headless tools when there is no adapter
    // at all (eframe would only say that no surface could be created).
    gpu::select_adapter(
        &pollster::block_on(gpu::enumerate_adapters()),
        None,
        &options.gpu,
    )?;
    let selector_options = options.gpu.clone();
    let device_options = options.gpu.clone();
    let setup = eframe::egui_wgpu::WgpuSetupCreateNew {
        instance_descriptor: wgpu::InstanceDescriptor {
            backends: gpu::backends(),
            ..wgpu::InstanceDescriptor::new_without_display_handle()
        },
        native_adapter_selector: Some(Arc::new(move |adapters, surface| {
            gpu::select_adapter(adapters, surface, &selector_options).map_err(|e| e.to_string())
        })),
        device_descriptor: Arc::new(move |adapter| {
            gpu::device_descriptor(adapter, &device_options)
        }),
        ..eframe::egui_wgpu::WgpuSetupCreateNew::without_display_handle()
    };
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("unica")
            .with_inner_size(OPENING_SIZE)
            .with_min_inner_size([480.0, 320.0])
            .with_drag_and_drop(true),
        renderer: eframe::Renderer::Wgpu,
        wgpu_options: eframe::egui_wgpu::WgpuConfiguration {
            wgpu_setup: eframe::egui_wgpu::WgpuSetup::CreateNew(setup),
            ..Default::default()
        },
        ..Default::default()
    };
    let outcome: Arc<Mutex<Option<anyhow::Error>>> = Arc::default();
    let app_outcome = outcome.clone();
    let device_lost = lost::Lost::default();
    let app_lost = device_lost.clone();
    let ran = lost::caught(&device_lost, || {
        eframe::run_native(
            "unica",
            native,
            Box::new(move |cc| {
                let state = cc
                    .wgpu_render_state
                    .as_ref()
                    .ok_or("the window has no wgpu renderer")?;
                let gpu = GpuContext::from_parts(
                    state.adapter.clone(),
                    state.device.clone(),
                    state.queue.clone(),
                );
                Ok(Box::new(UnicaApp::new(
                    gpu,
                    cc.egui_ctx.clone(),
                    options,
                    app_outcome,
                    app_lost,
                )))
            }),
        )
    })?;
    ran.map_err(|e| anyhow::anyhow!("could not open the window: {e}"))?;
    // A lost device is the cause of whatever else failed after it (the model's thread
    // may have stopped first).
    lost::reported(&device_lost)?;
    match outcome.lock().expect("outcome lock").take() {
        Some(err) => Err(err),
        None => Ok(()),
    }
}

struct UnicaApp {
    gpu: GpuContext,
    viewport: Viewport,
    shown: Shown,
    options: AppOptions,
    keys: HeldKeys,
    action: Action,
    frame: u64,
    last_frame: Instant,
    timings: Vec<StageTiming>,
    recording: Option<(SessionRecorder, Instant)>,
    /// Teacher frames owed to the clock (interactive pacing).
    step_clock: f64,
    follow: bool,
    record_dir: String,
    open_path: String,
    message: Option<String>,
    show_help: bool,
    screenshot_requested: bool,
    /// When the first generated frame arrived, and the window frame and the generated
    /// frame count then: the rates while the model runs (printed on the final line).
    model_started: Option<(Instant, u64, u64)>,
    /// The window's context, for the model's worker to wake it with a new frame.
    ctx: egui::Context,
    /// When the window opened (`--exit-after-seconds`).
    opened: Instant,
    /// Input to drawn frame, ms: one per frame that took a key press, a click, a drag or
    /// a wheel turn, from the frame's start until its viewport work has run on the GPU.
    latencies: Arc<Mutex<Vec<f64>>>,
    /// The HUD's counters, refreshed at most twice a second: when, window frames then,
    /// and the values shown.
    hud: HudCounters,
    /// Where the screenshot callback leaves its result for the exit path.
    outcome: Arc<Mutex<Option<anyhow::Error>>>,
    /// A scripted run failed: close the window (the error is in `outcome`).
    closing: bool,
    /// `--stress-resize`: the sizes and the hiding still to ask for.
    resizes: Option<resize::ResizeScript>,
    /// GPU errors no error scope caught (from any thread), not yet shown; and how many
    /// there have been.
    gpu_errors: Arc<Mutex<Vec<String>>>,
    gpu_error_count: usize,
    /// Why the GPU device was lost, once it is (set from wgpu's callback).
    device_lost: lost::Lost,
    /// `--stress-lose-device` has destroyed the device.
    device_destroyed: bool,
}

impl UnicaApp {
    fn new(
        gpu: GpuContext,
        ctx: egui::Context,
        options: AppOptions,
        outcome: Arc<Mutex<Option<anyhow::Error>>>,
        device_lost: lost::Lost,
    ) -> Self {
        // wgpu's default for an error no scope catches is a panic; the window reports it
        // instead (HUD and log) and goes on: resizing it fast on lavapipe made
        // Surface::configure fail ("Failed to wait for GPU to come idle") and panicked.
        let gpu_errors: Arc<Mutex<Vec<String>>> = Arc::default();
        let sink = gpu_errors.clone();
        gpu.device
            .on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                let text = e.to_string();
                let line = text
                    .lines()
                    .filter(|l| !l.trim().is_empty())
                    .collect::<Vec<_>>()
                    .join(": ");
                log::error!("GPU error: {line}");
                sink.lock().expect("GPU error lock").push(line);
            }));
        lost::watch(&gpu.device, &device_lost);
        let mut viewport = Viewport::new(&gpu);
        let character = options.character.as_deref();
        let shown = match (&options.splats, &options.bundle) {
            (Some(file), _) => Shown::splat_file(&gpu, &viewport.renderer, file, options.splat_up),
            (None, Some(dir)) => Shown::neural(
                &gpu,
                &viewport.renderer,
                character,
                &options.clips,
                neural::NeuralStart {
                    dir: dir.clone(),
                    steps: options.steps,
                    script: options.keys.clone(),
                    wake: wake(&ctx),
                },
            ),
            (None, None) => Shown::load(&gpu, &viewport.renderer, character, &options.clips),
        };
        viewport.camera = behind(&shown);
        log::info!("adapter: {}; {:?}", gpu.adapter_label(), gpu.caps);
        let record = options.record;
        let resizes = options
            .stress_resize
            .map(|n| resize::ResizeScript::new(n, OPENING_SIZE));
        let mut app = Self {
            record_dir: options.record_dir.display().to_string(),
            open_path: options
                .bundle
                .as_ref()
                .or(options.character.as_ref())
                .map(|p| p.display().to_string())
                .unwrap_or_default(),
            gpu,
            viewport,
            shown,
            options,
            keys: HeldKeys::default(),
            action: Action::Idle,
            frame: 0,
            last_frame: Instant::now(),
            timings: Vec::new(),
            recording: None,
            step_clock: 0.0,
            follow: true,
            message: None,
            show_help: false,
            screenshot_requested: false,
            model_started: None,
            ctx,
            opened: Instant::now(),
            latencies: Arc::default(),
            hud: HudCounters::default(),
            outcome,
            closing: false,
            resizes,
            gpu_errors,
            gpu_error_count: 0,
            device_lost,
            device_destroyed: false,
        };
        if record {
            app.toggle_recording();
        }
        app
    }

    /// Opens a bundle folder (the neural avatar) or a character file (its teacher).
    fn open(&mut self, path: PathBuf) {
        self.open_with(path, None);
    }

    /// Opens a bundle folder beside `teacher`, or a character file (its teacher).
    fn open_with(&mut self, path: PathBuf, teacher: Option<PathBuf>) {
        let renderer = &self.viewport.renderer;
        self.shown = if path.is_dir() {
            Shown::neural(
                &self.gpu,
                renderer,
                teacher.as_deref(),
                &[],
                neural::NeuralStart {
                    dir: path.clone(),
                    steps: self.options.steps,
                    script: self.options.keys.clone(),
                    wake: wake(&self.ctx),
                },
            )
        } else {
            Shown::load(&self.gpu, renderer, Some(&path), &[])
        };
        self.message = self.shown.problem.clone();
        self.viewport.camera = behind(&self.shown);
        self.open_path = path.display().to_string();
    }

    fn toggle_recording(&mut self) {
        match self.recording.take() {
            Some((recorder, _)) => {
                let dir = recorder.dir.clone();
                self.message = Some(match recorder.stop() {
                    Ok(n) => {
                        // Encoding takes seconds: it runs beside the window.
                        let video = match recorder::find_ffmpeg() {
                            None => "",
                            Some(ffmpeg) => {
                                let (dir, fps) = (dir.clone(), self.options.record_fps);
                                std::thread::spawn(move || {
                                    match recorder::encode_mp4(&ffmpeg, &dir, fps) {
                                        Ok(mp4) => log::info!("wrote {}", mp4.display()),
                                        Err(e) => log::error!("no MP4: {e}"),
                                    }
                                });
                                "; session.mp4 is being encoded"
                            }
                        };
                        format!("Recorded {n} frames to {}{video}", dir.display())
                    }
                    Err(e) => {
                        self.fail(format!("recording stopped: {e}"));
                        return;
                    }
                });
            }
            None => {
                match SessionRecorder::start(
                    &PathBuf::from(&self.record_dir),
                    self.options.record_fps,
                ) {
                    Ok(recorder) => {
                        self.message = None;
                        self.recording = Some((recorder, Instant::now()));
                    }
                    Err(e) => self.fail(format!("cannot record: {e}")),
                }
            }
        }
    }

    /// Keyboard: movement keys into held state, F/R/F9 commands, dropped files.
    fn handle_input(&mut self, ctx: &egui::Context) {
        let typing = ctx.egui_wants_keyboard_input();
        let (events, focused, dropped) =
            ctx.input(|i| (i.events.clone(), i.focused, i.raw.dropped_files.clone()));
        if !focused {
            self.keys.clear();
        }
        for event in events {
            let egui::Event::Key {
                key,
                pressed,
                repeat,
                ..
            } = event
            else {
                continue;
            };
            if let Some(action) = movement(key) {
                // Releases always count, so a key let go while typing does not stick.
                if !pressed {
                    self.keys.release(action);
                } else if !typing && !repeat {
                    self.keys.press(action);
                }
                continue;
            }
            if !pressed || repeat || typing {
                continue;
            }
            match key {
                egui::Key::F => {
                    let (lo, hi) = self.shown.bounds();
                    self.viewport.camera.frame(lo, hi);
                }
                egui::Key::R => self.viewport.camera = behind(&self.shown),
                egui::Key::F9 => self.toggle_recording(),
                _ => {}
            }
        }
        if let Some(path) = dropped.first().map(|f| f.path().to_path_buf()) {
            self.open(path);
        }
    }

    /// Steps the teacher at its frame rate (one step per rendered frame under a key
    /// script, so scripted runs are deterministic) and keeps the camera following it.
    fn animate(&mut self, seconds: f64) {
        let steps = if self.options.keys.is_some() {
            1
        } else {
            self.step_clock += seconds * f64::from(FRAME_RATE);
            let steps = self.step_clock.floor().min(MAX_STEPS_PER_FRAME);
            self.step_clock = (self.step_clock - steps).min(1.0);
            steps as u32
        };
        let before = self.shown.focus();
        self.shown.advance(
            &self.gpu,
            &self.viewport.renderer,
            self.action,
            self.options.keys.as_ref(),
            steps,
        );
        let after = self.shown.focus();
        if let (true, Some(before), Some(after)) = (self.follow, before, after) {
            self.viewport.camera.target += after - before;
        }
    }

    fn record_frame(&mut self) {
        let Some((recorder, started)) = &mut self.recording else {
            return;
        };
        if let Some(err) = recorder.poll_error() {
            let (recorder, _) = self.recording.take().expect("recording is on");
            let written = recorder
                .stop()
                .map(|n| n.to_string())
                .unwrap_or_else(|_| "earlier".into());
            self.fail(format!(
                "recording stopped: {err} (the {written} frames before it are kept)"
            ));
            return;
        }
        let due = recorder.frames_due(started.elapsed().as_secs_f64());
        if due == 0 {
            return;
        }
        let Some(target) = self.viewport.target() else {
            return;
        };
        match gpu::readback::rgba_texture(&self.gpu, &target.color) {
            Ok(image) => {
                let moment = recorder::Moment {
                    action: self.action,
                    camera: self.viewport.camera,
                    root: self.shown.focus(),
                };
                recorder.push(image, moment, due)
            }
            Err(e) => self.message = Some(format!("Recording: {e}")),
        }
    }
}

impl eframe::App for UnicaApp {
    /// Runs every pass, the window shown or hidden: the `--stress-resize` script.
    fn logic(&mut self, ctx: &egui::Context, _frame: &mut eframe::Frame) {
        if let Some(script) = self.resizes.as_mut().filter(|s| !s.done()) {
            for command in script.step(Instant::now(), OPENING_SIZE) {
                ctx.send_viewport_cmd(command);
            }
            ctx.request_repaint_after(Duration::from_millis(50));
        }
    }

    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        if self.device_gone(&ctx) {
            return;
        }
        let now = Instant::now();
        let dt = now.duration_since(self.last_frame).as_secs_f64() * 1e3;
        self.last_frame = now;

        if let Some(neural) = &self.shown.neural {
            neural.avatar.window_started();
        }
        if let (None, Some(n)) = (
            self.model_started,
            self.shown.neural.as_ref().filter(|n| n.frames > 0),
        ) {
            self.model_started = Some((now, self.frame, n.frames));
        }
        self.hud.refresh(now, self.frame, &self.timings);
        for error in self.gpu_errors.lock().expect("GPU error lock").drain(..) {
            self.gpu_error_count += 1;
            self.message = Some(format!("GPU error (the window goes on): {error}"));
        }

        let input = ctx.input(took_input);
        self.handle_input(&ctx);
        self.action = match &self.options.keys {
            Some(script) => script.action_at(self.shown.generated_frames() as usize),
            None => self.keys.current(),
        };
        self.animate(dt * 1e-3);
        if let Some(script) = &self.options.keys {
            // The action the next generated frame takes.
            self.action = script.action_at(self.shown.generated_frames() as usize);
        }

        egui::Panel::top("menu").show(ui, |ui| self.menu_bar(ui));
        egui::Panel::right("hud")
            .resizable(true)
            .default_size(260.0)
            .show(ui, |ui| self.hud(ui));
        egui::Window::new("Key map")
            .open(&mut self.show_help)
            .resizable(false)
            .show(&ctx, |ui| {
                egui::Grid::new("keys").striped(true).show(ui, |ui| {
                    for (key, what) in KEY_MAP {
                        ui.monospace(*key);
                        ui.label(*what);
                        ui.end_row();
                    }
                });
            });
        let state = frame.wgpu_render_state().expect("wgpu renderer").clone();
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| {
                let meshes = self.shown.gpu_meshes();
                let scene = self.shown.scene_generation();
                let splats = self.shown.splats();
                let labels = self.shown.labels();
                let scene = viewport::Scene {
                    meshes: &meshes,
                    generation: scene,
                    splats,
                    labels: &labels,
                    light: self.shown.light(),
                    full_size: self.recording.is_some(),
                };
                let timings = self
                    .viewport
                    .show(ui, &self.gpu, state.target_format, scene);
                if !timings.is_empty() {
                    self.timings = timings;
                }
                if let Some(note) = self.first_frame_note() {
                    ui.painter().text(
                        ui.max_rect().center_bottom() - egui::vec2(0.0, 40.0),
                        egui::Align2::CENTER_BOTTOM,
                        note,
                        egui::FontId::proportional(18.0),
                        egui::Color32::WHITE,
                    );
                }
            });
        if input {
            // The frame that took the input is drawn once the viewport's work, queued
            // behind any model part already submitted, has run.
            let latencies = self.latencies.clone();
            self.gpu.queue.on_submitted_work_done(move || {
                let ms = now.elapsed().as_secs_f64() * 1e3;
                latencies.lock().expect("latency lock").push(ms);
            });
        }
        self.record_frame();
        // The viewport's GPU work for this frame is done: the model may take its turn.
        if let Some(neural) = &self.shown.neural {
            neural.avatar.window_frame();
        }
        if let Some(e) = self.shown.neural.as_mut().and_then(|n| n.failure.take()) {
            self.fail(format!("the neural avatar stopped: {e}"));
        }
        if self.closing {
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            return;
        }
        self.frame += 1;
        self.scripted_exit(&ctx);
        self.schedule_repaint(&ctx);
    }

    /// Closing the window finishes a recording in progress (manifest included).
    fn on_exit(&mut self) {
        if self.recording.is_some() {
            self.toggle_recording();
            if let Some(message) = &self.message {
                println!("unica: {message}");
            }
        }
    }
}

impl UnicaApp {
    /// The note shown until the first generated frame arrives.
    fn first_frame_note(&self) -> Option<String> {
        let loaded = self.shown.first_frame_pending()?;
        let seconds = self.opened.elapsed().as_secs_f64();
        Some(if loaded {
            format!("The first generated frame is on its way… ({seconds:.0} s)")
        } else {
            format!("Loading the neural avatar… ({seconds:.0} s)")
        })
    }
}

/// The HUD's counters, refreshed at most twice a second so that they never make the
/// window draw on their own.
#[derive(Default)]
struct HudCounters {
    at: Option<(Instant, u64)>,
    window_fps: f64,
    timings: Vec<StageTiming>,
}

impl HudCounters {
    const PERIOD: Duration = Duration::from_millis(500);

    fn refresh(&mut self, now: Instant, frame: u64, timings: &[StageTiming]) {
        match self.at {
            Some((at, _)) if now.duration_since(at) < Self::PERIOD => {}
            Some((at, before)) => {
                self.window_fps = (frame - before) as f64 / now.duration_since(at).as_secs_f64();
                self.timings = timings.to_vec();
                self.at = Some((now, frame));
            }
            None => self.at = Some((now, frame)),
        }
    }
}

/// Whether this frame took input that the picture answers: a key pressed, a pointer
/// button, a drag or a wheel turn.
fn took_input(i: &egui::InputState) -> bool {
    let dragging = i.pointer.any_down() && i.pointer.delta() != egui::Vec2::ZERO;
    dragging
        || i.events.iter().any(|e| {
            matches!(
                e,
                egui::Event::Key {
                    pressed: true,
                    repeat: false,
                    ..
                } | egui::Event::PointerButton { .. }
                    | egui::Event::MouseWheel { .. }
            )
        })
}

/// The median of `values`; None when there are none.
fn median(values: &[f64]) -> Option<f64> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    (!sorted.is_empty()).then(|| {
        let mid = sorted.len() / 2;
        if sorted.len() % 2 == 1 {
            sorted[mid]
        } else {
            0.5 * (sorted[mid - 1] + sorted[mid])
        }
    })
}

/// A wake-up for the neural avatar's worker: a new frame makes the window draw.
fn wake(ctx: &egui::Context) -> neural::Wake {
    let ctx = ctx.clone();
    // Not `request_repaint()`: egui answers each of those with two frames ("to give some
    // things time to settle"), and a new generated frame needs one; a delay above zero
    // gets exactly one. On a CPU driver the second, unchanged frame took model time
    // (docs/performance.md: 1.39 → 1.51 generated frames a second beside the window).
    Arc::new(move || ctx.request_repaint_after(Duration::from_millis(1)))
}

/// The key map shown in Help and the README.
pub const KEY_MAP: &[(&str, &str)] = &[
    ("W / Up", "Forward"),
    ("S / Down", "Backward"),
    ("A / Left", "Left"),
    ("D / Right", "Right"),
    ("no key held", "Idle"),
    ("left drag", "orbit the camera"),
    ("right / middle drag", "pan"),
    ("wheel", "zoom"),
    ("F", "frame the avatar"),
    ("R", "reset the camera"),
    ("F9", "start / stop recording"),
];

/// Most teacher frames run in one rendered frame when the window falls behind.
const MAX_STEPS_PER_FRAME: f64 = 4.0;

/// The default view: behind the avatar (which starts facing +Z), a little to its left,
/// framing it.
fn behind(shown: &Shown) -> OrbitCamera {
    let mut camera = OrbitCamera {
        yaw: std::f32::consts::PI - 0.45,
        ..OrbitCamera::default()
    };
    let (lo, hi) = shown.bounds();
    camera.frame(lo, hi);
    camera.distance *= 1.4;
    camera
}

fn movement(key: egui::Key) -> Option<Action> {
    Some(match key {
        egui::Key::W | egui::Key::ArrowUp => Action::Forward,
        egui::Key::S | egui::Key::ArrowDown => Action::Backward,
        egui::Key::A | egui::Key::ArrowLeft => Action::Left,
        egui::Key::D | egui::Key::ArrowRight => Action::Right,
        _ => return None,
    })
}
