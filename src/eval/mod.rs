//! The strict evaluation (`unica eval`, docs/eval): the teacher and the engine driven
//! in lockstep on the same key scripts, drawn by the shipped splat path from the same
//! cameras, and scored on foreground pixels over several backgrounds, with two-sided
//! motion tolerances.

mod decibels;
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
    /// Reuse the seeds a former run into the same `out` finished with the same bundle
    /// and options (`OUT/seeds/seedN.json`).
    pub resume: bool,
}

/// Runs every seed's script in lockstep and writes summary.json, report.md and
/// results.json to `out`; returns the summary.
pub fn strict(
    gpu: &GpuContext,
    options: &StrictOptions,
    progress: &dyn Fn(&str, u64, u64),
) -> anyhow::Result<Map<String, Value>> {
    std::fs::create_dir_all(&options.out).with_context(|| options.out.display().to_string())?;
    // Made first, so that an OUT where it cannot be made fails before hours of work.
    let seeds_folder = options.out.join("seeds");
    std::fs::create_dir_all(&seeds_folder).with_context(|| seeds_folder.display().to_string())?;
    let inputs = inputs_key(gpu, options)?;
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
        let lockstep_options = lockstep::LockstepOptions {
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
        };
        let saved = seeds_folder.join(format!("seed{seed}.json"));
        let key = seed_key(&inputs, &lockstep_options, &script);
        let resumed = if options.resume {
            load_seed(&saved, &key)
        } else {
            None
        };
        let run = match resumed {
            Some(run) => {
                progress(&format!("{what} resumed from {}", saved.display()), 1, 1);
                run
            }
            None => {
                let run = lockstep::run(gpu, &lockstep_options, &|stage, done, total| {
                    progress(&format!("{what} {stage}"), done, total)
                })?;
                if let Some(sheet) = &run.sheet {
                    crate::files::write_png_atomic(
                        &options.out.join(format!("sheet_seed{seed}.png")),
                        sheet,
                    )?;
                }
                if let Err(e) = save_seed(&saved, &key, &run) {
                    // The run goes on: only a later --resume loses this seed.
                    eprintln!("unica eval: {}: not saved ({e:#})", saved.display());
                }
                run
            }
        };
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

/// Bump when what a saved seed holds, or how the lockstep run computes it, changes.
const SEED_FORMAT: u32 = 2;

/// What every saved seed of this run must match to be reused: this program's version and
/// seed format, the adapter, and FNV-1a hashes of the files the run reads (the bundle's
/// manifest and weights, the teacher's character file, the description beside it and
/// its clips; a glTF's external buffers and images are not hashed).
fn inputs_key(gpu: &GpuContext, options: &StrictOptions) -> anyhow::Result<Value> {
    let mut files = vec![
        options.bundle.join("manifest.json"),
        options.bundle.join("weights.safetensors"),
        options.character.clone(),
    ];
    let description = options.character.with_extension("avatar.json");
    if description.is_file() {
        files.push(description);
    }
    files.extend(options.clips.iter().cloned());
    let mut hashes = Map::new();
    for path in files {
        let bytes = std::fs::read(&path).with_context(|| path.display().to_string())?;
        hashes.insert(
            path.display().to_string(),
            json!(format!("{:016x}", fnv1a(&bytes))),
        );
    }
    Ok(json!({
        "version": env!("CARGO_PKG_VERSION"),
        "seed_format": SEED_FORMAT,
        "adapter": gpu.adapter_label(),
        "files": hashes,
    }))
}

/// The key of one seed: the run's inputs (`inputs_key`), the seed's options and script.
fn seed_key(inputs: &Value, lockstep: &lockstep::LockstepOptions, script: &str) -> Value {
    json!({
        "inputs": inputs,
        "bundle": lockstep.bundle.display().to_string(),
        "seed": lockstep.seed,
        "script": script,
        "size": lockstep.size,
        "score_every": lockstep.score_every,
        "fine_every": lockstep.fine_every,
        "window": lockstep.window,
        "window_step": lockstep.window_step,
        "engine_level": lockstep.engine_level,
        "levels": lockstep.levels,
    })
}

/// 64-bit FNV-1a.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |hash, &b| {
        (hash ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Writes the seed's run under `key` to `path` (its folder made by `strict`).
fn save_seed(
    path: &std::path::Path,
    key: &Value,
    run: &lockstep::LockstepRun,
) -> anyhow::Result<()> {
    write_atomic(
        path,
        serde_json::to_string(
            &json!({ "key": key, "run": floats_as_text(serde_json::to_value(run)?) }),
        )?
        .as_bytes(),
    )?;
    Ok(())
}

/// `value` with `leaf` applied to every value that is not an array or an object.
fn map_leaves(value: Value, leaf: &dyn Fn(Value) -> Value) -> Value {
    match value {
        Value::Array(items) => {
            Value::Array(items.into_iter().map(|v| map_leaves(v, leaf)).collect())
        }
        Value::Object(map) => Value::Object(
            map.into_iter()
                .map(|(k, v)| (k, map_leaves(v, leaf)))
                .collect(),
        ),
        other => leaf(other),
    }
}

/// `value` with every fractional number written as its shortest exact text: serde_json's
/// own float parser (without its `float_roundtrip` feature, which would change how every
/// JSON file of the program is read) reads some values back 1 ulp off, and a resumed
/// summary then differed in its last digits; Rust's `str::parse` is exact.
fn floats_as_text(value: Value) -> Value {
    map_leaves(value, &|leaf| match leaf.as_f64() {
        Some(v) if leaf.is_f64() => Value::String(v.to_string()),
        _ => leaf,
    })
}

/// The inverse of [`floats_as_text`]: every text that reads as a finite number becomes
/// that number again (the run holds no other text but the decibels' "inf").
fn floats_from_text(value: Value) -> Value {
    map_leaves(value, &|leaf| match leaf
        .as_str()
        .and_then(|t| t.parse::<f64>().ok())
        .and_then(serde_json::Number::from_f64)
    {
        Some(n) => Value::Number(n),
        None => leaf,
    })
}

/// The saved run at `path` if its key is `key`; None (and a line saying why, unless the
/// file is absent) when it cannot be reused.
fn load_seed(path: &std::path::Path, key: &Value) -> Option<lockstep::LockstepRun> {
    let reason = match std::fs::read_to_string(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => e.to_string(),
        Ok(text) => match serde_json::from_str::<Value>(&text) {
            Err(e) => format!("not a saved seed ({e})"),
            Ok(saved) if saved.get("key") != Some(key) => {
                "saved with another bundle or other options".to_string()
            }
            Ok(saved) => match serde_json::from_value(floats_from_text(saved["run"].clone())) {
                Ok(run) => return Some(run),
                Err(e) => format!("unreadable run ({e})"),
            },
        },
    };
    eprintln!(
        "unica eval: {}: {reason}; running that seed again",
        path.display()
    );
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::lockstep::{FrameScore, LockstepRun, ViewScore};
    use crate::eval::motion::FootSample;
    use crate::eval::pixels::Silhouette;
    use glam::Vec3;

    fn run() -> LockstepRun {
        let view = ViewScore {
            view: 2,
            // Values that a fast, inexact float parser reads back 1 ulp off.
            psnr_db: [9.207795473019093, 21.5, f64::INFINITY],
            ssim: [0.4496710175205879, 0.625, 0.75],
            silhouette: Silhouette {
                iou: 0.9,
                halo: 0.01,
                holes: 0.02,
            },
            face_psnr_db: Some([15.1, f64::INFINITY, 16.3]),
            hands_psnr_db: None,
        };
        LockstepRun {
            teacher_roots: vec![Vec3::new(0.1, 1.0, -0.3); 2],
            engine_roots: vec![Vec3::new(1.0 / 3.0, 0.9, 0.2); 2],
            teacher_facing: vec![0.0, 1.0 / 7.0],
            engine_facing: vec![-3.5, 2.25],
            teacher_feet: vec![vec![FootSample {
                centre: Vec3::new(0.2, 0.0, 0.1),
                lift: 0.01,
            }]],
            engine_feet: vec![Vec::new()],
            flicker: vec![(0.1, 0.2)],
            teacher_swing: vec![Vec3::Y],
            engine_swing: vec![Vec3::NEG_Y],
            scores: vec![FrameScore {
                index: 30,
                level: 256,
                best_index: 28,
                best: vec![view.clone()],
                same: vec![view.clone()],
                ceiling: vec![view],
            }],
            fill: 0.61,
            seconds: [1.0, 2.0, 3.0, 4.0, 5.0],
            sheet: None,
        }
    }

    #[test]
    fn a_saved_seed_reads_back_exactly_and_only_under_its_own_key() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("seed7.json");
        let key = json!({"seed": 7, "script": "40W 60I"});
        let saved = run();
        save_seed(&path, &key, &saved).unwrap();
        let back = load_seed(&path, &key).expect("the same key reads it back");
        // Lossless, infinities included: both serialise alike (fails with serde_json's
        // own float parser), and the infinite PSNRs are infinite again.
        assert_eq!(
            serde_json::to_string(&back).unwrap(),
            serde_json::to_string(&saved).unwrap()
        );
        assert_eq!(back.scores[0].best[0].psnr_db[2], f64::INFINITY);
        assert_eq!(
            back.scores[0].ceiling[0].face_psnr_db.unwrap()[1],
            f64::INFINITY
        );
        assert_eq!(back.engine_roots[0], Vec3::new(1.0 / 3.0, 0.9, 0.2));
        // Another bundle or options: run again.
        assert!(load_seed(&path, &json!({"seed": 7, "script": "40W 61I"})).is_none());
        // A file cut short by an interruption: run again.
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::write(&path, &text[..text.len() / 2]).unwrap();
        assert!(load_seed(&path, &key).is_none());
        assert!(load_seed(&dir.path().join("absent.json"), &key).is_none());
    }

    #[test]
    fn fnv1a_matches_its_published_values() {
        // The FNV-1a 64-bit test vectors: "" and "a".
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    }
}
