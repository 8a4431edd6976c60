//! The strict evaluation's numbers: every seed's lockstep scores and motion reduced to
//! summary.json's keys (means, worst seed, worst background) and a report.md that sets
//! them beside the targets of docs/eval.

use std::fmt::Write;

use serde_json::{Map, Value, json};

use super::lockstep::{FrameScore, LockstepRun, VIEWS, ViewScore};
use super::motion::{self, MotionCompare};
use super::pixels::BACKGROUNDS;

/// PSNR of identical pixels is infinite; averages take it as this.
const PSNR_CAP: f64 = 100.0;

/// A slide shorter than this (m) gives no ratio: the teacher barely moved.
const MIN_SLIDE_M: f32 = 0.02;

/// One seed's run on its script.
pub struct SeedRun {
    pub seed: u64,
    pub script: String,
    pub run: LockstepRun,
    pub motion: MotionCompare,
}

/// Which comparison of a scored frame.
#[derive(Clone, Copy, PartialEq)]
pub enum Kind {
    Best,
    Same,
    Ceiling,
}

impl Kind {
    fn of(self, f: &FrameScore) -> &[ViewScore] {
        match self {
            Kind::Best => &f.best,
            Kind::Same => &f.same,
            Kind::Ceiling => &f.ceiling,
        }
    }
}

/// Means over views and frames, per background (BACKGROUNDS order).
#[derive(Clone, Debug, Default)]
pub struct Means {
    pub psnr_db: [f64; 3],
    pub ssim: [f64; 3],
    pub iou: f64,
    pub halo: f64,
    pub holes: f64,
    pub face_psnr_db: [f64; 3],
    pub hands_psnr_db: [f64; 3],
    pub count: usize,
}

impl Means {
    fn of<'a>(scores: impl Iterator<Item = &'a ViewScore>) -> Means {
        let mut m = Means::default();
        let (mut faces, mut hands) = (0usize, 0usize);
        for s in scores {
            m.count += 1;
            for b in 0..3 {
                m.psnr_db[b] += s.psnr_db[b].min(PSNR_CAP);
                m.ssim[b] += s.ssim[b];
            }
            m.iou += s.silhouette.iou;
            m.halo += s.silhouette.halo;
            m.holes += s.silhouette.holes;
            if let Some(f) = s.face_psnr_db {
                faces += 1;
                for (sum, v) in m.face_psnr_db.iter_mut().zip(f) {
                    *sum += v.min(PSNR_CAP);
                }
            }
            if let Some(h) = s.hands_psnr_db {
                hands += 1;
                for (sum, v) in m.hands_psnr_db.iter_mut().zip(h) {
                    *sum += v.min(PSNR_CAP);
                }
            }
        }
        let n = m.count.max(1) as f64;
        for b in 0..3 {
            m.psnr_db[b] /= n;
            m.ssim[b] /= n;
            m.face_psnr_db[b] /= faces.max(1) as f64;
            m.hands_psnr_db[b] /= hands.max(1) as f64;
        }
        m.iou /= n;
        m.halo /= n;
        m.holes /= n;
        m
    }

    fn worst(values: [f64; 3]) -> f64 {
        values.into_iter().fold(f64::INFINITY, f64::min)
    }

    pub fn worst_psnr(&self) -> f64 {
        Self::worst(self.psnr_db)
    }

    pub fn worst_ssim(&self) -> f64 {
        Self::worst(self.ssim)
    }

    pub fn worst_face(&self) -> f64 {
        Self::worst(self.face_psnr_db)
    }
}

/// The means of `kind` at `level` over the given runs' frames (and views, when `view`).
fn means(runs: &[&SeedRun], level: usize, kind: Kind, view: Option<usize>) -> Means {
    Means::of(
        runs.iter()
            .flat_map(|r| r.run.scores.iter())
            .filter(|f| f.level == level)
            .flat_map(|f| kind.of(f).iter())
            .filter(|s| view.is_none_or(|v| s.view == v)),
    )
}

/// One seed's best-in-window pixels at the finest level with scored frames, and the level.
fn seed_pixels(run: &SeedRun, levels: &[usize]) -> (Option<usize>, Means) {
    let mut finest_first = levels.to_vec();
    finest_first.sort_unstable_by(|a, b| b.cmp(a));
    finest_first
        .into_iter()
        .map(|level| (Some(level), means(&[run], level, Kind::Best, None)))
        .find(|(_, m)| m.count > 0)
        .unwrap_or((None, Means::default()))
}

fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn min_max(values: &[f64]) -> (Value, Value) {
    if values.is_empty() {
        return (Value::Null, Value::Null);
    }
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (number(lo), number(hi))
}

/// A JSON number; infinities and NaN (which JSON cannot hold) as null.
fn number(x: f64) -> Value {
    if x.is_finite() { json!(x) } else { Value::Null }
}

/// The motion ratios of one or more runs: (turn, slide, stop) ratios, the largest idle
/// creep (m) and speed error (%).
struct MotionNumbers {
    turns: Vec<f64>,
    slides: Vec<f64>,
    stops: Vec<f64>,
    creep_m: Option<f64>,
    teacher_creep_m: Option<f64>,
    speed_error_pct: Option<f64>,
}

fn motion_numbers(runs: &[&SeedRun]) -> MotionNumbers {
    let mut n = MotionNumbers {
        turns: Vec::new(),
        slides: Vec::new(),
        stops: Vec::new(),
        creep_m: None,
        teacher_creep_m: None,
        speed_error_pct: None,
    };
    let max = |a: Option<f64>, b: f64| Some(a.map_or(b, |a| a.max(b)));
    for r in runs {
        let m = &r.motion;
        for t in &m.turns {
            let f = |x: Option<usize>| x.map(|x| x as f64);
            n.turns.extend(motion::ratio(f(t.generated), f(t.teacher)));
        }
        for s in &m.stops {
            if s.teacher_slide_m >= MIN_SLIDE_M {
                n.slides.push(s.slide_m as f64 / s.teacher_slide_m as f64);
            }
            let f = |x: Option<usize>| x.map(|x| x as f64);
            n.stops
                .extend(motion::ratio(f(s.frames), f(s.teacher_frames)));
        }
        for c in &m.creep {
            n.creep_m = max(n.creep_m, c.creep_m as f64);
            n.teacher_creep_m = max(n.teacher_creep_m, c.teacher_creep_m as f64);
        }
        for s in &m.speeds {
            let e = 100.0 * ((s.speed - s.teacher_speed) / s.teacher_speed).abs() as f64;
            n.speed_error_pct = max(n.speed_error_pct, e);
        }
    }
    n
}

/// Facing error (degrees) of every frame after the start, and the horizontal root
/// distance (m), generated against the teacher at the same index.
fn following(run: &LockstepRun) -> (Vec<f64>, Vec<f64>) {
    let facing = run
        .engine_facing
        .iter()
        .zip(&run.teacher_facing)
        .skip(1)
        .map(|(e, t)| motion::wrap_deg(e - t).abs() as f64)
        .collect();
    let roots = run
        .engine_roots
        .iter()
        .zip(&run.teacher_roots)
        .skip(1)
        .map(|(e, t)| {
            let d = *e - *t;
            (d.x * d.x + d.z * d.z).sqrt() as f64
        })
        .collect();
    (facing, roots)
}

/// summary.json: the headline level's numbers (worst background, mean over seeds),
/// each with its worst seed, every level's and background's, and the motion.
pub fn summary(runs: &[SeedRun], levels: &[usize], script_seed: u64) -> Map<String, Value> {
    let all: Vec<&SeedRun> = runs.iter().collect();
    let headline = levels.iter().copied().max().unwrap_or(1024);
    let mut s = Map::new();
    let mut put = |k: &str, v: Value| {
        s.insert(k.to_string(), v);
    };
    for &level in levels {
        let prefix = if level == headline {
            String::new()
        } else {
            format!("level{level}_")
        };
        for (name, kind) in [
            ("ceiling", Kind::Ceiling),
            ("free", Kind::Best),
            ("free_same_index", Kind::Same),
        ] {
            let m = means(&all, level, kind, None);
            put(&format!("{prefix}{name}_psnr_db"), number(m.worst_psnr()));
            put(&format!("{prefix}{name}_ssim"), number(m.worst_ssim()));
            put(&format!("{prefix}{name}_iou"), number(m.iou));
            put(&format!("{prefix}{name}_halo"), number(m.halo));
            put(&format!("{prefix}{name}_holes"), number(m.holes));
            for (b, (bg, _)) in BACKGROUNDS.iter().enumerate() {
                put(
                    &format!("{prefix}{name}_psnr_db_{bg}"),
                    number(m.psnr_db[b]),
                );
                put(&format!("{prefix}{name}_ssim_{bg}"), number(m.ssim[b]));
            }
            let face = if kind == Kind::Ceiling {
                format!("{prefix}ceiling_face_psnr_db")
            } else if kind == Kind::Best {
                format!("{prefix}face_psnr_db")
            } else {
                format!("{prefix}face_same_index_psnr_db")
            };
            put(&face, number(m.worst_face()));
            put(
                &format!("{face}_hands"),
                number(Means::worst(m.hands_psnr_db)),
            );
            let per_seed: Vec<Means> = runs
                .iter()
                .map(|r| means(&[r], level, kind, None))
                .collect();
            let worst =
                |f: &dyn Fn(&Means) -> f64| per_seed.iter().map(f).fold(f64::INFINITY, f64::min);
            put(
                &format!("{prefix}{name}_psnr_db_worst_seed"),
                number(worst(&Means::worst_psnr)),
            );
            put(
                &format!("{prefix}{name}_ssim_worst_seed"),
                number(worst(&Means::worst_ssim)),
            );
            put(
                &format!("{prefix}{name}_iou_worst_seed"),
                number(worst(&|m| m.iou)),
            );
        }
    }
    let (mut facing, mut roots) = (Vec::new(), Vec::new());
    let mut facing_worst_seed = 0.0f64;
    for r in runs {
        let (f, d) = following(&r.run);
        facing_worst_seed = facing_worst_seed.max(median(f.clone()));
        facing.extend(f);
        roots.extend(d);
    }
    put("facing_error_deg", number(median(facing)));
    put("facing_error_deg_worst_seed", number(facing_worst_seed));
    put(
        "root_path_error_m",
        number(roots.iter().sum::<f64>() / roots.len().max(1) as f64),
    );
    let m = motion_numbers(&all);
    let (lo, hi) = min_max(&m.turns);
    put("turn_ratio_min", lo);
    put("turn_ratio_max", hi);
    let (lo, hi) = min_max(&m.slides);
    put("slide_ratio_min", lo);
    put("slide_ratio_max", hi);
    let (lo, hi) = min_max(&m.stops);
    put("stop_ratio_min", lo);
    put("stop_ratio_max", hi);
    put("turns", json!(m.turns.len()));
    put("stops", json!(m.stops.len()));
    // A turn or stop that never completes is an infinite ratio, which JSON cannot hold:
    // the max is then null and these counts say why.
    let never = |v: &[f64]| v.iter().filter(|r| r.is_infinite()).count();
    put("turns_never_completed", json!(never(&m.turns)));
    put("stops_never_completed", json!(never(&m.stops)));
    put("idle_creep_m", m.creep_m.map_or(Value::Null, number));
    put(
        "teacher_idle_creep_m",
        m.teacher_creep_m.map_or(Value::Null, number),
    );
    put(
        "speed_error_pct",
        m.speed_error_pct.map_or(Value::Null, number),
    );
    // A measure, the teacher's (`teacher_` before its key) and their ratio.
    let mut against_teacher = |key: &str, ratio_key: &str, (generated, teacher)| {
        let optional = |x: Option<f64>| x.map_or(Value::Null, number);
        put(key, optional(generated));
        put(&format!("teacher_{key}"), optional(teacher));
        put(ratio_key, optional(motion::ratio(generated, teacher)));
    };
    against_teacher("foot_slip_mm", "foot_slip_ratio", foot_slip_mm(runs));
    let flicker: Vec<(f64, f64)> = runs.iter().flat_map(|r| r.run.flicker.clone()).collect();
    let mean = |f: &dyn Fn(&(f64, f64)) -> f64| {
        (!flicker.is_empty()).then(|| flicker.iter().map(f).sum::<f64>() / flicker.len() as f64)
    };
    against_teacher(
        "flicker_change",
        "flicker_ratio",
        (mean(&|f| f.0), mean(&|f| f.1)),
    );
    // Swings where the teacher's loose parts move at least 1 mm.
    let moving = || {
        runs.iter()
            .flat_map(|r| &r.motion.swings)
            .filter(|s| s.teacher_m >= 1e-3)
    };
    let swings: Vec<f64> = moving()
        .map(|s| (s.generated_m / s.teacher_m) as f64)
        .collect();
    let (lo, hi) = min_max(&swings);
    put("swing_ratio_min", lo);
    put("swing_ratio_max", hi);
    put("swings", json!(swings.len()));
    // How fast they die down, where the teacher's takes at least a frame (no target).
    let settles: Vec<f64> = moving()
        .filter(|s| s.teacher_settle > 0)
        .map(|s| s.generated_settle as f64 / s.teacher_settle as f64)
        .collect();
    let (lo, hi) = min_max(&settles);
    put("swing_settle_ratio_min", lo);
    put("swing_settle_ratio_max", hi);
    put("seeds", json!(runs.len()));
    put(
        "frames",
        json!(
            runs.iter()
                .map(|r| r.run.engine_roots.len() - 1)
                .sum::<usize>()
        ),
    );
    for &level in levels {
        let count = |r: &SeedRun| r.run.scores.iter().filter(|f| f.level == level).count();
        put(
            &format!("scored_frames_level{level}"),
            json!(runs.iter().map(count).sum::<usize>()),
        );
    }
    put("script_seed", json!(script_seed));
    put("headline_level", json!(headline));
    put(
        "figure_fill",
        number(runs.iter().map(|r| r.run.fill as f64).fold(1.0, f64::min)),
    );
    s
}

/// The targets of docs/eval: (summary key, at least or at most, value).
pub const TARGETS: &[(&str, &str, f64)] = &[
    ("ceiling_psnr_db", ">=", 26.0),
    ("ceiling_ssim", ">=", 0.92),
    ("ceiling_iou", ">=", 0.95),
    ("free_psnr_db", ">=", 22.0),
    ("free_ssim", ">=", 0.86),
    ("free_iou", ">=", 0.90),
    ("face_psnr_db", ">=", 20.0),
    ("facing_error_deg", "<=", 10.0),
    ("turn_ratio_min", ">=", motion::TURN_RATIO.0),
    ("turn_ratio_max", "<=", motion::TURN_RATIO.1),
    ("slide_ratio_min", ">=", motion::SLIDE_RATIO.0),
    ("slide_ratio_max", "<=", motion::SLIDE_RATIO.1),
    ("stop_ratio_min", ">=", motion::STOP_RATIO.0),
    ("stop_ratio_max", "<=", motion::STOP_RATIO.1),
    ("idle_creep_m", "<=", motion::IDLE_CREEP_M),
    ("speed_error_pct", "<=", motion::SPEED_ERROR_PCT),
    ("foot_slip_ratio", "<=", motion::FOOT_SLIP_RATIO),
    ("flicker_ratio", "<=", FLICKER_RATIO),
    ("swing_ratio_min", ">=", motion::SWING_RATIO.0),
    ("swing_ratio_max", "<=", motion::SWING_RATIO.1),
];

/// The generated frames' frame-to-frame image change against the teacher's (issue #48:
/// within 1.5×).
pub const FLICKER_RATIO: f64 = 1.5;

/// The mean slip (mm a frame) of every foot over every seed while planted, the
/// generated's and the teacher's; None where no foot was planted twice in a row.
fn foot_slip_mm(runs: &[SeedRun]) -> (Option<f64>, Option<f64>) {
    let mean = |side: &dyn Fn(&SeedRun) -> &Vec<Vec<motion::FootSample>>| {
        let (mut total, mut steps) = (0.0, 0);
        for r in runs {
            let frames = side(r);
            for foot in 0..frames.first().map_or(0, Vec::len) {
                let samples: Vec<motion::FootSample> =
                    frames.iter().filter_map(|f| f.get(foot).copied()).collect();
                let (t, n) = motion::foot_slip(&samples);
                total += t;
                steps += n;
            }
        }
        (steps > 0).then(|| 1e3 * total / steps as f64)
    };
    (
        mean(&|r| &r.run.engine_feet),
        mean(&|r| &r.run.teacher_feet),
    )
}

/// Whether a summary value meets its target; None when it was not measured.
pub fn meets(summary: &Map<String, Value>, key: &str, op: &str, target: f64) -> Option<bool> {
    let v = summary.get(key)?.as_f64()?;
    Some(if op == ">=" { v >= target } else { v <= target })
}

/// report.md: the targets, then every level, kind and background, the views, and each
/// seed's script, turns and stops.
pub fn markdown(runs: &[SeedRun], levels: &[usize], summary: &Map<String, Value>) -> String {
    let mut out = String::new();
    let all: Vec<&SeedRun> = runs.iter().collect();
    let f = |k: &str| {
        summary
            .get(k)
            .and_then(Value::as_f64)
            .map_or("not measured".to_string(), |v| {
                if v.fract() == 0.0 {
                    format!("{v:.0}")
                } else {
                    format!("{v:.3}")
                }
            })
    };
    let _ = writeln!(out, "# Strict evaluation\n");
    let _ = writeln!(
        out,
        "{} seeds, {} frames; scripts drawn from --script-seed {}. Scored frames per splat \
         level: {}. The engine's splats are drawn by the WGSL rasterizer against the teacher's \
         mesh and scored over the union of both foreground masks; the headline is the worst of \
         the white, grey and black backgrounds, at level {}.\n",
        f("seeds"),
        f("frames"),
        f("script_seed"),
        levels
            .iter()
            .map(|l| format!("{l}: {}", f(&format!("scored_frames_level{l}"))))
            .collect::<Vec<_>>()
            .join(", "),
        f("headline_level"),
    );
    let _ = writeln!(
        out,
        "## Targets\n\n| key | target | value | |\n|---|---|---|---|"
    );
    for &(key, op, target) in TARGETS {
        let never = match key {
            "turn_ratio_max" => "turns_never_completed",
            "stop_ratio_max" => "stops_never_completed",
            _ => "",
        };
        let infinite = summary.get(never).and_then(Value::as_u64).unwrap_or(0);
        let (value, mark) = match meets(summary, key, op, target) {
            _ if infinite > 0 => (format!("∞ ({infinite} never completed)"), "✗"),
            Some(true) => (f(key), "✓"),
            Some(false) => (f(key), "✗"),
            None => (f(key), "not measured"),
        };
        let _ = writeln!(out, "| {key} | {op} {target} | {value} | {mark} |");
    }
    let _ = writeln!(
        out,
        "\n## Pixels by level, comparison and background\n\n| level | comparison | PSNR white | grey | black | SSIM white | grey | black | IoU | halo | holes | face PSNR (worst bg) | hands PSNR (worst bg) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for &level in levels {
        for (name, kind) in [
            ("ceiling (teacher geometry)", Kind::Ceiling),
            ("free, best in window", Kind::Best),
            ("free, same index", Kind::Same),
        ] {
            let m = means(&all, level, kind, None);
            let _ = writeln!(
                out,
                "| {level} | {name} | {:.2} | {:.2} | {:.2} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} | {:.2} |",
                m.psnr_db[0],
                m.psnr_db[1],
                m.psnr_db[2],
                m.ssim[0],
                m.ssim[1],
                m.ssim[2],
                m.iou,
                m.halo,
                m.holes,
                m.worst_face(),
                Means::worst(m.hands_psnr_db),
            );
        }
    }
    let headline = levels.iter().copied().max().unwrap_or(1024);
    let _ = writeln!(
        out,
        "\n## Views (level {headline}, best in window; ceiling beside)\n\n| view | PSNR (worst bg) | SSIM (worst bg) | IoU | ceiling PSNR | ceiling IoU |\n|---|---|---|---|---|---|"
    );
    for (v, view) in VIEWS.iter().enumerate() {
        let m = means(&all, headline, Kind::Best, Some(v));
        let c = means(&all, headline, Kind::Ceiling, Some(v));
        let _ = writeln!(
            out,
            "| {} | {:.2} | {:.3} | {:.3} | {:.2} | {:.3} |",
            view.name,
            m.worst_psnr(),
            m.worst_ssim(),
            m.iou,
            c.worst_psnr(),
            c.iou
        );
    }
    let _ = writeln!(out, "\n## Seeds\n");
    for r in runs {
        let (level, m) = seed_pixels(r, levels);
        let (facing, roots) = following(&r.run);
        let _ = writeln!(
            out,
            "### Seed {}\n\nScript `{}`. Free PSNR {:.2} dB, SSIM {:.3}, IoU {:.3} (worst bg, level {}); facing error median {:.1}°, root distance mean {:.3} m. Seconds: teacher {:.0}, engine {:.0}, appearance {:.0}, drawing {:.0}, scoring {:.0}.\n",
            r.seed,
            r.script,
            m.worst_psnr(),
            m.worst_ssim(),
            m.iou,
            level.map_or("none scored".to_string(), |l| l.to_string()),
            median(facing),
            roots.iter().sum::<f64>() / roots.len().max(1) as f64,
            r.run.seconds[0],
            r.run.seconds[1],
            r.run.seconds[2],
            r.run.seconds[3],
            r.run.seconds[4],
        );
        let show = |x: Option<usize>| x.map_or("never".to_string(), |x| x.to_string());
        let turns = r.motion.turns.iter().map(|t| {
            vec![
                t.label.clone(),
                t.frame.to_string(),
                show(t.generated),
                show(t.teacher),
            ]
        });
        table(&mut out, &["turn", "frame", "frames", "teacher"], turns);
        let stops = r.motion.stops.iter().map(|s| {
            vec![
                s.after.letter().to_string(),
                s.release.to_string(),
                show(s.frames),
                show(s.teacher_frames),
                format!("{:.3}", s.slide_m),
                format!("{:.3}", s.teacher_slide_m),
            ]
        });
        let _ = writeln!(out);
        let head = [
            "stop after",
            "release",
            "frames",
            "teacher",
            "slide m",
            "teacher",
        ];
        table(&mut out, &head, stops);
        let speeds = r.motion.speeds.iter().map(|s| {
            let (speed, teacher) = (format!("{:.3}", s.speed), format!("{:.3}", s.teacher_speed));
            vec![
                s.key.letter().to_string(),
                s.start.to_string(),
                speed,
                teacher,
            ]
        });
        let _ = writeln!(out);
        table(&mut out, &["key", "from", "speed m/s", "teacher"], speeds);
        let swings = r.motion.swings.iter().map(|s| {
            vec![
                s.label.clone(),
                s.frame.to_string(),
                format!("{:.1}", s.generated_m * 1e3),
                format!("{:.1}", s.teacher_m * 1e3),
                s.generated_settle.to_string(),
                s.teacher_settle.to_string(),
            ]
        });
        let _ = writeln!(out);
        let head = [
            "swing after",
            "frame",
            "mm",
            "teacher",
            "settled after (frames)",
            "teacher",
        ];
        table(&mut out, &head, swings);
        for c in &r.motion.creep {
            let _ = writeln!(
                out,
                "\nIdle creep over the {} frames from {}: {:.4} m (teacher {:.4}).",
                motion::CREEP_FRAMES,
                c.from,
                c.creep_m,
                c.teacher_creep_m
            );
        }
        let _ = writeln!(out);
    }
    out
}

/// A Markdown table: the header's cells, the separator, then each row's cells.
fn table(out: &mut String, header: &[&str], rows: impl Iterator<Item = Vec<String>>) {
    let _ = writeln!(out, "| {} |", header.join(" | "));
    let _ = writeln!(out, "|{}", "---|".repeat(header.len()));
    for row in rows {
        let _ = writeln!(out, "| {} |", row.join(" | "));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::Action;
    use crate::eval::lockstep::FrameScore;
    use crate::eval::motion::{StopCompare, TurnCompare};
    use crate::eval::pixels::Silhouette;
    use glam::Vec3;

    fn foot(x: f32) -> Vec<crate::eval::motion::FootSample> {
        vec![crate::eval::motion::FootSample {
            centre: Vec3::new(x, 0.0, 0.0),
            lift: 0.0,
        }]
    }

    fn view(view: usize, psnr: [f64; 3], iou: f64) -> ViewScore {
        ViewScore {
            view,
            psnr_db: psnr,
            ssim: [0.9, 0.8, 0.95],
            silhouette: Silhouette {
                iou,
                halo: 0.1,
                holes: 0.2,
            },
            face_psnr_db: (view == 0).then_some([30.0, 20.0, f64::INFINITY]),
            hands_psnr_db: None,
        }
    }

    #[test]
    fn the_summary_takes_the_worst_background_and_the_two_sided_ratios() {
        let frame = |index, psnr| FrameScore {
            index,
            level: 1024,
            best_index: index,
            best: vec![view(0, psnr, 0.8), view(1, [20.0, 22.0, 24.0], 0.9)],
            same: vec![view(0, [10.0, 10.0, 10.0], 0.5)],
            ceiling: vec![view(0, [30.0, 30.0, 30.0], 1.0)],
        };
        let run = LockstepRun {
            teacher_roots: vec![Vec3::ZERO; 3],
            engine_roots: vec![Vec3::ZERO, Vec3::X, Vec3::Z * 3.0],
            teacher_facing: vec![0.0, 10.0, 170.0],
            engine_facing: vec![0.0, 14.0, -170.0],
            scores: vec![frame(1, [18.0, 26.0, 30.0]), frame(2, [22.0, 26.0, 30.0])],
            fill: 0.7,
            seconds: [0.0; 5],
            sheet: None,
            // One foot, planted throughout: the teacher's slides 1 mm a frame, the
            // generated one 2.
            teacher_feet: [0.0, 0.001, 0.002].map(foot).to_vec(),
            engine_feet: [0.0, 0.002, 0.004].map(foot).to_vec(),
            // Changes 0.1 and 0.3 against the teacher's 0.1 twice: ratio 2.
            flicker: vec![(0.1, 0.1), (0.3, 0.1)],
            // Swings are compared in MotionCompare below.
            teacher_swing: Vec::new(),
            engine_swing: Vec::new(),
        };
        let motion = MotionCompare {
            turns: vec![TurnCompare {
                label: "W→A (90°)".into(),
                frame: 1,
                generated: Some(2),
                teacher: Some(4),
            }],
            stops: vec![StopCompare {
                after: Action::Forward,
                release: 1,
                frames: None,
                teacher_frames: Some(9),
                slide_m: 0.1,
                teacher_slide_m: 0.4,
            }],
            speeds: vec![],
            creep: vec![],
            // Half the teacher's swing; a teacher swing under 1 mm is left out.
            // Settling in 12 frames against the teacher's 8; the small one left out.
            swings: [(0.05, 0.1, 12), (0.01, 0.0005, 30)]
                .map(|(generated_m, teacher_m, generated_settle)| {
                    crate::eval::motion::SwingCompare {
                        label: "W→I".into(),
                        frame: 1,
                        generated_m,
                        teacher_m,
                        generated_settle,
                        teacher_settle: 8,
                    }
                })
                .to_vec(),
        };
        let runs = [SeedRun {
            seed: 7,
            script: "2W".into(),
            run,
            motion,
        }];
        let s = summary(&runs, &[1024], 5);
        let get = |k: &str| s[k].as_f64().unwrap_or(f64::NAN);
        // White: views 0 (18, 22) and 1 (20, 20) → 20; grey 24, black 27 → worst 20.
        assert_eq!(get("free_psnr_db"), 20.0);
        assert_eq!(get("free_psnr_db_black"), 27.0);
        assert_eq!(get("free_ssim"), 0.8);
        assert!((get("free_iou") - 0.85).abs() < 1e-12);
        assert_eq!(get("ceiling_psnr_db"), 30.0);
        // Faces: white 30, grey 20, black capped at 100.
        assert_eq!(get("face_psnr_db"), 20.0);
        // Facing errors 4° and 20° (wrapped): the median of two is the larger.
        assert_eq!(get("facing_error_deg"), 20.0);
        assert_eq!(get("root_path_error_m"), 2.0);
        assert_eq!((get("turn_ratio_min"), get("turn_ratio_max")), (0.5, 0.5));
        assert_eq!(get("slide_ratio_min"), 0.25);
        // A stop that never comes is an infinite ratio, which JSON holds as null.
        assert!(s["stop_ratio_max"].is_null());
        assert_eq!(s["stops_never_completed"], json!(1));
        assert!(
            markdown(&runs, &[1024], &s)
                .contains("| stop_ratio_max | <= 1.25 | ∞ (1 never completed) | ✗ |")
        );
        // A seed's line names its pixels' level: the finest one with scored frames.
        assert!(
            markdown(&runs, &[1024], &s)
                .contains("Free PSNR 20.00 dB, SSIM 0.800, IoU 0.850 (worst bg, level 1024)")
        );
        assert_eq!(seed_pixels(&runs[0], &[2048, 1024]).0, Some(1024));
        assert!(s["idle_creep_m"].is_null());
        assert_eq!((get("swing_ratio_min"), get("swing_ratio_max")), (0.5, 0.5));
        assert_eq!(s["swings"], json!(1));
        assert_eq!(get("swing_settle_ratio_min"), 1.5);
        assert_eq!(get("swing_settle_ratio_max"), 1.5);
        assert!((get("flicker_ratio") - 2.0).abs() < 1e-9);
        assert_eq!(meets(&s, "flicker_ratio", "<=", 1.5), Some(false));
        assert!((get("foot_slip_mm") - 2.0).abs() < 1e-6);
        assert!((get("teacher_foot_slip_mm") - 1.0).abs() < 1e-6);
        assert!((get("foot_slip_ratio") - 2.0).abs() < 1e-6);
        assert_eq!(meets(&s, "foot_slip_ratio", "<=", 1.5), Some(false));
        assert_eq!(meets(&s, "free_psnr_db", ">=", 22.0), Some(false));
        assert_eq!(meets(&s, "turn_ratio_min", ">=", 0.75), Some(false));
        assert_eq!(meets(&s, "swing_ratio_min", ">=", 0.7), Some(false));
    }
}
