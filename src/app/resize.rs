//! The window under resizing (`--stress-resize N`, for tests): N sizes from the opening
//! size down to 1 × 1 and back, one per window frame, then minimized for a second (a
//! window manager iconifies it; where none runs, as under a bare Xvfb, nothing happens),
//! then unmapped for a second (what minimizing does without a window manager), then shown
//! again at the opening size. The app keeps drawing, recording and running the model
//! throughout.

use std::time::{Duration, Instant};

use eframe::egui;

/// How long the window stays minimized, then unmapped.
const HIDDEN: Duration = Duration::from_secs(1);

/// Where the script is.
#[derive(Debug)]
pub struct ResizeScript {
    sizes: Vec<[f32; 2]>,
    next: usize,
    /// When the window was minimized, and when unmapped.
    minimized_since: Option<Instant>,
    unmapped_since: Option<Instant>,
    done: bool,
}

impl ResizeScript {
    /// `count` sizes from `full` geometrically down to 1 × 1 and back up.
    pub fn new(count: usize, full: [f32; 2]) -> Self {
        let half = count.div_ceil(2).max(1);
        let down: Vec<[f32; 2]> = (1..=half)
            .map(|i| {
                let t = i as f32 / half as f32;
                full.map(|side| side.powf(1.0 - t).round().max(1.0))
            })
            .collect();
        let up = down[..half - 1].iter().rev().copied().chain([full]);
        let mut sizes: Vec<[f32; 2]> = down.iter().copied().chain(up).collect();
        sizes.truncate(count);
        Self {
            sizes,
            next: 0,
            minimized_since: None,
            unmapped_since: None,
            done: false,
        }
    }

    /// The sizes asked for, in order.
    #[cfg(test)]
    pub fn sizes(&self) -> &[[f32; 2]] {
        &self.sizes
    }

    /// Whether every step has been taken.
    pub fn done(&self) -> bool {
        self.done
    }

    /// The commands for this window frame (none once done).
    pub fn step(&mut self, now: Instant, full: [f32; 2]) -> Vec<egui::ViewportCommand> {
        use egui::ViewportCommand as C;
        if self.done {
            return Vec::new();
        }
        if let Some(&[w, h]) = self.sizes.get(self.next) {
            let mut out = Vec::new();
            if self.next == 0 {
                out.push(C::MinInnerSize(egui::vec2(1.0, 1.0)));
            }
            self.next += 1;
            out.push(C::InnerSize(egui::vec2(w, h)));
            return out;
        }
        let waited = |since: Instant| now.duration_since(since) >= HIDDEN;
        match (self.minimized_since, self.unmapped_since) {
            (None, _) => {
                self.minimized_since = Some(now);
                vec![C::Minimized(true)]
            }
            (Some(t), None) if waited(t) => {
                self.unmapped_since = Some(now);
                vec![C::Visible(false)]
            }
            (Some(_), Some(t)) if waited(t) => {
                self.done = true;
                vec![
                    C::Visible(true),
                    C::Minimized(false),
                    C::InnerSize(egui::vec2(full[0], full[1])),
                ]
            }
            _ => Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sizes_go_down_to_one_pixel_and_back() {
        let script = ResizeScript::new(200, [1280.0, 800.0]);
        let sizes = script.sizes();
        assert_eq!(sizes.len(), 200);
        assert_eq!(sizes[99], [1.0, 1.0]);
        assert_eq!(sizes[199], [1280.0, 800.0]);
        assert!(sizes[..100].windows(2).all(|w| w[1][0] <= w[0][0]));
    }

    #[test]
    fn the_window_is_minimized_then_unmapped_after_the_sizes_and_shown_again() {
        use egui::ViewportCommand as C;
        let mut script = ResizeScript::new(3, [100.0, 50.0]);
        let t = Instant::now();
        let full = [100.0, 50.0];
        assert_eq!(script.step(t, full).len(), 2); // min size, first size
        assert_eq!(script.step(t, full).len(), 1);
        assert_eq!(script.step(t, full).len(), 1);
        assert_eq!(script.step(t, full), vec![C::Minimized(true)]);
        assert!(script.step(t, full).is_empty());
        let second = t + HIDDEN;
        assert_eq!(script.step(second, full), vec![C::Visible(false)]);
        assert!(script.step(second, full).is_empty());
        assert!(!script.done());
        let shown = script.step(second + HIDDEN, full);
        assert_eq!(shown[..2], [C::Visible(true), C::Minimized(false)]);
        assert!(script.done());
    }
}
