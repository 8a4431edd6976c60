//! The auto-rigger's subcommands: `unica rig`, `rig-eval` and `rig-data`.

use std::path::{Path, PathBuf};

use anyhow::bail;

use super::defaults::default_character;

#[derive(clap::Args, Debug)]
pub(super) struct RigEvalArgs {
    /// The rig-data folder the models were trained on (its last --holdout pairs are unseen)
    #[arg(long)]
    data: PathBuf,
    /// Pairs at the end of --data held out of training
    #[arg(long, default_value_t = 100)]
    holdout: usize,
    /// Folder of the trained models (skeleton.*, skin.*)
    #[arg(long, value_name = "DIR", default_value = "assets/autorig")]
    models: PathBuf,
    /// A rigged character to rig from its mesh alone and compare with its own rig
    /// [default: the default character]
    #[arg(long, value_name = "FILE")]
    character: Option<PathBuf>,
    /// Where results.json goes
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
pub(super) struct RigArgs {
    /// The character mesh
    mesh: PathBuf,
    /// The rigged file to write (.glb)
    #[arg(long)]
    out: PathBuf,
    /// Folder of the trained auto-rig models (skeleton.* and skin.*)
    #[arg(long, value_name = "DIR", default_value = "assets/autorig")]
    models: PathBuf,
    /// Use the geometric baselines (template fit, geodesic prior) instead of the models
    #[arg(long)]
    baseline: bool,
    /// The rigged humanoid whose clips are retargeted [default: the default character]
    #[arg(long, value_name = "FILE")]
    clips_from: Option<PathBuf>,
    /// Animation libraries (.gltf/.glb) whose clips join --clips-from's by joint name
    /// (its idle/walk/run: clips named Idle/Walk/Run, else as its description says)
    #[arg(long, value_name = "FILE", num_args = 1..)]
    clips: Vec<PathBuf>,
    /// Seed of the surface sampling (of the first try)
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Skeletons to predict, from surface samplings --seed, --seed + 1, …: the rig whose
    /// walk stretches an edge least is written (the model's spring chains vary most
    /// between samplings). 1 rigs once
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=64))]
    tries: u64,
    /// Leave out the finger joints (the hands are each one bone, the wrist). Without it
    /// they are kept unless they tear the mesh over a walk (a mitten hand): the rig is
    /// then made both ways and the one without them is written
    #[arg(long)]
    no_hands: bool,
}

#[derive(clap::Args, Debug)]
pub(super) struct RigDataArgs {
    /// Output folder (sample_NNNNN.safetensors + manifest.json)
    #[arg(long)]
    out: PathBuf,
    /// Synthetic characters to write
    #[arg(long, default_value_t = 2000)]
    count: usize,
    /// Seed of the first character (character i uses seed + i)
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// A rigged character (.gltf, .glb) to write as OUT/sample_00000.safetensors instead
    #[arg(long, value_name = "FILE")]
    character: Option<PathBuf>,
    /// The plain generator the shipped models were trained on: no chibi or long-limbed
    /// builds, no arms at the sides, capsule skirts and hair, no capes
    #[arg(long)]
    plain: bool,
}

pub(super) fn rig(args: RigArgs) -> anyhow::Result<()> {
    use crate::autorig::pipeline::{Models, RigOptions, rig_file};
    if args
        .out
        .extension()
        .is_none_or(|e| !e.eq_ignore_ascii_case("glb"))
    {
        bail!(
            "{}: the rigged output must be a .glb file",
            args.out.display()
        );
    }
    let models = if args.baseline {
        Models::none()
    } else {
        Models::load(&models_dir(&args.models))?
    };
    let clips_from = args.clips_from.or_else(default_character).ok_or_else(|| {
        anyhow::anyhow!("no rigged humanoid to take clips from; give --clips-from FILE")
    })?;
    let start = std::time::Instant::now();
    let options = RigOptions {
        clips_from: &clips_from,
        clip_files: &args.clips,
        seed: args.seed,
        tries: args.tries,
        hands: !args.no_hands,
    };
    let summary = rig_file(&args.mesh, &args.out, &models, &options, &|stage| {
        eprintln!("rig: {stage}…")
    })?;
    println!(
        "rigged {} into {} in {:.1} s: {} joints ({:?} skeleton), {:?} skin, {} spring chains{} (VRM; {} predicted ones left out), {} clips, largest edge stretch {} over a walk; description {}",
        args.mesh.display(),
        args.out.display(),
        start.elapsed().as_secs_f64(),
        summary.joints,
        summary.skeleton,
        summary.skin,
        summary.spring_chains,
        if summary.chain_parents.is_empty() {
            String::new()
        } else {
            format!(" hanging from {}", summary.chain_parents.join(", "))
        },
        summary.dropped_chains,
        summary.clips,
        summary
            .stretch
            .map_or("not measured".to_string(), |s| format!("{s:.2}")),
        summary.description.display()
    );
    if let crate::autorig::pipeline::Hands::DroppedTearing(stretch) = summary.hands {
        println!(
            "finger joints left out: with them the walk stretched an edge {stretch:.2} times (the mesh's fingers are not separate)"
        );
    }
    if summary.tries.len() > 1 {
        let tries: Vec<String> = summary
            .tries
            .iter()
            .map(|(seed, stretch)| {
                let stretch = stretch.map_or("not measured".to_string(), |s| format!("{s:.2}"));
                format!("seed {seed}: {stretch}")
            })
            .collect();
        println!(
            "skeletons tried (largest edge stretch over the walk): {}; written: seed {}",
            tries.join(", "),
            summary.seed
        );
    }
    Ok(())
}

pub(super) fn rig_eval(args: RigEvalArgs) -> anyhow::Result<()> {
    use crate::autorig::{evaluate::evaluate, pipeline::Models};
    let manifest_path = args.data.join("manifest.json");
    let manifest: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&manifest_path)
            .map_err(|e| anyhow::anyhow!("{}: {e}", manifest_path.display()))?,
    )
    .map_err(|e| anyhow::anyhow!("{}: {e}", manifest_path.display()))?;
    let count = manifest["count"]
        .as_u64()
        .ok_or_else(|| anyhow::anyhow!("{}: no count", manifest_path.display()))?
        as usize;
    if args.holdout == 0 || args.holdout > count {
        bail!(
            "--holdout must be between 1 and the {count} pairs of {}",
            args.data.display()
        );
    }
    let models = Models::load(&models_dir(&args.models))?;
    let character = args.character.or_else(default_character);
    let bar = super::progress::bar(
        "held-out characters {bar:40} {pos}/{len}, {left}",
        args.holdout as u64,
    );
    let report = evaluate(
        &args.data,
        args.holdout,
        count,
        character.as_deref(),
        &models,
        &|done, _| bar.set_position(done as u64),
    )?;
    bar.finish_and_clear();
    std::fs::create_dir_all(&args.out)?;
    let path = args.out.join("results.json");
    crate::files::write_atomic(&path, serde_json::to_string_pretty(&report)?.as_bytes())?;
    let markdown = crate::autorig::evaluate::markdown(&report);
    crate::files::write_atomic(&args.out.join("report.md"), markdown.as_bytes())?;
    println!("{markdown}");
    println!("wrote {} and report.md", path.display());
    Ok(())
}

pub(super) fn rig_data(args: RigDataArgs) -> anyhow::Result<()> {
    use crate::autorig::{data, skeleton};
    if let Some(path) = &args.character {
        let character = crate::avatar::load_character(path)?;
        let skeleton = skeleton::of_character(&character);
        let skin = data::skin_of_character(&character, &skeleton);
        let pair = data::sample(&skeleton, &character.rest_mesh(), &skin, args.seed)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        std::fs::create_dir_all(&args.out)?;
        pair.write(&data::sample_path(&args.out, 0))?;
        println!(
            "wrote {} ({} joints)",
            data::sample_path(&args.out, 0).display(),
            skeleton.len()
        );
        return Ok(());
    }
    let bar = super::progress::bar("characters {bar:40} {pos}/{len}, {left}", args.count as u64);
    let start = std::time::Instant::now();
    data::write_synthetic(&args.out, args.count, args.seed, !args.plain, &|done, _| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();
    println!(
        "wrote {} synthetic characters into {} in {:.1} s",
        args.count,
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The auto-rig models folder: as given, else (for the default relative path run from
/// elsewhere) the same path in the source tree.
pub(super) fn models_dir(dir: &Path) -> PathBuf {
    if dir.is_dir() {
        dir.to_path_buf()
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(dir)
    }
}
