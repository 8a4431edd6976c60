//! Progress bars for the commands that run for minutes (bake, render, export, eval,
//! rig). On a terminal they are indicatif's bars. Where stderr is not a terminal
//! (a log file, CI, `nohup`), indicatif hides its bars, so a 30-minute `unica eval` said
//! nothing until it ended; there the bar's line is written as plain text at most once
//! every [`LOG_EVERY`], so such a run still shows that it is alive and how far it is.

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{
    HumanDuration, ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle, TermLike,
};

/// How often a bar writes its line where stderr is not a terminal.
pub const LOG_EVERY: Duration = Duration::from_secs(30);

/// A bar of `len` steps drawn with `template` (indicatif's template syntax, plus
/// `{left}`: see [`time_left`]): a live bar on a terminal, a line every [`LOG_EVERY`]
/// otherwise.
pub fn bar(template: &str, len: u64) -> ProgressBar {
    let style = ProgressStyle::with_template(template)
        .expect("valid template")
        .with_key(
            "left",
            |state: &ProgressState, w: &mut dyn std::fmt::Write| {
                let _ = w.write_str(&time_left(state.elapsed(), state.pos(), state.len()));
            },
        );
    let bar = ProgressBar::new(len).with_style(style);
    if !std::io::stderr().is_terminal() {
        bar.set_draw_target(log_target(Box::new(std::io::stderr()), LOG_EVERY));
    }
    bar
}

/// A draw target that writes each drawn bar as one line to `out`, at most once every
/// `every` (the first drawing always).
pub fn log_target(out: Box<dyn Write + Send>, every: Duration) -> ProgressDrawTarget {
    ProgressDrawTarget::term_like_with_hz(
        Box::new(Lines {
            every,
            state: Mutex::new(LinesState {
                out,
                text: String::new(),
                last: None,
            }),
        }),
        1,
    )
}

/// "N left" at the mean rate since the bar started (or was reset): `elapsed` × the steps
/// to go / the steps done; "time left unknown" before the first step. indicatif's
/// `{eta}` follows the recent rate, which decays toward zero while no step comes: a
/// frame scored at level 1024 holds `unica eval`'s bar for a minute on a CPU driver, and
/// its `{eta}` then read hundreds of years.
pub fn time_left(elapsed: Duration, done: u64, total: Option<u64>) -> String {
    match total {
        Some(total) if done > 0 => {
            let left = elapsed.mul_f64(total.saturating_sub(done) as f64 / done as f64);
            format!("{} left", HumanDuration(left))
        }
        _ => "time left unknown".to_string(),
    }
}

struct LinesState {
    out: Box<dyn Write + Send>,
    /// What indicatif has written since its last flush.
    text: String,
    /// When a line was last written.
    last: Option<Instant>,
}

struct Lines {
    every: Duration,
    state: Mutex<LinesState>,
}

impl std::fmt::Debug for Lines {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lines").field("every", &self.every).finish()
    }
}

impl Lines {
    fn push(&self, s: &str) {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        state.text.push_str(s);
    }
}

impl TermLike for Lines {
    fn width(&self) -> u16 {
        100
    }
    fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn write_line(&self, s: &str) -> std::io::Result<()> {
        self.push(s);
        self.push(" ");
        Ok(())
    }
    fn write_str(&self, s: &str) -> std::io::Result<()> {
        self.push(s);
        Ok(())
    }
    fn clear_line(&self) -> std::io::Result<()> {
        Ok(())
    }
    fn flush(&self) -> std::io::Result<()> {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let text = std::mem::take(&mut state.text);
        let line = text.replace('\r', "");
        let line = line.trim();
        let due = state.last.is_none_or(|t| t.elapsed() >= self.every);
        if line.is_empty() || !due {
            return Ok(());
        }
        state.last = Some(Instant::now());
        writeln!(state.out, "{line}")?;
        state.out.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A writer whose bytes the test can read.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);

    impl Write for Shared {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    fn written(out: &Shared) -> String {
        String::from_utf8(out.0.lock().unwrap().clone()).unwrap()
    }

    #[test]
    fn time_left_is_the_mean_rate_since_the_start() {
        // 30 of 120 done in 60 s: 90 to go at 2 s each.
        assert_eq!(
            time_left(Duration::from_secs(60), 30, Some(120)),
            "3 minutes left"
        );
        assert_eq!(
            time_left(Duration::from_secs(60), 0, Some(120)),
            "time left unknown"
        );
        assert_eq!(
            time_left(Duration::from_secs(60), 120, Some(120)),
            "0 seconds left"
        );
        // A stall grows it in proportion, never to years: 10 s more without a step,
        // 90 to go at 70/30 s each is 210 s.
        assert_eq!(
            time_left(Duration::from_secs(70), 30, Some(120)),
            "4 minutes left"
        );
    }

    #[test]
    fn a_piped_bar_writes_plain_lines_and_no_faster_than_asked() {
        let out = Shared::default();
        let bar = ProgressBar::new(10)
            .with_style(ProgressStyle::with_template("frames {pos}/{len}").unwrap());
        bar.set_draw_target(log_target(Box::new(out.clone()), Duration::ZERO));
        bar.set_position(3);
        bar.tick();
        let text = written(&out);
        assert!(text.contains("frames 3/10\n"), "{text:?}");
        assert!(!text.contains('\r') && !text.contains('\x1b'), "{text:?}");

        let slow = Shared::default();
        let bar = ProgressBar::new(10)
            .with_style(ProgressStyle::with_template("frames {pos}/{len}").unwrap());
        bar.set_draw_target(log_target(
            Box::new(slow.clone()),
            Duration::from_secs(3600),
        ));
        for i in 0..10 {
            bar.set_position(i);
            bar.tick();
        }
        assert_eq!(written(&slow).lines().count(), 1, "{:?}", written(&slow));
    }
}
