//! The strict evaluation (`unica eval`, docs/eval): the teacher and the engine driven
//! in lockstep on the same key scripts, drawn by the shipped splat path from the same
//! cameras, and scored on foreground pixels over several backgrounds, with two-sided
//! motion tolerances.

pub mod lockstep;
pub mod motion;
pub mod pixels;
pub mod report;
pub mod scripts;

use std::path::PathBuf;

use anyhow::Context;
use serde_json::{Map, Value, json};

use crate::files::write_atomic;
use crate::gpu::GpuContext;

/// What the strict evaluation runs.
pub struct StrictOptions {
    pub bundle: PathBuf,
    pub character: PathBuf,
    pub clips: Vec<PathBuf>,
    pub out: PathBuf,
    /// Engine seeds, one script each.
    pub seeds: u32,
    pub script_seed: u64,
    /// Frames of random keys per script, before its final idle.
    pub script_frames: usize,
    /// The final idle of the first script (long enough to measure idle creep) and of the
    /// others.
    pub first_idle: usize,
    pub idle: usize,
    pub size: u32,
    pub score_every: usize,
    /// Levels other than the engine's are scored every this many frames.
    pub fine_every: usize,
    pub window: usize,
    pub window_step: usize,
    /// The engine's own splat level (the adapter's default), and every level scored.
    pub engine_level: usize,
    pub levels: Vec<usize>,
}

/// Runs every seed's script in lockstep and writes summary.json, report.md and
/// results.json to `out`; returns the summary.
pub fn strict(
    gpu: &GpuContext,
    options: &StrictOptions,
    progress: &dyn Fn(&str, u64, u64),
) -> anyhow::Result<Map<String, Value>> {
    std::fs::create_dir_all(&options.out).with_context(|| options.out.display().to_string())?;
    let mut runs = Vec::new();
    for k in 0..options.seeds as u64 {
        let idle = if k == 0 {
            options.first_idle
        } else {
            options.idle
        };
        let (script, keys) = scripts::script(options.script_seed, k, options.script_frames, idle);
        let seed = options.script_seed + k;
        let what = format!("seed {seed} ({}/{})", k + 1, options.seeds);
        let run = lockstep::run(
            gpu,
            &lockstep::LockstepOptions {
                bundle: options.bundle.clone(),
                character: options.character.clone(),
                clips: options.clips.clone(),
                seed,
                keys: keys.clone(),
                size: options.size,
                score_every: options.score_every,
                fine_every: options.fine_every,
                window: options.window,
                window_step: options.window_step,
                engine_level: options.engine_level,
                levels: options.levels.clone(),
            },
            &|stage, done, total| progress(&format!("{what} {stage}"), done, total),
        )?;
        if let Some(sheet) = &run.sheet {
            crate::files::write_png_atomic(
                &options.out.join(format!("sheet_seed{seed}.png")),
                sheet,
            )?;
        }
        let actions: Vec<_> = (0..keys.len()).map(|i| keys.action_at(i)).collect();
        let mut motion = motion::compare(&run.engine_roots, &run.teacher_roots, &actions);
        motion.swings = motion::swings(&run.engine_swing, &run.teacher_swing, &actions);
        runs.push(report::SeedRun {
            seed,
            script,
            run,
            motion,
        });
    }
    let summary = report::summary(&runs, &options.levels, options.script_seed);
    let results: Vec<Value> = runs
        .iter()
        .map(|r| {
            json!({
                "seed": r.seed,
                "script": r.script,
                "motion": r.motion,
                "teacher_roots": r.run.teacher_roots.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
                "engine_roots": r.run.engine_roots.iter().map(|p| p.to_array()).collect::<Vec<_>>(),
                "teacher_facing_deg": r.run.teacher_facing,
                "engine_facing_deg": r.run.engine_facing,
                "teacher_feet": r.run.teacher_feet,
                "engine_feet": r.run.engine_feet,
                "flicker": r.run.flicker,
                "scores": r.run.scores,
            })
        })
        .collect();
    write_atomic(
        &options.out.join("results.json"),
        serde_json::to_string(&json!({
            "views": lockstep::VIEWS.iter().map(|v| v.name).collect::<Vec<_>>(),
            "backgrounds": pixels::BACKGROUNDS.iter().map(|b| b.0).collect::<Vec<_>>(),
            "runs": results,
        }))?
        .as_bytes(),
    )?;
    write_atomic(
        &options.out.join("report.md"),
        report::markdown(&runs, &options.levels, &summary).as_bytes(),
    )?;
    write_atomic(
        &options.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    Ok(summary)
}
