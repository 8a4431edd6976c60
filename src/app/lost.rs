//! A lost GPU device. eframe owns the device the window draws with and cannot be given
//! a new one, so a lost device ends the window: one line saying so, exit 1, the
//! recording whole. egui's painter panics on its next upload to a lost device
//! (egui-wgpu 0.37: "Failed to create staging buffer"), which nothing can prevent when
//! the loss comes between a frame's UI and its painting, and wgpu may report the loss
//! only as the device is dropped while that panic unwinds: the panic is caught around
//! the window and the panic hook keeps quiet about it.

use std::sync::{Arc, Mutex};

use eframe::egui;

use super::UnicaApp;

/// Why the device was lost, once it is (set from wgpu's callback).
pub type Lost = Arc<Mutex<Option<String>>>;

/// Records the loss of `device` in `lost`.
pub fn watch(device: &wgpu::Device, lost: &Lost) {
    let lost = lost.clone();
    device.set_device_lost_callback(move |reason, message| {
        let why = if message.is_empty() {
            format!("{reason:?}")
        } else {
            format!("{reason:?}: {message}")
        };
        log::error!("the GPU device was lost ({why})");
        *lost.lock().expect("device lost lock") = Some(why);
    });
}

/// Runs the window (`body`); a panic that a lost device caused becomes the one-line
/// error, any other panic goes on.
pub fn caught<R>(lost: &Lost, body: impl FnOnce() -> R) -> anyhow::Result<R> {
    let hook_lost = lost.clone();
    let previous_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let known = hook_lost.lock().is_ok_and(|lost| lost.is_some());
        if !(known || painter_lost_its_device(info.payload())) {
            previous_hook(info);
        }
    }));
    let panic = match std::panic::catch_unwind(std::panic::AssertUnwindSafe(body)) {
        Ok(ran) => return Ok(ran),
        Err(panic) => panic,
    };
    if painter_lost_its_device(panic.as_ref()) {
        let mut lost = lost.lock().unwrap_or_else(|e| e.into_inner());
        lost.get_or_insert_with(|| "egui could not upload to it".into());
    }
    reported(lost)?;
    std::panic::resume_unwind(panic)
}

/// The one-line error for a lost device, if it was lost.
pub fn reported(lost: &Lost) -> anyhow::Result<()> {
    match lost.lock().ok().and_then(|lost| lost.clone()) {
        Some(why) => anyhow::bail!(
            "the GPU device was lost ({why}): unica cannot draw without it; start it again \
             (a recording keeps every frame made before it)"
        ),
        None => Ok(()),
    }
}

/// Whether a panic is egui-wgpu's painter failing to upload a frame, which it does when
/// the device is lost.
fn painter_lost_its_device(payload: &(dyn std::any::Any + Send)) -> bool {
    let message = payload
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| payload.downcast_ref::<&str>().copied())
        .unwrap_or("");
    message.starts_with("Failed to create staging buffer")
}

impl UnicaApp {
    /// Whether the GPU device is known to be lost (`--stress-lose-device` destroys it
    /// here; wgpu says so a little later, while the frame is painted, as a real loss can
    /// come at any moment). Then the window is asked to close (the run ends with
    /// [`reported`]'s line) and the frame adds nothing to draw.
    pub(super) fn device_gone(&mut self, ctx: &egui::Context) -> bool {
        if let Some(seconds) = self.options.stress_lose_device
            && !self.device_destroyed
            && self.opened.elapsed().as_secs_f64() >= seconds
        {
            self.device_destroyed = true;
            self.gpu.device.destroy();
        }
        if self.device_lost.lock().expect("device lost lock").is_none() {
            return false;
        }
        // The run's error line is `reported`'s, given when the window has closed.
        self.closing = true;
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_painters_upload_failure_counts_as_a_lost_device() {
        let staging: Box<dyn std::any::Any + Send> = Box::new(String::from(
            "Failed to create staging buffer for index data. Index count: 7455.",
        ));
        assert!(painter_lost_its_device(staging.as_ref()));
        let other: Box<dyn std::any::Any + Send> = Box::new("index out of bounds");
        assert!(!painter_lost_its_device(other.as_ref()));
    }
}
