//! The command-line contract (docs/architecture.md, Command line): the app by default,
//! and the subcommands. Subcommands of later milestones are listed and refuse to run
//! until they exist.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Parser, Subcommand};

use crate::action::KeyScript;
use crate::app::{self, AppOptions};
use crate::gpu::{self, GpuContext, GpuOptions};
use crate::splat::files::{self, Up};

mod defaults;
mod eval;
mod progress;
mod rig;

use defaults::render_with_bar;
pub use defaults::{
    CHARACTER_ENV, default_bundle, default_character, shipped_avatars, shipped_teacher,
};

use eval::{EvalArgs, eval};
use rig::{RigArgs, RigDataArgs, RigEvalArgs, rig, rig_data, rig_eval};

#[derive(Parser, Debug)]
#[command(
    name = "unica",
    version,
    about = "Drive a 3D avatar with W/A/S/D: action-conditioned diffusion geometry on the GPU, drawn free-view",
    long_about = "Drive a 3D avatar with W/A/S/D. Without a subcommand unica opens the app: \
        an egui window with the 3D viewport (left-drag orbits, right/middle-drag pans, wheel \
        zooms, F frames the avatar, R resets the camera, F9 records frames).\n\n\
        GPU selection: WGPU_BACKEND=vulkan|metal|dx12|gl picks the backend, \
        WGPU_ADAPTER_NAME=<substring> picks the adapter, UNICA_FORCE_FALLBACK=1 (or \
        --gpu-fallback) uses only the f32 / no-subgroup / CPU-timer paths. Without a GPU, \
        install Mesa's CPU Vulkan driver (apt-get install mesa-vulkan-drivers libvulkan1)."
)]
pub struct Cli {
    #[command(subcommand)]
    command: Option<Command>,

    /// Character file (.gltf, .glb, .obj): without --bundle its teacher is shown alone;
    /// with --bundle it runs beside the neural avatar [default with neither: the shipped
    /// Witch bundle beside $UNICA_CHARACTER, else assets/witch/source/Witch.gltf]
    #[arg(long, value_name = "FILE")]
    character: Option<PathBuf>,

    /// Animation libraries (.gltf/.glb with a skeleton and clips, a mesh or not) whose
    /// clips join the --character's, matched to its joints by name; for characters whose
    /// animations ship in separate files
    #[arg(long, value_name = "FILE", num_args = 1..)]
    clips: Vec<PathBuf>,

    /// Neural avatar bundle to play, e.g. assets/knight/bundle; a shipped one plays beside
    /// its teacher [default: assets/witch/bundle unless --character]
    #[arg(long, value_name = "DIR")]
    bundle: Option<PathBuf>,

    /// Drive the avatar from a key script instead of the keyboard, e.g. "60W 60S 60A 20I"
    /// (keys W A S D, I = idle). Counts are generated frames: the neural avatar's (the
    /// teacher beside it steps with them), or, for a teacher alone, one step per drawn
    /// frame. Idle after the script ends
    #[arg(long, value_name = "SCRIPT")]
    keys: Option<String>,

    /// Render this many window frames, then exit (for tests and scripted captures; the
    /// window then redraws continuously so that the count advances)
    #[arg(long, value_name = "N", conflicts_with = "exit_after_seconds")]
    exit_after: Option<u64>,

    /// Close after this many seconds, whatever was drawn, and print the final line with
    /// generated_fps=, window_fps= and input_latency_ms= (the window draws only when
    /// something changes, as in normal use)
    #[arg(long, value_name = "SECONDS")]
    exit_after_seconds: Option<f64>,

    /// The neural avatar's teacher sampler with this many DDIM steps per generated frame
    /// [default: the bundle's sampler: its distilled one pass where it has one]; the HUD
    /// changes it live
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..=1000))]
    steps: Option<u64>,

    /// Save a PNG of the whole window when exiting (needs --exit-after or
    /// --exit-after-seconds)
    #[arg(long, value_name = "PNG")]
    screenshot: Option<PathBuf>,

    /// Folder that recordings (F9) go to [default: recordings/session-<unix time>]
    #[arg(long, value_name = "DIR")]
    record_dir: Option<PathBuf>,

    /// Start recording (as F9 does) when the window opens
    #[arg(long)]
    record: bool,

    /// Recording rate in frames per second
    #[arg(long, value_name = "FPS", default_value_t = crate::app::recorder::DEFAULT_FPS,
          value_parser = parse_fps)]
    record_fps: f64,

    /// Use only the portable GPU paths: f32 kernels, no subgroups, CPU timers
    #[arg(long, global = true)]
    gpu_fallback: bool,

    /// For tests: resize the window through N sizes down to 1 × 1 and back, one a frame,
    /// then hide it for a second and show it again
    #[arg(long, value_name = "N", hide = true)]
    stress_resize: Option<usize>,

    /// For tests: destroy the GPU device after SECONDS (the device is then lost)
    #[arg(long, value_name = "SECONDS", hide = true)]
    stress_lose_device: Option<f64>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// List the GPU adapters and what unica would use on each
    Adapters,
    /// Time the GPU kernels and the geometry model (UNet steps, decoder, a whole
    /// generated frame) on the present adapter, with FLOPs and GFLOP/s
    Bench(BenchArgs),
    /// Bake a teacher dataset from a character file (.gltf, .glb): the transition table
    /// of all action pairs, as skinning matrices + position-map table (see README)
    Bake(BakeArgs),
    /// Check a baked dataset: files, shapes, actions vs switch frames, normalised ranges
    Validate {
        /// The dataset folder written by `unica bake`
        dir: PathBuf,
    },
    /// Headless scripted session to numbered PNGs per view + manifest.json: the neural
    /// avatar of --bundle DIR, or the teacher of --teacher CHARACTER
    Render(RenderArgs),
    /// Evaluate a bundle strictly against its teacher: both driven in lockstep on random
    /// key scripts from several seeds, the engine's splats scored on foreground pixels on
    /// white, grey and black from 8 views, motion two-sided (OUT/report.md,
    /// summary.json); then the former lenient evaluation in OUT/lenient (python3 with
    /// `pip install -e ./train`)
    Eval(EvalArgs),
    /// Export the neural avatar's splats after a key script as a 3DGS PLY or an
    /// antimatter15 .splat (optionally Z-up)
    Export(ExportArgs),
    /// Open a splat file in the viewer: a 3DGS PLY (unica's or another program's),
    /// SuperSplat's compressed PLY, or an antimatter15 .splat (optionally Z-up)
    View(ViewArgs),
    /// Write the auto-rigger's training pairs: synthetic characters (humanoids,
    /// quadrupeds, creatures in random poses) with their skeleton tokens, skin weights and
    /// voxel geodesic distances; with --character, one pair from a rigged file instead
    /// (for held-out evaluation)
    RigData(RigDataArgs),
    /// Rig a static mesh (.obj, .gltf, .glb, .vrm; any skin it has is ignored): skeleton,
    /// skin weights, the template's idle/walk/run clips, and spring chains on the mesh
    /// written as VRM 1.0 spring bones with colliders beside a VRM humanoid bone map; a .glb
    /// plus OUT.avatar.json, ready for `unica bake`
    Rig(RigArgs),
    /// Measure the auto-rigger on held-out synthetic pairs and a rigged file with its skin
    /// removed (J2J, J2B, B2B, skin L1, motion L2; learned vs the geometric baselines)
    RigEval(RigEvalArgs),
    /// Make a neural avatar from a character file: bake, train the geometry model and the
    /// refiner, evaluate; resumable (run it again to continue). Needs Python 3 with the
    /// trainer (pip install -e ./train). Full run ≈ 2 hours on a 2-core CPU; --quick:
    /// minutes
    Make(crate::make::MakeArgs),
}

#[derive(clap::Args, Debug)]
struct BenchArgs {
    /// Model configurations with random weights: tiny (the parity fixtures' shape),
    /// default (the shipped Witch's shape), both, or none
    #[arg(long, value_enum, default_value = "both")]
    models: BenchModels,
    /// Also time a trained bundle (e.g. assets/witch/bundle)
    #[arg(long, value_name = "DIR")]
    bundle: Option<PathBuf>,
    /// DDIM steps per generated frame [default: 10 for the model tables; for --live and
    /// --soak the bundle's own sampler: its distilled one pass where it has one]. Given
    /// with --live or --soak, the bundle's teacher runs that many DDIM steps
    #[arg(long)]
    steps: Option<usize>,
    /// Classifier-free guidance scale (1 = no guidance, batch 1; else batch 2) [default:
    /// 2 for the model tables; the bundle's for --live and --soak]
    #[arg(long)]
    cfg_scale: Option<f32>,
    /// Timed runs per row, after one warm-up
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// Storage precision: f32, f16 (needs SHADER_F16) or both
    #[arg(long, value_enum, default_value = "both")]
    precision: BenchPrecision,
    /// Splats for the rasterizer rows (1280×720 and 1920×1080); 0 leaves them out
    #[arg(long, default_value_t = 250_000)]
    splats: usize,
    /// Instead of the tables: run the live loop of --bundle for N frames (geometry
    /// only, with the bundle's Idle guidance and noise scale) and report speed, clamped
    /// and non-finite values, memory and path headings
    #[arg(long, value_name = "N", requires = "bundle")]
    soak: Option<usize>,
    /// Instead of the tables: N generated frames of --bundle after a warm-up, as the app
    /// makes them (key to splat buffer), and the GPU work counted per frame: dispatches,
    /// submissions, readbacks and their bytes, buffers and bind groups created, CPU and
    /// wall milliseconds (with the bundle's Idle guidance and noise scale)
    #[arg(long, value_name = "N", requires = "bundle", conflicts_with = "soak")]
    live: Option<usize>,
    /// Splat level of the --bundle live-frame rows (128, 256, 512 or 1024) [default: 1024
    /// on a GPU, 256 on a CPU driver]
    #[arg(long, value_name = "SIZE", value_parser = parse_level)]
    splat_level: Option<usize>,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum BenchModels {
    Tiny,
    Default,
    Both,
    None,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum BenchPrecision {
    F32,
    F16,
    Both,
}

#[derive(clap::Args, Debug)]
struct BakeArgs {
    /// The character file
    character: PathBuf,
    /// Output folder (created)
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Also write preview.png: position maps and posed point clouds of sampled frames
    #[arg(long)]
    preview: bool,
    /// A few short clips instead of the full table (smoke tests)
    #[arg(long)]
    quick: bool,
    /// Skip the ground-truth RGB renders (geometry only; no GPU adapter needed)
    #[arg(long)]
    no_renders: bool,
    /// Avatar description (JSON) [default: <character>.avatar.json beside it, a shipped
    /// one for its name, or inferred: the waist and feet from bone names, else from the
    /// skeleton (the hips where the leg chains meet, the feet their lowest leaf joints);
    /// idle/walk/run from clip names, else from how fast the feet slide under the hips
    /// (still: idle, slower: walk, faster: run). What was inferred is printed in one line]
    #[arg(long, value_name = "FILE")]
    avatar: Option<PathBuf>,
    /// Animation libraries (.gltf/.glb with a skeleton and clips, a mesh or not) whose
    /// clips join the character's, matched to its joints by name; for characters whose
    /// animations ship in separate files
    #[arg(long, value_name = "FILE", num_args = 1..)]
    clips: Vec<PathBuf>,
    /// Instead of the table, bake every key change from or to Forward N times, the change
    /// moved 3 frames later each time (3 s of the first key, 2 s of the second): extra
    /// training data for turning and stopping at every phase of the stride (`python -m
    /// unica_train.train --extra-data DIR`; 5·N clips, 30 with N = 6)
    #[arg(long, value_name = "N", default_value_t = 0)]
    switch_phases: usize,
    /// Render every N-th frame from the four cardinal cameras; 1 renders every pose, for
    /// `unica eval`, whose free-running frames are each compared with the nearest
    /// rendered pose (with every 5th rendered, the teacher's own frames score 0.83 masked
    /// SSIM against their nearest; ~5× the renders' time and disk)
    #[arg(long, value_name = "N", default_value_t = crate::dataset::bake::RENDER_EVERY as u32,
          value_parser = clap::value_parser!(u32).range(1..))]
    render_every: u32,
}

/// How the neural avatar's splats are made.
#[derive(clap::Args, Debug)]
struct SplatArgs {
    /// Splat level: one splat per foreground pixel of the position map upscaled to this
    /// size (128, 256, 512 or 1024) [default: 1024 on a GPU, 256 on a CPU driver]
    #[arg(long, value_name = "SIZE", value_parser = parse_level)]
    splat_level: Option<usize>,
    /// Draw the base splats without the bundle's refiner
    #[arg(long)]
    no_refiner: bool,
}

fn parse_up(text: &str) -> Result<Up, String> {
    match text {
        "y" | "Y" => Ok(Up::Y),
        "z" | "Z" => Ok(Up::Z),
        _ => Err(format!("'{text}' is not an up axis: give y or z")),
    }
}

fn parse_level(text: &str) -> Result<usize, String> {
    let levels = crate::engine::appearance::LEVELS;
    text.parse::<usize>()
        .ok()
        .filter(|l| levels.contains(l))
        .ok_or_else(|| format!("'{text}' is not one of the splat levels {levels:?}"))
}

#[derive(clap::Args, Debug)]
struct RenderArgs {
    /// Render the teacher (the rigged character driven by the locomotion controller)
    #[arg(long, value_name = "CHARACTER")]
    teacher: Option<PathBuf>,
    /// Render the neural avatar of a bundle (e.g. assets/witch/bundle)
    #[arg(long, value_name = "DIR")]
    bundle: Option<PathBuf>,
    /// DDIM steps per generated frame [default: the bundle's]
    #[arg(long)]
    steps: Option<usize>,
    /// Classifier-free guidance scale [default: the bundle's]
    #[arg(long)]
    cfg_scale: Option<f32>,
    /// Draw the raw decoded points, without the PCA clean-up
    #[arg(long)]
    no_pca: bool,
    /// Store activations as f16 where the adapter has SHADER_F16
    #[arg(long)]
    f16: bool,
    /// Also write each frame's points as frame_NNNNN.ply (--bundle)
    #[arg(long)]
    points: bool,
    /// Draw the neural avatar as its triangulated map surface instead of splats
    #[arg(long)]
    surface: bool,
    #[command(flatten)]
    look: SplatArgs,
    /// Key script, e.g. "60W 60S 60A 20I" (one action per frame at 30 fps)
    #[arg(long, value_name = "SCRIPT")]
    keys: String,
    /// Output folder (created)
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Image width and height in pixels
    #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(16..=4096))]
    size: u32,
    /// Cameras around the avatar (view 0 behind its start, the others evenly around)
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=16))]
    views: u32,
    /// Seed of the neural avatar's sampler noise (the teacher is deterministic)
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Avatar description for --teacher (see `unica bake --help`)
    #[arg(long, value_name = "FILE")]
    avatar: Option<PathBuf>,
    /// Animation libraries (.gltf/.glb with a skeleton and clips, a mesh or not) whose
    /// clips join the --teacher's, matched to its joints by name; for characters whose
    /// animations ship in separate files
    #[arg(long, value_name = "FILE", num_args = 1..)]
    clips: Vec<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct ExportArgs {
    /// What to export: `ply` (3DGS PLY, float properties) or `splat` (antimatter15's
    /// .splat: 32 bytes per splat, 8-bit colour and rotation, largest size × opacity
    /// first)
    #[arg(value_parser = ["ply", "splat"])]
    format: String,
    /// The bundle whose neural avatar is driven
    #[arg(long, value_name = "DIR")]
    bundle: PathBuf,
    /// Key script run before the export, e.g. "30W 10D" (the last frame is exported)
    #[arg(long, value_name = "SCRIPT", default_value = "1I")]
    keys: String,
    /// Output file (FILE.ply or FILE.splat, as the format says)
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
    /// DDIM steps per generated frame [default: the bundle's]
    #[arg(long)]
    steps: Option<usize>,
    /// Seed of the sampler noise
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The file's up axis: y (unica's) or z (turned +90° about X on the way out, for
    /// Z-up tools)
    #[arg(long, value_name = "y|z", default_value = "y", value_parser = parse_up)]
    up: Up,
    #[command(flatten)]
    look: SplatArgs,
}

#[derive(clap::Args, Debug)]
struct ViewArgs {
    /// A splat file: .splat (antimatter15) by its extension, else a PLY (3DGS, or
    /// SuperSplat's compressed layout, found by its content)
    file: PathBuf,
    /// The file's up axis: y (as unica draws) or z (a Z-up file: turned −90° about X so
    /// +Z becomes +Y)
    #[arg(long, value_name = "y|z", default_value = "y", value_parser = parse_up)]
    up: Up,
    /// Render this many frames, then exit
    #[arg(long, value_name = "N")]
    exit_after: Option<u64>,
    /// Save a PNG of the whole window when exiting (needs --exit-after)
    #[arg(long, value_name = "PNG", requires = "exit_after")]
    screenshot: Option<PathBuf>,
}

/// Parses the process arguments and runs the command.
pub fn run() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let mut gpu_options = GpuOptions::from_env();
    gpu_options.force_fallback |= cli.gpu_fallback;
    match cli.command {
        None => play(cli, gpu_options),
        Some(Command::Adapters) => adapters(&gpu_options),
        Some(Command::Bench(args)) => bench(args, &gpu_options),
        Some(Command::Bake(args)) => bake(args),
        Some(Command::Validate { dir }) => {
            let report = crate::dataset::validate(&dir)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(())
        }
        Some(Command::Render(args)) => render(args, &gpu_options),
        Some(Command::Eval(args)) => eval(args, &gpu_options),
        Some(Command::Export(args)) => export(args, &gpu_options),
        Some(Command::View(args)) => view(args, gpu_options),
        Some(Command::RigData(args)) => rig_data(args),
        Some(Command::Rig(args)) => rig(args),
        Some(Command::RigEval(args)) => rig_eval(args),
        Some(Command::Make(args)) => {
            let exe = std::env::current_exe().context("finding the unica executable")?;
            let python = std::env::var("UNICA_PYTHON").unwrap_or_else(|_| "python3".into());
            crate::make::make(&args, &exe, &python)
        }
    }
}

fn bench(args: BenchArgs, gpu_options: &GpuOptions) -> anyhow::Result<()> {
    use crate::gpu::kernel::Precision;
    let sampling =
        crate::nn::sampler::Sampling::new(args.steps.unwrap_or(10), args.cfg_scale.unwrap_or(2.0));
    // The random-weight models use the 1000-step schedule; a bundle is checked on load.
    sampling.check(1000).map_err(anyhow::Error::msg)?;
    if args.repeat == 0 {
        bail!("--repeat must be at least 1");
    }
    let gpu = GpuContext::headless(gpu_options)?;
    // The live rows run as the app does: the bundle's sampler (its one pass where it has
    // one), or its teacher with --steps and --cfg-scale, with its Idle guidance and noise
    // scale.
    let bundled = |dir: &Path| -> anyhow::Result<crate::nn::sampler::Sampling> {
        let manifest = crate::engine::bundle::read_manifest(&dir.join("manifest.json"))?;
        Ok(manifest.sampler.chosen(args.steps, args.cfg_scale))
    };
    if let (Some(frames), Some(dir)) = (args.soak, &args.bundle) {
        let sampling = bundled(dir)?;
        return crate::bench::soak(&gpu, dir, frames, Some(sampling), &mut std::io::stdout());
    }
    if let (Some(frames), Some(dir)) = (args.live, &args.bundle) {
        if frames == 0 {
            bail!("--live must be at least 1 frame");
        }
        let sampling = bundled(dir)?;
        let level = args
            .splat_level
            .unwrap_or_else(|| crate::engine::appearance::default_level(&gpu));
        return crate::bench::live(&gpu, dir, sampling, level, frames, &mut std::io::stdout());
    }
    if matches!(args.precision, BenchPrecision::F16) && !gpu.caps.shader_f16 {
        bail!(
            "{} has no SHADER_F16: use --precision f32",
            gpu.adapter_label()
        );
    }
    let options = crate::bench::BenchOptions {
        tiny: matches!(args.models, BenchModels::Tiny | BenchModels::Both),
        default: matches!(args.models, BenchModels::Default | BenchModels::Both),
        bundle: args.bundle,
        sampling,
        repeat: args.repeat,
        splats: args.splats,
        splat_level: args.splat_level,
        precisions: match args.precision {
            BenchPrecision::F32 => vec![Precision::F32],
            BenchPrecision::F16 => vec![Precision::F16],
            BenchPrecision::Both => vec![Precision::F32, Precision::F16],
        },
    };
    crate::bench::run(&gpu, &options, &mut std::io::stdout())
}

fn bake(args: BakeArgs) -> anyhow::Result<()> {
    let bar = progress::bar("baking {bar:40} {pos}/{len} frames, {left}", 0);
    let options = crate::dataset::bake::BakeOptions {
        description: args.avatar,
        clips: args.clips,
        quick: args.quick,
        preview: args.preview,
        no_renders: args.no_renders,
        switch_phases: args.switch_phases,
        render_every: Some(args.render_every as usize),
    };
    let start = std::time::Instant::now();
    let manifest =
        crate::dataset::bake::bake(&args.character, &args.out, &options, &|done, total| {
            bar.set_length(total);
            bar.set_position(done);
        })?;
    bar.finish_and_clear();
    let frames: usize = manifest.clips.iter().map(|c| c.frames).sum();
    println!(
        "baked {} clips, {frames} frames of {} into {} in {:.1} s ({} foreground pixels, {:.1}% of the surface seen)",
        manifest.clips.len(),
        manifest.avatar,
        args.out.display(),
        start.elapsed().as_secs_f64(),
        manifest.foreground_pixels,
        manifest.coverage["surface_seen"].as_f64().unwrap_or(0.0) * 100.0
    );
    // What the map gives the face and hands, against an even spread over the surface.
    if let Some(regions) = manifest.coverage["regions"].as_array() {
        let parts: Vec<String> = regions
            .iter()
            .map(|r| {
                format!(
                    "{} {} (an even share by area would be {:.0})",
                    r["name"].as_str().unwrap_or("?"),
                    r["pixels"],
                    r["fair_pixels"].as_f64().unwrap_or(0.0)
                )
            })
            .collect();
        println!("map pixels: {}", parts.join(", "));
    }
    Ok(())
}

fn render(args: RenderArgs, gpu: &GpuOptions) -> anyhow::Result<()> {
    use crate::gpu::kernel::Precision;
    use crate::headless::Avatar;
    let keys = KeyScript::parse(&args.keys).context("--keys")?;
    let avatar = match (args.teacher, args.bundle) {
        (Some(character), None) => Avatar::Teacher {
            character,
            clips: args.clips,
            description: args.avatar,
        },
        (None, Some(dir)) => {
            let manifest = crate::engine::bundle::read_manifest(&dir.join("manifest.json"))?;
            let sampling = manifest.sampler.chosen(args.steps, args.cfg_scale);
            sampling
                .check(manifest.diffusion.steps)
                .map_err(anyhow::Error::msg)?;
            Avatar::Bundle {
                dir,
                options: crate::engine::EngineOptions {
                    precision: if args.f16 {
                        Precision::F16
                    } else {
                        Precision::F32
                    },
                    seed: args.seed,
                    sampling: Some(sampling),
                    pca: !args.no_pca,
                    ..Default::default()
                },
            }
        }
        _ => bail!("give exactly one of --teacher CHARACTER or --bundle DIR"),
    };
    if args.points && matches!(avatar, Avatar::Teacher { .. }) {
        bail!("--points needs --bundle (the teacher has no position-map points)");
    }
    let gpu_context = GpuContext::headless(gpu)?;
    if args.f16 && !gpu_context.caps.shader_f16 {
        bail!(
            "{} has no SHADER_F16; leave out --f16",
            gpu_context.adapter_label()
        );
    }
    let job = crate::headless::RenderJob {
        avatar,
        keys,
        out: args.out,
        size: args.size,
        views: args.views,
        points: args.points,
        surface: args.surface,
        splat_level: args.look.splat_level,
        refine: !args.look.no_refiner,
    };
    let frames = render_with_bar(&job, gpu_context, "rendering")?;
    println!(
        "rendered {frames} frames x {} views into {}",
        job.views,
        job.out.display()
    );
    Ok(())
}

fn parse_fps(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(fps) if (1.0..=120.0).contains(&fps) => Ok(fps),
        _ => Err(format!(
            "'{text}' is not a rate between 1 and 120 frames per second"
        )),
    }
}

fn export(args: ExportArgs, gpu: &GpuOptions) -> anyhow::Result<()> {
    let keys = KeyScript::parse(&args.keys).context("--keys")?;
    let gpu = GpuContext::headless(gpu)?;
    let manifest = crate::engine::bundle::read_manifest(&args.bundle.join("manifest.json"))?;
    let options = crate::engine::EngineOptions {
        seed: args.seed,
        sampling: Some(manifest.sampler.chosen(args.steps, None)),
        ..Default::default()
    };
    let level = args
        .look
        .splat_level
        .unwrap_or_else(|| crate::engine::appearance::default_level(&gpu));
    let options = crate::engine::EngineOptions {
        splat_level: Some(level),
        refine: !args.look.no_refiner,
        ..options
    };
    let mut engine = crate::engine::Engine::new(&gpu, &args.bundle, &options)?;
    let bar = progress::bar("generating {bar:40} {pos}/{len} frames", keys.len() as u64);
    for i in 0..keys.len() {
        engine.frame(keys.action_at(i))?;
        engine.finish();
        bar.inc(1);
    }
    bar.finish_and_clear();
    let splats = if keys.is_empty() {
        let mut look = crate::engine::appearance::Appearance::new(
            &gpu,
            &engine.bundle,
            options.precision,
            level,
        )?;
        look.refine &= !args.look.no_refiner;
        look.splats(&engine.bundle, &engine.standing_points())?
    } else {
        engine.read_splats()?
    };
    let format = match args.format.as_str() {
        "splat" => files::Format::Splat,
        _ => files::Format::Ply,
    };
    files::write(&args.out, &splats, format, args.up)?;
    println!("wrote {} splats to {}", splats.len(), args.out.display());
    Ok(())
}

fn view(args: ViewArgs, gpu: GpuOptions) -> anyhow::Result<()> {
    if args.exit_after == Some(0) {
        bail!("--exit-after must be at least 1");
    }
    // Refuse an unreadable file before the window opens, and say what was dropped.
    let kept = files::read(&args.file, args.up)?;
    if let Some(note) = kept.note() {
        eprintln!("warning: {}: {note}", args.file.display());
    }
    app::run(AppOptions {
        splats: Some(args.file),
        splat_up: args.up,
        exit_after: args.exit_after,
        exit_after_seconds: None,
        screenshot: args.screenshot,
        record_fps: crate::app::recorder::DEFAULT_FPS,
        gpu,
        ..Default::default()
    })
}

fn play(cli: Cli, gpu: GpuOptions) -> anyhow::Result<()> {
    let (bundle, character) = match (cli.bundle, cli.character) {
        // A shipped bundle plays beside its teacher unless --character says otherwise.
        (Some(bundle), character) => {
            let character = character.or_else(|| shipped_teacher(&bundle));
            (Some(bundle), character)
        }
        (None, Some(character)) => (None, Some(character)),
        (None, None) => (default_bundle(), default_character()),
    };
    if let Some(dir) = &bundle {
        // Refuse a broken bundle before the window opens (the worker loads it again).
        crate::engine::bundle::read_manifest(&dir.join("manifest.json"))?;
    }
    let keys = cli
        .keys
        .as_deref()
        .map(KeyScript::parse)
        .transpose()
        .context("--keys")?;
    if cli.exit_after == Some(0) {
        bail!("--exit-after must be at least 1");
    }
    if let Some(s) = cli
        .exit_after_seconds
        .filter(|s| !(s.is_finite() && *s > 0.0))
    {
        bail!("--exit-after-seconds {s}: a positive number of seconds is needed");
    }
    if cli.screenshot.is_some() && cli.exit_after.is_none() && cli.exit_after_seconds.is_none() {
        bail!("--screenshot needs --exit-after N or --exit-after-seconds S (when to take it)");
    }
    let record_dir = cli.record_dir.unwrap_or_else(|| {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        PathBuf::from(format!("recordings/session-{secs}"))
    });
    app::run(AppOptions {
        bundle,
        avatars: shipped_avatars(),
        splats: None,
        splat_up: Up::Y,
        character,
        clips: cli.clips,
        keys,
        exit_after: cli.exit_after,
        exit_after_seconds: cli.exit_after_seconds,
        steps: cli.steps.map(|s| s as usize),
        screenshot: cli.screenshot,
        record_dir,
        record: cli.record,
        record_fps: cli.record_fps,
        stress_resize: cli.stress_resize,
        stress_lose_device: cli.stress_lose_device,
        gpu,
    })
}

fn adapters(options: &GpuOptions) -> anyhow::Result<()> {
    let adapters = pollster::block_on(gpu::enumerate_adapters());
    let chosen = gpu::select_adapter(&adapters, None, options)?;
    for adapter in &adapters {
        let info = adapter.get_info();
        let caps = gpu::Capabilities::for_adapter(adapter, options);
        let mark = if info == chosen.get_info() { "*" } else { " " };
        println!(
            "{mark} {} ({:?}, {:?}, driver {}): f16 {}, subgroups {}, timestamps {}, max storage binding {} MiB",
            info.name,
            info.backend,
            info.device_type,
            info.driver,
            caps.shader_f16,
            caps.subgroups,
            caps.timestamps,
            adapter.limits().max_storage_buffer_binding_size >> 20
        );
    }
    println!("* = used by unica");
    Ok(())
}
