//! The window's menus and heads-up display: the menu bar (file, view, record, help) and
//! the HUD's lines (speeds, the neural avatar's sampler and stages, the recorder).

use std::path::PathBuf;

use eframe::egui;

use super::{UnicaApp, behind, shown, viewport};
use crate::action::Action;
use crate::avatar::locomotion::FRAME_RATE;
use crate::nn::sampler::SamplerKind;

impl UnicaApp {
    pub(super) fn menu_bar(&mut self, ui: &mut egui::Ui) {
        egui::MenuBar::new().ui(ui, |ui| {
            ui.menu_button("File", |ui| {
                ui.label("A bundle folder (neural avatar) or a character file (.gltf, .glb, .obj); or drop one on the window:");
                ui.text_edit_singleline(&mut self.open_path);
                if ui.button("Open").clicked() {
                    self.open(PathBuf::from(self.open_path.trim()));
                    ui.close();
                }
                ui.separator();
                if ui.button("Quit").clicked() {
                    ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
                }
            });
            ui.menu_button("Record", |ui| {
                ui.label("Folder for numbered PNG frames and manifest.json:");
                ui.add_enabled(
                    self.recording.is_none(),
                    egui::TextEdit::singleline(&mut self.record_dir),
                );
                ui.add_enabled(
                    self.recording.is_none(),
                    egui::DragValue::new(&mut self.options.record_fps)
                        .range(1.0..=120.0)
                        .suffix(" fps"),
                );
                let label = if self.recording.is_some() {
                    "Stop recording (F9)"
                } else {
                    "Start recording (F9)"
                };
                if ui.button(label).clicked() {
                    self.toggle_recording();
                    ui.close();
                }
            });
            ui.menu_button("View", |ui| {
                if !self.options.avatars.is_empty() {
                    ui.menu_button("Avatar", |ui| {
                        let mut chosen = None;
                        for avatar in &self.options.avatars {
                            let current = self.shown.bundle().is_some_and(|dir| {
                                dir.canonicalize().ok() == avatar.bundle.canonicalize().ok()
                            });
                            if ui.radio(current, &avatar.name).clicked() && !current {
                                chosen = Some(avatar.clone());
                            }
                        }
                        if let Some(avatar) = chosen {
                            self.open_with(avatar.bundle, Some(avatar.character));
                            ui.close();
                        }
                    });
                    ui.separator();
                }
                ui.checkbox(&mut self.follow, "Camera follows the avatar");
                if self.shown.neural.is_some() && self.shown.teacher.is_some() {
                    ui.checkbox(&mut self.shown.show_teacher, "Teacher beside the neural avatar");
                }
                if ui.button("Frame the avatar (F)").clicked() {
                    let (lo, hi) = self.shown.bounds();
                    self.viewport.camera.frame(lo, hi);
                    ui.close();
                }
                if ui.button("Reset the camera (R)").clicked() {
                    self.viewport.camera = behind(&self.shown);
                    ui.close();
                }
            });
            ui.menu_button("Help", |ui| {
                if ui.button("Key map").clicked() {
                    self.show_help = true;
                    ui.close();
                }
            });
        });
    }

    pub(super) fn hud(&mut self, ui: &mut egui::Ui) {
        ui.heading(&self.shown.name);
        if let Some(problem) = &self.shown.problem {
            ui.colored_label(egui::Color32::YELLOW, problem);
        }
        ui.separator();
        ui.label(
            egui::RichText::new(format!("Action: {}", self.action))
                .size(20.0)
                .strong(),
        );
        ui.horizontal(|ui| {
            for action in [
                Action::Left,
                Action::Forward,
                Action::Backward,
                Action::Right,
            ] {
                let text = egui::RichText::new(action.letter().to_string())
                    .monospace()
                    .size(18.0);
                let text = if action == self.action {
                    text.color(egui::Color32::BLACK)
                        .background_color(egui::Color32::LIGHT_GREEN)
                } else {
                    text
                };
                ui.label(text);
            }
        });
        if self.options.keys.is_some() {
            ui.label(format!(
                "Key script: generated frame {}",
                self.shown.generated_frames()
            ));
        }
        if let Some(neural) = &mut self.shown.neural {
            neural_hud(ui, neural);
        }
        if let Some(teacher) = &self.shown.teacher {
            let loco = &teacher.locomotion;
            let root = teacher.root();
            ui.label(format!(
                "Teacher: {:.2} m/s, heading {:.0}°",
                loco.speed,
                loco.yaw.to_degrees()
            ));
            ui.label(format!(
                "Root: ({:.2}, {:.2}, {:.2})",
                root.x, root.y, root.z
            ));
        }
        ui.separator();
        ui.label(format!(
            "Window: {:.1} frames/s, drawn only when something changes",
            self.hud.window_fps
        ));
        for t in &self.hud.timings {
            ui.label(format!("{}: {:.3} ms ({})", t.name, t.ms, t.clock));
        }
        ui.add(
            egui::Slider::new(&mut self.viewport.resolution_scale, 0.25..=1.0)
                .text("3D resolution scale"),
        );
        ui.separator();
        ui.label(format!("Adapter: {}", self.gpu.adapter_label()));
        let cpu = self.gpu.cpu_driver();
        ui.label(format!(
            "Defaults for {}: the bundle's sampler (one pass where distilled), splat level {}, \
             3D resolution scale {}",
            if cpu { "a CPU driver" } else { "a GPU" },
            crate::engine::appearance::default_level(&self.gpu),
            viewport::default_resolution_scale(&self.gpu)
        ));
        let caps = self.gpu.caps;
        ui.label(format!(
            "f16: {}  subgroups: {}  timestamps: {}",
            yes_no(caps.shader_f16),
            yes_no(caps.subgroups),
            yes_no(caps.timestamps)
        ));
        if let Some((recorder, _)) = &self.recording {
            ui.separator();
            ui.colored_label(
                egui::Color32::RED,
                format!("● REC → {}", recorder.dir.display()),
            );
        }
        if let Some(message) = &self.message {
            ui.separator();
            ui.label(message);
        }
    }
}

/// The neural avatar's part of the HUD: generation rate, lag, model timings, clamped
/// values, and the live settings (DDIM steps, CFG scale, PCA, splats or surface, the
/// refiner, the splat level).
fn neural_hud(ui: &mut egui::Ui, neural: &mut shown::Neural) {
    ui.label(format!(
        "Neural: {:.1} generated fps (data rate {FRAME_RATE}), frame {}",
        neural.avatar.fps, neural.frames
    ));
    ui.label(format!(
        "Model and splats on the GPU: {:.1} s per generated frame, worked on in slices \
         between window frames (the window keeps its own rate)",
        neural.frame_ms / 1e3
    ));
    if neural.clamped > 0 {
        ui.colored_label(
            egui::Color32::YELLOW,
            format!("{} values clamped to [0, 1]", neural.clamped),
        );
    }
    let has_refiner = neural.has_refiner;
    let Some(settings) = &mut neural.settings else {
        return;
    };
    let before = *settings;
    if let Some(bundled) = neural.bundled.filter(|b| b.kind == SamplerKind::OnePass) {
        let mut one_pass = settings.sampling.kind == SamplerKind::OnePass;
        ui.horizontal(|ui| {
            ui.radio_value(&mut one_pass, true, "One pass (distilled)");
            ui.radio_value(&mut one_pass, false, "Teacher (DDIM)");
        });
        if one_pass != (settings.sampling.kind == SamplerKind::OnePass) {
            settings.sampling = if one_pass {
                bundled.live()
            } else {
                bundled.ddim(bundled.steps)
            };
        }
    }
    ui.label(format!(
        "{} UNet pass{} a frame",
        settings.sampling.unet_passes(),
        if settings.sampling.unet_passes() == 1 {
            ""
        } else {
            "es"
        }
    ));
    if settings.sampling.kind == SamplerKind::Ddim {
        ui.add(egui::Slider::new(&mut settings.sampling.steps, 1..=50).text("DDIM steps"));
        ui.add(egui::Slider::new(&mut settings.sampling.cfg_scale, 0.0..=5.0).text("CFG scale"));
    }
    ui.checkbox(&mut settings.pca, "PCA clean-up");
    ui.checkbox(&mut settings.splats, "Splats (else the surface)");
    ui.add_enabled(
        has_refiner,
        egui::Checkbox::new(&mut settings.refine, "Refiner"),
    );
    egui::ComboBox::from_label("Splat level")
        .selected_text(format!("{0}² map", settings.level))
        .show_ui(ui, |ui| {
            for level in crate::engine::appearance::LEVELS {
                ui.selectable_value(&mut settings.level, level, format!("{level}² map"));
            }
        });
    if *settings != before {
        neural.avatar.set_settings(*settings);
    }
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}
