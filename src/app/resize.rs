//! The window under resizing (`--stress-resize N`, for tests): N sizes from the opening
//! size down to 1 × 1 and back, one per window frame, then hidden (minimized, and unmapped,
//! which is what minimizing does where no window manager runs, as under Xvfb) for a
//! second, then shown again at the opening size. The app keeps drawing, recording and
//! running the model throughout.

use std::time::{Duration, Instant};

use eframe::egui;

/// How long the window stays hidden.
const HIDDEN: Duration = Duration::from_secs(1);

/// Where the script is.
#[derive(Debug)]
pub struct ResizeScript {
    sizes: Vec<[f32; 2]>,
    next: usize,
    hidden_since: Option<Instant>,
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
            hidden_since: None,
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
        match self.hidden_since {
            None => {
                self.hidden_since = Some(now);
                vec![C::Minimized(true), C::Visible(false)]
            }
            Some(t) if now.duration_since(t) < HIDDEN => Vec::new(),
            Some(_) => {
                self.done = true;
                vec![
                    C::Visible(true),
                    C::Minimized(false),
                    C::InnerSize(egui::vec2(full[0], full[1])),
                ]
            }
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
    fn the_window_is_hidden_after_the_sizes_and_shown_a_second_later() {
        let mut script = ResizeScript::new(3, [100.0, 50.0]);
        let t = Instant::now();
        let count = |c: Vec<egui::ViewportCommand>| c.len();
        assert_eq!(count(script.step(t, [100.0, 50.0])), 2); // min size, first size
        assert_eq!(count(script.step(t, [100.0, 50.0])), 1);
        assert_eq!(count(script.step(t, [100.0, 50.0])), 1);
        assert_eq!(count(script.step(t, [100.0, 50.0])), 2); // hidden
        assert_eq!(count(script.step(t, [100.0, 50.0])), 0);
        assert!(!script.done());
        let later = t + HIDDEN;
        assert_eq!(count(script.step(later, [100.0, 50.0])), 3); // shown, full size
        assert!(script.done());
    }
}
