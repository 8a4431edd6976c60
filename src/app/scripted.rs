//! A scripted session (`--keys`, `--exit-after`, `--exit-after-seconds`): when it ends,
//! its final line, how a failure ends it, and when the window draws again.

use std::time::Duration;

use eframe::egui;

use super::{UnicaApp, median};

impl UnicaApp {
    /// Whether the session is scripted (`--keys`, `--exit-after` or
    /// `--exit-after-seconds`): a failure then ends it with a non-zero exit.
    pub(super) fn scripted(&self) -> bool {
        self.options.keys.is_some()
            || self.options.exit_after.is_some()
            || self.options.exit_after_seconds.is_some()
    }

    /// The line a scripted session ends with: frames drawn, the action, and with a
    /// neural avatar the generated and window rates while the model ran
    /// (`generated_fps=`, `window_fps=`) and the median input latency
    /// (`input_latency_ms=`, "none" without input).
    pub(super) fn final_line(&self) -> String {
        let generated = self
            .shown
            .neural
            .as_ref()
            .map(|n| {
                let (generated_fps, window_fps) =
                    self.model_started.map_or((0.0, 0.0), |(t, frame, first)| {
                        let seconds = t.elapsed().as_secs_f64().max(1e-9);
                        (
                            n.frames.saturating_sub(first) as f64 / seconds,
                            (self.frame - frame) as f64 / seconds,
                        )
                    });
                format!(
                    "; {} generated frames; {generated_fps:.2} generated per second; the window \
                     ran at {window_fps:.1} fps while the model ran; generated_fps={generated_fps:.3} \
                     window_fps={window_fps:.2}",
                    n.frames
                )
            })
            .unwrap_or_default();
        let latency = median(&self.latencies.lock().expect("latency lock"))
            .map_or("none".to_string(), |ms| format!("{ms:.1}"));
        let beside = match (&self.shown.neural, &self.shown.teacher) {
            (Some(_), Some(teacher)) if self.shown.show_teacher => {
                format!("; teacher {} beside", teacher.character.name)
            }
            _ => String::new(),
        };
        format!(
            "unica: {} frames rendered; action {}; character {}{beside}{generated}; input_latency_ms={latency} gpu_errors={}",
            self.frame, self.action, self.shown.name, self.gpu_error_count
        )
    }

    /// The window draws again only when something will change: continuously while a
    /// teacher alone animates or `--exit-after N` counts frames; else at a recording's
    /// ticks, each second while the first generated frame is on its way (its note counts
    /// up), when `--exit-after-seconds` is due, and once more after a camera move (the
    /// splats drawn small while moving are redrawn at full size). Input and the model's
    /// new frames (its worker wakes the window) need nothing here.
    pub(super) fn schedule_repaint(&self, ctx: &egui::Context) {
        let teacher_alone = self.shown.neural.is_none() && self.shown.teacher.is_some();
        if self.options.exit_after.is_some() || teacher_alone {
            ctx.request_repaint();
            return;
        }
        if self.recording.is_some() {
            ctx.request_repaint_after(Duration::from_secs_f64(1.0 / self.options.record_fps));
        }
        if self.shown.first_frame_pending().is_some() {
            ctx.request_repaint_after(Duration::from_millis(500));
        }
        if let Some(seconds) = self.options.exit_after_seconds {
            let left = (seconds - self.opened.elapsed().as_secs_f64()).max(0.0);
            ctx.request_repaint_after(Duration::from_secs_f64(left));
        }
        if !self.viewport.settled() {
            ctx.request_repaint_after(Duration::from_millis(100));
        }
    }

    /// Shows `problem`; a scripted session also closes and exits non-zero with it.
    pub(super) fn fail(&mut self, problem: String) {
        log::error!("{problem}");
        self.message = Some(problem.clone());
        if self.scripted() {
            let mut outcome = self.outcome.lock().expect("outcome lock");
            outcome.get_or_insert_with(|| anyhow::anyhow!("{problem}"));
            self.closing = true;
        }
    }

    /// `--exit-after N` (N window frames) or `--exit-after-seconds S`: take the
    /// screenshot (if asked), print the final line and close.
    pub(super) fn scripted_exit(&mut self, ctx: &egui::Context) {
        let frames_done = self.options.exit_after.is_some_and(|n| self.frame >= n);
        let time_done = self
            .options
            .exit_after_seconds
            .is_some_and(|s| self.opened.elapsed().as_secs_f64() >= s);
        if !(frames_done || time_done) || self.screenshot_requested {
            return;
        }
        self.screenshot_requested = true;
        println!("{}", self.final_line());
        let Some(path) = self.options.screenshot.clone() else {
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            return;
        };
        let outcome = self.outcome.clone();
        let close_ctx = ctx.clone();
        ctx.request_screenshot(move |image| {
            let rgba = image::RgbaImage::from_raw(
                image.size[0] as u32,
                image.size[1] as u32,
                image.pixels.iter().flat_map(|c| c.to_array()).collect(),
            );
            let result = match rgba {
                Some(rgba) => {
                    crate::files::write_png_atomic(&path, &rgba).map_err(anyhow::Error::from)
                }
                None => Err(anyhow::anyhow!("the screenshot had the wrong size")),
            };
            if let Err(e) = result {
                *outcome.lock().expect("outcome lock") = Some(e);
            }
            close_ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        });
    }
}
