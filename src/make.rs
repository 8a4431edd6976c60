//! `unica make`: from a character file to a neural avatar bundle in one command. It runs
//! the five stages a person would run by hand — bake the teacher's dataset, train the
//! geometry model, train the splat refiner, distil the sampler into a one-pass student,
//! evaluate — each as its own process with its
//! own progress bar, and records in `OUT/make.json` what it was asked and which stages
//! finished, so a second run with the same arguments continues where the first stopped
//! (the trainers resume from their checkpoints). The bundle the app opens is `OUT/bundle`.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};

/// The stages in order, with what each one writes under OUT.
pub const STAGES: [(&str, &str); 5] = [
    ("bake", "data/"),
    ("geometry", "geometry/ (VAE + UNet run; bundle/ from it)"),
    ("refiner", "refiner/ (adds the refiner to bundle/)"),
    ("distil", "distil/ (adds the one-pass student to bundle/)"),
    ("eval", "eval/report.md"),
];

/// The shipped Witch's geometry recipe: her schedule (train/configs/witch_cpu.json: 3,000
/// VAE steps and 3,800 + 1,200 UNet steps at batch 16) in samples, so that more processes
/// or larger batches see the same data in fewer steps (about 105 minutes on a 2-core CPU);
/// her PCA-head VAE and quarter-turned UNet training; and her live settings (sampler,
/// root motion, heading, grounding, stand latch), which the trainer writes into the
/// manifest. Made without them, the Knight's VAE reconstructed 61 mm (the Witch's 6.7)
/// and it ran at 2.4 times its teacher's speed (docs/make.md).
const FULL_GEOMETRY: &str = include_str!("../train/configs/make_full.json");
/// The shipped Witch's refiner schedule in frames: 3,000 steps of one frame (about 50
/// minutes on a 2-core CPU); N processes take 3,000 / N steps.
const FULL_REFINER_FRAMES: u32 = 3000;

/// The distillation of the shipped Witch's sampler (docs/experiments/distillation.md):
/// 1,536 frames sampled by the teacher and 400 student steps, about 35 minutes on a
/// 2-core CPU.
const FULL_DISTIL: [&str; 8] = [
    "--frames",
    "1536",
    "--steps",
    "400",
    "--batch",
    "16",
    "--held-out-frames",
    "128",
];
/// `--quick`: a handful of frames and steps (the quick dataset holds clip 2 out).
const QUICK_DISTIL: [&str; 12] = [
    "--frames",
    "16",
    "--steps",
    "4",
    "--batch",
    "2",
    "--held-out-frames",
    "8",
    "--held-out-clips",
    "2",
    "--checkpoint-every",
    "2",
];

/// `--quick`: a tiny model and a few steps of each stage on the quick dataset (4 clips;
/// clip 2 held out), minutes in all: it proves the pipeline, not the avatar.
const QUICK_GEOMETRY: &str = r#"{
  "vae": {"channels": [16, 12, 8, 8], "latent": 4, "kl_weight": 1e-6, "decoder": "pca", "components": 8},
  "quarter_turns": true, "cfg_scale": 2.0, "guide_idle": false, "noise_scale": 0.25,
  "idle_brake_cfg_scale": 0.75, "idle_brake_frames": 10, "root_motion": "decoded",
  "grounded": true, "stand_speed": 0.1,
  "unet": {"latent": 4, "channels": [16, 32], "embed": 32, "heads": 2, "frames": 4, "actions": 5},
  "vae_samples": 40, "vae_batch": 2, "unet_samples": 40, "stage2_samples": 20, "unet_batch": 2,
  "pca_components": 8, "pca_frames": 20, "held_out_clips": [2], "rollout_frames": 3,
  "ddim_steps": 2, "checkpoint_every": 10
}
"#;
const QUICK_REFINER: &str = r#"{
  "model": {"channels": [8, 16], "depths": [1, 1], "heads": [2, 2], "decoder_depth": 1,
            "patch": 16, "stride": 4, "mean_bound": 0.004},
  "samples": 10, "image_size": 32, "held_out_clips": [2], "eval_frames": 2,
  "checkpoint_every": 5, "splat_level": 256, "alpha_weight": 0.5
}
"#;

#[derive(clap::Args, Debug)]
pub struct MakeArgs {
    /// The character file (.gltf, .glb, .obj with its rig), as for `unica bake`
    pub character: PathBuf,
    /// Output folder: data/, geometry/, refiner/, eval/ and bundle/ (the neural avatar:
    /// `unica --bundle OUT/bundle`). Run again with the same arguments to continue an
    /// interrupted make
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// A tiny model and a few steps of each stage (minutes; proves the pipeline, the
    /// avatar will not look like anything)
    #[arg(long)]
    pub quick: bool,
    /// Where the trainers run: auto (CUDA when PyTorch sees a GPU), cpu or cuda
    #[arg(long, default_value = "auto", value_parser = ["auto", "cpu", "cuda"])]
    pub device: String,
    /// Train the geometry model and the refiner data-parallel in this many processes
    /// (torchrun, one machine): one per GPU with --device cuda (NCCL), or CPU processes
    /// (gloo). Schedules are the same data either way: N processes take 1/N of the steps
    /// of the refiner, and of the geometry model where its config gives samples
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub gpus: u32,
    /// Avatar description (JSON) passed to `unica bake` [default: inferred]
    #[arg(long, value_name = "FILE")]
    pub avatar: Option<PathBuf>,
    /// Animation libraries (.gltf/.glb) whose clips join the character's, matched to its
    /// joints by name (as for `unica bake`)
    #[arg(long, value_name = "FILE", num_args = 1..)]
    pub clips: Vec<PathBuf>,
    /// Stop after this stage (a later run with the same arguments goes on from there)
    #[arg(long, value_name = "STAGE", value_parser = ["bake", "geometry", "refiner", "distil", "eval"])]
    pub until: Option<String>,
}

/// What a make was asked; a later run must ask the same to continue it.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
struct Asked {
    character: PathBuf,
    quick: bool,
    avatar: Option<PathBuf>,
    #[serde(default)]
    clips: Vec<PathBuf>,
}

#[derive(serde::Serialize, serde::Deserialize, Debug)]
struct State {
    asked: Asked,
    /// Stages finished, in order.
    done: Vec<String>,
    /// Wall-clock seconds of each finished stage, in order: the run that finished it (a
    /// stage resumed after an interruption counts its last run only).
    #[serde(default)]
    seconds: Vec<(String, f64)>,
}

/// Runs the stages not yet done; `exe` is this program (for bake and eval), `python` the
/// interpreter with the trainer.
pub fn make(args: &MakeArgs, exe: &Path, python: &str) -> anyhow::Result<()> {
    if !args.character.is_file() {
        bail!("{}: no such character file", args.character.display());
    }
    std::fs::create_dir_all(&args.out).with_context(|| args.out.display().to_string())?;
    let state_path = args.out.join("make.json");
    let asked = Asked {
        character: std::path::absolute(&args.character)
            .with_context(|| args.character.display().to_string())?,
        quick: args.quick,
        avatar: args.avatar.clone(),
        clips: args.clips.clone(),
    };
    let mut state = read_state(&state_path)?.unwrap_or(State {
        asked: asked.clone(),
        done: Vec::new(),
        seconds: Vec::new(),
    });
    if state.asked != asked {
        bail!(
            "{}: this folder holds a make of {} (quick {}); give another --out, or the same \
             arguments to continue it",
            state_path.display(),
            state.asked.character.display(),
            state.asked.quick
        );
    }
    check_trainer(python)?;
    let started = Instant::now();
    let (data, geometry, refiner, distil, bundle, eval) = (
        args.out.join("data"),
        args.out.join("geometry"),
        args.out.join("refiner"),
        args.out.join("distil"),
        args.out.join("bundle"),
        args.out.join("eval"),
    );
    // A make killed between copy_dir's two renames left OUT/bundle aside: put it back
    // before any stage reads it (the distillation opens it before its copy_dir).
    restore_aside(&bundle)?;
    for (index, (stage, writes)) in STAGES.iter().enumerate() {
        let header = format!("[{}/{}] {stage} → {}", index + 1, STAGES.len(), writes);
        if state.done.iter().any(|d| d == stage) {
            println!("{header}: done before, kept");
            continue;
        }
        println!("{header}");
        let clock = Instant::now();
        match *stage {
            "bake" => {
                let mut command = Command::new(exe);
                command
                    .arg("bake")
                    .arg(&args.character)
                    .arg("--out")
                    .arg(&data);
                if args.quick {
                    command.arg("--quick");
                }
                if let Some(avatar) = &args.avatar {
                    command.arg("--avatar").arg(avatar);
                }
                if !args.clips.is_empty() {
                    command.arg("--clips").args(&args.clips);
                }
                run(command, "unica bake")?;
            }
            "geometry" => {
                let config = args.out.join("geometry_config.json");
                let text = if args.quick {
                    QUICK_GEOMETRY
                } else {
                    FULL_GEOMETRY
                };
                crate::files::write_atomic(&config, text.as_bytes())?;
                let mut command = trainer_on(python, "unica_train.train", args.gpus);
                command
                    .arg("--data")
                    .arg(&data)
                    .arg("--out")
                    .arg(&geometry)
                    .arg("--config")
                    .arg(&config)
                    .args(["--device", &args.device]);
                if geometry.join("checkpoints").is_dir() {
                    command.arg("--resume");
                }
                run(command, "the geometry trainer")?;
            }
            "refiner" => {
                // The refiner is added to a copy of the geometry bundle, so a rerun of
                // this stage starts from the same geometry.
                copy_dir(&geometry.join("bundle"), &bundle)?;
                // A student distilled from an earlier bundle would not match this one.
                if distil.exists() {
                    std::fs::remove_dir_all(&distil)
                        .with_context(|| distil.display().to_string())?;
                }
                let mut command = trainer_on(python, "unica_train.refiner", args.gpus);
                command
                    .args(bundle_data_out(&bundle, &data, &refiner))
                    .args(["--device", &args.device])
                    .arg("--write-bundle");
                if args.quick {
                    let config = args.out.join("refiner_config.json");
                    crate::files::write_atomic(&config, QUICK_REFINER.as_bytes())?;
                    command.arg("--config").arg(&config);
                } else {
                    command.args(["--samples", &FULL_REFINER_FRAMES.to_string()]);
                }
                if refiner.join("refiner_checkpoint.pt").is_file() {
                    command.arg("--resume");
                }
                run(command, "the refiner trainer")?;
            }
            "distil" => {
                // The student is distilled from the refiner stage's bundle and written
                // into a copy of it, which then replaces OUT/bundle whole.
                let mut command = trainer(python, "unica_train.distil");
                command
                    .args(bundle_data_out(&bundle, &data, &distil))
                    .args(if args.quick {
                        &QUICK_DISTIL[..]
                    } else {
                        &FULL_DISTIL[..]
                    });
                if distil.is_dir() {
                    command.arg("--resume");
                }
                run(command, "the distillation")?;
                copy_dir(&distil.join("bundle"), &bundle)?;
            }
            "eval" => {
                let mut command = Command::new(exe);
                command
                    .arg("eval")
                    .args(bundle_data_out(&bundle, &data, &eval))
                    .arg("--character")
                    .arg(&args.character)
                    .args(["--quick", "--strict-only"]);
                run(command, "unica eval")?;
            }
            _ => unreachable!("a stage of STAGES"),
        }
        let seconds = clock.elapsed().as_secs_f64();
        state.done.push(stage.to_string());
        state
            .seconds
            .push((stage.to_string(), (seconds * 10.0).round() / 10.0));
        write_state(&state_path, &state)?;
        println!(
            "[{}/{}] {stage}: done in {}",
            index + 1,
            STAGES.len(),
            duration(seconds)
        );
        if args.until.as_deref() == Some(*stage) {
            println!("stopped after {stage} (--until); the same command without --until goes on");
            return Ok(());
        }
    }
    let times: Vec<String> = state
        .seconds
        .iter()
        .map(|(stage, s)| format!("{stage} {}", duration(*s)))
        .collect();
    println!(
        "made {} in {} ({}; this run {}): play it with `unica --bundle {}`; the evaluation is in {}",
        bundle.display(),
        duration(state.seconds.iter().map(|(_, s)| s).sum()),
        times.join(", "),
        duration(started.elapsed().as_secs_f64()),
        bundle.display(),
        eval.join("report.md").display()
    );
    Ok(())
}

/// Seconds as "42 s", "12.5 min" or "2.25 h".
fn duration(seconds: f64) -> String {
    if seconds < 120.0 {
        format!("{seconds:.0} s")
    } else if seconds < 7200.0 {
        format!("{:.1} min", seconds / 60.0)
    } else {
        format!("{:.2} h", seconds / 3600.0)
    }
}

fn read_state(path: &Path) -> anyhow::Result<Option<State>> {
    match std::fs::read(path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map(Some)
            .with_context(|| format!("{}: not a make state file", path.display())),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| path.display().to_string()),
    }
}

fn write_state(path: &Path, state: &State) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(state)? + "\n";
    crate::files::write_atomic(path, text.as_bytes())?;
    Ok(())
}

/// The arguments `--bundle B --data D --out O` that the stages after the geometry take.
fn bundle_data_out<'a>(bundle: &'a Path, data: &'a Path, out: &'a Path) -> [&'a OsStr; 6] {
    [
        "--bundle".as_ref(),
        bundle.as_os_str(),
        "--data".as_ref(),
        data.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]
}

fn trainer(python: &str, module: &str) -> Command {
    let mut command = Command::new(python);
    command.args(["-u", "-m", module]);
    command
}

/// `trainer`, in `processes` data-parallel processes under torchrun on this machine when
/// more than one (`torch.distributed.run --standalone`: it picks a free port), started as
/// `unica_train.torchrun` so that it dies with the make as the trainers do.
fn trainer_on(python: &str, module: &str, processes: u32) -> Command {
    if processes <= 1 {
        return trainer(python, module);
    }
    let mut command = Command::new(python);
    command.args(["-u", "-m", "unica_train.torchrun", "--standalone"]);
    command.arg(format!("--nproc-per-node={processes}"));
    command.args(["-m", module]);
    command
}

/// PYTHONPATH with this source tree's trainer first, for every process a make starts
/// (`unica eval` runs the trainer for the lenient evaluation, which a make skips).
fn python_path() -> std::ffi::OsString {
    let mut path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("train")
        .into_os_string();
    if let Some(old) = std::env::var_os("PYTHONPATH").filter(|p| !p.is_empty()) {
        path.push(":");
        path.push(old);
    }
    path
}

/// Fails in one line when the trainer cannot be imported (before any stage runs).
fn check_trainer(python: &str) -> anyhow::Result<()> {
    let output = trainer(python, "unica_train.bundle")
        .arg("--help")
        .env("PYTHONPATH", python_path())
        .output()
        .with_context(|| format!("running {python}: unica make needs Python 3 with PyTorch"))?;
    if !output.status.success() {
        let err = String::from_utf8_lossy(&output.stderr);
        let last = err.lines().last().unwrap_or("").trim().to_string();
        bail!(
            "{python} cannot run the trainer ({last}); install it with \
             `python3 -m pip install -e ./train` (or set UNICA_PYTHON)"
        );
    }
    Ok(())
}

fn run(mut command: Command, what: &str) -> anyhow::Result<()> {
    command
        .env("PYTHONPATH", python_path())
        // torchrun's worker processes do not get `python -u`: unbuffered output keeps
        // their progress lines in order with the make's own.
        .env("PYTHONUNBUFFERED", "1")
        // Each process a stage starts below this one dies with its parent
        // (unica_train/__init__.py; torchrun too, as unica_train.torchrun), so a make killed
        // part-way leaves none writing while it is run again. The value is the make's
        // pid, so that a child of a make running as pid 1 (a container's entry point)
        // does not take its parent for dead.
        .env("UNICA_DIE_WITH_PARENT", std::process::id().to_string());
    let status = command
        .status()
        .with_context(|| format!("starting {what}"))?;
    if !status.success() {
        bail!("{what} failed ({status}); run the same `unica make` again to continue");
    }
    Ok(())
}

/// `to` put back from `.NAME.old` where [`copy_dir`] was killed between its renames.
fn restore_aside(to: &Path) -> anyhow::Result<()> {
    let name = to.file_name().expect("a folder name").to_string_lossy();
    let old = to.with_file_name(format!(".{name}.old"));
    if !to.exists() && old.exists() {
        std::fs::rename(&old, to).with_context(|| to.display().to_string())?;
    }
    Ok(())
}

/// Replaces `to` whole with a copy of the files of `from` (a flat bundle folder): the
/// copy is made and synced beside `to` (`.NAME.new`), then put in its place by two
/// renames, the old folder moved aside (`.NAME.old`) first and removed last. A make
/// killed between the renames finds `to` missing and the old folder aside, and puts it
/// back when it starts again ([`restore_aside`]).
fn copy_dir(from: &Path, to: &Path) -> anyhow::Result<()> {
    if !from.join("manifest.json").is_file() {
        bail!(
            "{}: the stage before wrote no bundle (no manifest.json)",
            from.display()
        );
    }
    let name = to.file_name().expect("a folder name").to_string_lossy();
    let staging = to.with_file_name(format!(".{name}.new"));
    let old = to.with_file_name(format!(".{name}.old"));
    let context = |path: &Path| path.display().to_string();
    restore_aside(to)?;
    for leftover in [&staging, &old] {
        if leftover.exists() {
            std::fs::remove_dir_all(leftover).with_context(|| context(leftover))?;
        }
    }
    std::fs::create_dir_all(&staging).with_context(|| context(&staging))?;
    for entry in std::fs::read_dir(from).with_context(|| context(from))? {
        let path = entry?.path();
        if path.is_file() {
            let copy = staging.join(path.file_name().expect("a file name"));
            std::fs::copy(&path, &copy).with_context(|| context(&path))?;
            std::fs::File::open(&copy)
                .and_then(|f| f.sync_all())
                .with_context(|| context(&copy))?;
        }
    }
    if to.exists() {
        std::fs::rename(to, &old).with_context(|| context(to))?;
    }
    std::fs::rename(&staging, to).with_context(|| context(to))?;
    if old.exists() {
        std::fs::remove_dir_all(&old).with_context(|| context(&old))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bundle_left_aside_between_the_renames_is_put_back() {
        let dir = tempfile::tempdir().unwrap();
        let (bundle, old) = (dir.path().join("bundle"), dir.path().join(".bundle.old"));
        std::fs::create_dir(&old).unwrap();
        std::fs::write(old.join("manifest.json"), "old").unwrap();
        restore_aside(&bundle).unwrap();
        assert_eq!(std::fs::read(bundle.join("manifest.json")).unwrap(), b"old");
        assert!(!old.exists());
        // A bundle in place is kept, and copy_dir replaces it whole.
        let new = dir.path().join("new");
        std::fs::create_dir(&new).unwrap();
        std::fs::write(new.join("manifest.json"), "new").unwrap();
        restore_aside(&bundle).unwrap();
        copy_dir(&new, &bundle).unwrap();
        assert_eq!(std::fs::read(bundle.join("manifest.json")).unwrap(), b"new");
        let mut names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        assert_eq!(names, ["bundle", "new"]);
    }
}
