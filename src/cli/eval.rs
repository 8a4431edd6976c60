//! `unica eval`: the strict evaluation (src/eval), then the lenient one (the teacher and
//! the engine driven on fixed key scripts, then the trainer's evaluation).

use std::path::PathBuf;

use anyhow::{Context, bail};

use super::defaults::render_with_bar;
use crate::action::KeyScript;
use crate::gpu::{GpuContext, GpuOptions};

#[derive(clap::Args, Debug)]
pub(super) struct EvalArgs {
    /// The bundle to evaluate (e.g. assets/witch/bundle)
    #[arg(long, value_name = "DIR")]
    bundle: PathBuf,
    /// The dataset baked from the bundle's character: the strict evaluation reads its
    /// character and clips; the lenient one needs its renders (`unica bake
    /// --render-every 1`: each free-running frame is compared with the nearest rendered
    /// teacher pose, so with fewer renders it is measured against a farther one)
    #[arg(long, value_name = "DIR")]
    data: PathBuf,
    /// Output folder for report.md, results.json and the plots (created)
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// The teacher's character file [default: the one the dataset was baked from]
    #[arg(long, value_name = "FILE")]
    character: Option<PathBuf>,
    /// Animation libraries for the teacher's character [default: those the dataset was
    /// baked with]
    #[arg(long, value_name = "FILE", num_args = 1..)]
    clips: Vec<PathBuf>,
    /// A short script and fewer frames (a few minutes; CI)
    #[arg(long)]
    quick: bool,
    /// The key script the avatar and the teacher are driven on, e.g. "60W 60S 60A 60D 30I"
    /// [default: that one; with --quick "20W 20S 20A 20D 20I"]. Speeds are measured after
    /// the first 15 frames of each key where every movement key is held at least 40 frames, else
    /// after the first 5 (then they include most of each turn)
    #[arg(long, value_name = "SCRIPT")]
    keys: Option<String>,
    /// Seed of the sampler noise
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Frames of the long (drift) run [default: the key script 10 times; with --quick
    /// twice]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(100..))]
    long_frames: Option<u32>,
    /// Seeds of the PyTorch loop whose stop, speeds and turns the report gives beside the
    /// engine's run (summary.json's seeds_* keys are the worst of them) [default: 3; with
    /// --quick 2]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    motion_seeds: Option<u32>,
    /// The key script whose every movement key is released into Idle, run from each of
    /// --motion-seeds seeds for the stop after each direction [default: "40W 30I 40S 30I
    /// 40A 30I 40D 30I"; with --quick "20W 20I 20S 20I 20A 20I 20D 20I"]
    #[arg(long, value_name = "SCRIPT")]
    stops_keys: Option<String>,
    /// The key script whose turns are pressed at many phases of the stride (every key held
    /// a different number of frames), run from each of --motion-seeds seeds; summary.json's
    /// phase_turn180_frames and phase_turn90_frames are its slowest turns [default: "45W
    /// 40S 41W 42A 43W 44D 45S 46A 47D 48W 49S 30I"; with --quick "20W 21S 22A 23D 20I"]
    #[arg(long, value_name = "SCRIPT")]
    turns_keys: Option<String>,
    /// Engine seeds of the strict evaluation, each driven on its own random key script
    /// [default: 5; with --quick 2]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..100))]
    seeds: Option<u32>,
    /// Seed the strict evaluation's key scripts are drawn from: one that no training or
    /// tuning used
    #[arg(long, value_name = "N", default_value_t = crate::eval::scripts::SCRIPT_SEED)]
    script_seed: u64,
    /// Frames of random keys in each strict script, before its final idle (the first
    /// script idles 330 frames, to measure idle creep over 300; the others 60)
    /// [default: 280; with --quick 40]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(20..100_000))]
    script_frames: Option<u32>,
    /// Score every this many frames at the engine's own splat level [default: 10 on a
    /// GPU, 30 on a CPU driver; with --quick 20]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..1000))]
    score_every: Option<u32>,
    /// Score the other levels (1024 where the engine draws 256) every this many frames:
    /// a frame of 250k splats takes seconds to draw on a CPU driver [default: as
    /// --score-every on a GPU, 300 on a CPU driver; with --quick 120]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..10_000))]
    fine_every: Option<u32>,
    /// Each scored frame is compared with the teacher's frames this many either side of
    /// its index (half a stride: gait phase may differ)
    #[arg(long, value_name = "N", default_value_t = 15, value_parser = clap::value_parser!(u32).range(0..100))]
    window: u32,
    /// ... taking every this many of them [default: 1; with --quick 5]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..100))]
    window_step: Option<u32>,
    /// Image size of the strict views, in pixels (square) [default: 512; with --quick 128]
    #[arg(long, value_name = "PX", value_parser = clap::value_parser!(u32).range(64..=2048))]
    size: Option<u32>,
    /// Only the strict evaluation (no lenient one, whose keys are otherwise added to
    /// summary.json with a `lenient_` prefix)
    #[arg(long)]
    strict_only: bool,
    /// Go on with an interrupted run into the same OUT: every seed it finished (saved in
    /// OUT/seeds) with the same bundle files and options is read back, not run again
    #[arg(long)]
    resume: bool,
}

/// The evaluation's key script: every movement key, a 180° (W→S, A→D) and a 90° (S→A)
/// turn, and enough idle at the end to see the root come to rest.
const EVAL_KEYS: &str = "60W 60S 60A 60D 30I";

const EVAL_KEYS_QUICK: &str = "20W 20S 20A 20D 20I";

/// The stops scripts (`unica eval --stops-keys`): every movement key released into Idle;
/// the same as the trainer's `eval.STOPS_KEYS` and `STOPS_KEYS_QUICK`.
const EVAL_STOPS_KEYS: &str = "40W 30I 40S 30I 40A 30I 40D 30I";

const EVAL_STOPS_KEYS_QUICK: &str = "20W 20I 20S 20I 20A 20I 20D 20I";

/// The turns scripts (`unica eval --turns-keys`): turns pressed at many phases of the
/// stride; the same as the trainer's `eval.TURNS_KEYS` and `TURNS_KEYS_QUICK`.
const EVAL_TURNS_KEYS: &str = "45W 40S 41W 42A 43W 44D 45S 46A 47D 48W 49S 30I";

const EVAL_TURNS_KEYS_QUICK: &str = "20W 21S 22A 23D 20I";

/// The key script given, else the default (`quick`: the short one).
pub(super) fn eval_script<'a>(
    given: &'a Option<String>,
    quick: bool,
    full: &'a str,
    short: &'a str,
) -> &'a str {
    match (given, quick) {
        (Some(keys), _) => keys,
        (None, true) => short,
        (None, false) => full,
    }
}

/// The strict evaluation (src/eval) of the bundle against the dataset's teacher, then,
/// unless `--strict-only`, the lenient one in `OUT/lenient`, whose summary keys join
/// summary.json with a `lenient_` prefix.
pub(super) fn eval(args: EvalArgs, gpu: &GpuOptions) -> anyhow::Result<()> {
    let manifest_path = args.data.join("manifest.json");
    let manifest: crate::dataset::DatasetManifest = serde_json::from_slice(
        &std::fs::read(&manifest_path).with_context(|| manifest_path.display().to_string())?,
    )
    .with_context(|| format!("{}: not a dataset manifest", manifest_path.display()))?;
    let character = args
        .character
        .clone()
        .unwrap_or_else(|| PathBuf::from(&manifest.character));
    if !character.is_file() {
        bail!(
            "{}: the dataset's character file is not there; give it with --character",
            character.display()
        );
    }
    std::fs::create_dir_all(&args.out).with_context(|| args.out.display().to_string())?;
    let clips: Vec<PathBuf> = if args.clips.is_empty() {
        manifest.clip_files.iter().map(PathBuf::from).collect()
    } else {
        args.clips.clone()
    };
    let context = GpuContext::headless(gpu)?;
    let engine_level = crate::engine::appearance::default_level(&context);
    let mut levels = vec![engine_level, 1024];
    levels.dedup();
    let quick = args.quick;
    let cpu = context.cpu_driver();
    let score_every = args.score_every.map_or(
        if quick {
            20
        } else if cpu {
            30
        } else {
            10
        },
        |n| n as usize,
    );
    let options = crate::eval::StrictOptions {
        bundle: args.bundle.clone(),
        character: character.clone(),
        clips: clips.clone(),
        out: args.out.clone(),
        seeds: args.seeds.unwrap_or(if quick { 2 } else { 5 }),
        script_seed: args.script_seed,
        script_frames: args.script_frames.unwrap_or(if quick { 40 } else { 280 }) as usize,
        first_idle: if quick { 40 } else { 330 },
        idle: if quick { 20 } else { 60 },
        size: args.size.unwrap_or(if quick { 128 } else { 512 }),
        score_every,
        fine_every: args.fine_every.map_or(
            if quick {
                120
            } else if cpu {
                300
            } else {
                score_every
            },
            |n| n as usize,
        ),
        window: args.window as usize,
        window_step: args.window_step.unwrap_or(if quick { 5 } else { 1 }) as usize,
        engine_level,
        levels,
        resume: args.resume,
    };
    let bar = super::progress::bar(
        "strict evaluation: {msg} {bar:30} {pos}/{len} frames, {left}",
        0,
    );
    // Each stage (a seed's teacher, engine, ...) counts its own frames: the bar starts
    // again with it, so its time left is that stage's.
    let stage = std::sync::Mutex::new(String::new());
    let summary = crate::eval::strict(&context, &options, &|what, done, total| {
        let mut last = stage.lock().unwrap_or_else(|e| e.into_inner());
        bar.set_message(what.to_string());
        bar.set_length(total);
        bar.set_position(done);
        if *last != what {
            // Not `reset()`, which draws at once with the old stage's message.
            bar.reset_elapsed();
            *last = what.to_string();
        }
    })?;
    bar.finish_and_clear();
    let summary = if args.strict_only {
        summary
    } else {
        let folder = args.out.join("lenient");
        lenient(&args, &character, &clips, &folder, gpu)?;
        with_lenient(&folder, summary)?
    };
    crate::files::write_atomic(
        &args.out.join("summary.json"),
        serde_json::to_string_pretty(&summary)?.as_bytes(),
    )?;
    eprintln!(
        "unica eval: {} (summary.json, report.md)",
        args.out.display()
    );
    Ok(())
}

/// The strict summary with the lenient evaluation's keys added under `lenient_`. Python
/// writes NaN and infinities as bare `NaN` / `Infinity`, which JSON has no words for: they
/// become null, as the strict summary writes them.
fn with_lenient(
    folder: &std::path::Path,
    mut summary: serde_json::Map<String, serde_json::Value>,
) -> anyhow::Result<serde_json::Map<String, serde_json::Value>> {
    let path = folder.join("summary.json");
    let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
    let lenient: serde_json::Map<String, serde_json::Value> = serde_json::from_str(&text)
        .or_else(|_| {
            serde_json::from_str(
                &text
                    .replace("-Infinity", "null")
                    .replace("Infinity", "null")
                    .replace("NaN", "null"),
            )
        })
        .with_context(|| format!("{}: not a summary", path.display()))?;
    for (key, value) in lenient {
        summary.insert(format!("lenient_{key}"), value);
    }
    Ok(summary)
}

/// The lenient evaluation into `out`: the teacher driven on its key scripts (geometry
/// only) and the engine's rollout, then the trainer's evaluation (`python3 -m
/// unica_train.eval`, or $UNICA_PYTHON) on them.
fn lenient(
    args: &EvalArgs,
    character: &std::path::Path,
    clips: &[PathBuf],
    out: &std::path::Path,
    gpu: &GpuOptions,
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
    let pick = |given, full, short| eval_script(given, args.quick, full, short);
    let script = pick(&args.keys, EVAL_KEYS, EVAL_KEYS_QUICK);
    let stops_script = pick(&args.stops_keys, EVAL_STOPS_KEYS, EVAL_STOPS_KEYS_QUICK);
    let turns_script = pick(&args.turns_keys, EVAL_TURNS_KEYS, EVAL_TURNS_KEYS_QUICK);
    let keys = KeyScript::parse(script).context("--keys")?;
    let stops_keys = KeyScript::parse(stops_script).context("--stops-keys")?;
    let turns_keys = KeyScript::parse(turns_script).context("--turns-keys")?;
    let teacher = out.join("teacher.json");
    let stops_teacher = out.join("teacher_stops.json");
    let turns_teacher = out.join("teacher_turns.json");
    for (keys, path) in [
        (&keys, &teacher),
        (&stops_keys, &stops_teacher),
        (&turns_keys, &turns_teacher),
    ] {
        let roots = crate::headless::teacher_roots(character, clips, keys)?;
        let frames: Vec<_> = roots
            .iter()
            .map(|r| serde_json::json!({ "root": r.to_array() }))
            .collect();
        crate::files::write_atomic(
            path,
            serde_json::to_string(&serde_json::json!({ "frames": frames }))?.as_bytes(),
        )?;
    }
    // The free-running rollout through the shipped engine path (the WGSL model, PCA
    // clean-up): each frame's drawn points, which the report compares with the teacher.
    let engine_dir = out.join("engine");
    let manifest = crate::engine::bundle::read_manifest(&args.bundle.join("manifest.json"))?;
    let job = crate::headless::RenderJob {
        avatar: crate::headless::Avatar::Bundle {
            dir: args.bundle.clone(),
            options: crate::engine::EngineOptions {
                seed: args.seed,
                sampling: Some(manifest.sampler.live()),
                pca: true,
                ..Default::default()
            },
        },
        keys: keys.clone(),
        out: engine_dir.clone(),
        size: 64,
        views: 1,
        points: true,
        surface: false,
        splat_level: Some(128),
        refine: false,
    };
    render_with_bar(&job, GpuContext::headless(gpu)?, "engine rollout")?;
    let python = std::env::var("UNICA_PYTHON").unwrap_or_else(|_| "python3".into());
    let mut command = std::process::Command::new(&python);
    command
        .args(["-m", "unica_train.eval", "--engine"])
        .arg(&engine_dir)
        .args(["--keys", script])
        .arg("--bundle")
        .arg(&args.bundle)
        .arg("--data")
        .arg(&args.data)
        .arg("--teacher")
        .arg(&teacher)
        .args(["--stops-keys", stops_script])
        .arg("--stops-teacher")
        .arg(&stops_teacher)
        .args(["--turns-keys", turns_script])
        .arg("--turns-teacher")
        .arg(&turns_teacher)
        .arg("--out")
        .arg(out)
        .args(["--seed", &args.seed.to_string()]);
    if args.quick {
        command.arg("--quick");
    }
    if let Some(n) = args.long_frames {
        command.args(["--long-frames", &n.to_string()]);
    }
    if let Some(n) = args.motion_seeds {
        command.args(["--motion-seeds", &n.to_string()]);
    }
    let status = command.status().with_context(|| {
        format!(
            "running {python}: unica eval needs Python 3 with the trainer (pip install -e ./train)"
        )
    })?;
    if !status.success() {
        bail!("the evaluation failed ({python} -m unica_train.eval exited with {status})");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lenient_keys_join_with_a_prefix_and_python_non_numbers_become_null() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("summary.json"),
            "{\"masked_psnr_db\": 25.5, \"stop_frames\": NaN, \"drift\": -Infinity, \"seeds\": [0, 1]}",
        )
        .unwrap();
        let mut strict = serde_json::Map::new();
        strict.insert("seeds".into(), serde_json::json!(5));
        let merged = with_lenient(dir.path(), strict).unwrap();
        assert_eq!(merged["seeds"], serde_json::json!(5));
        assert_eq!(merged["lenient_seeds"], serde_json::json!([0, 1]));
        assert_eq!(merged["lenient_masked_psnr_db"], serde_json::json!(25.5));
        assert!(merged["lenient_stop_frames"].is_null() && merged["lenient_drift"].is_null());
        let error = with_lenient(&dir.path().join("none"), serde_json::Map::new()).unwrap_err();
        assert!(
            format!("{error:#}").contains("none/summary.json"),
            "{error:#}"
        );
    }
}
