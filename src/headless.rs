//! Headless scripted sessions (`unica render`): an avatar — the teacher or the neural
//! avatar of a bundle — driven by a key script, drawn from cameras that follow it,
//! written as numbered PNGs per view plus manifest.json (actions, world root path per
//! frame, cameras, timings; for the neural avatar also the sampler, clamped values and
//! per-stage timings) and optionally one point cloud (.ply) per frame.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;

use crate::action::{Action, KeyScript};
use crate::avatar::description::Description;
use crate::avatar::load_character_with;
use crate::avatar::teacher::Teacher;
use crate::engine::appearance;
use crate::engine::surface::MapSurface;
use crate::engine::{Engine, EngineOptions};
use crate::files::{write_atomic, write_png_atomic};
use crate::gpu::GpuContext;
use crate::mesh::Mesh;
use crate::render::OrbitCamera;
use crate::render::offscreen::Offscreen;
use crate::render::scene::{DrawOptions, character_light};

/// Who is rendered.
pub enum Avatar {
    Teacher {
        character: PathBuf,
        /// Animation libraries merged into the character's clips (`--clips`).
        clips: Vec<PathBuf>,
        description: Option<PathBuf>,
    },
    Bundle {
        dir: PathBuf,
        options: EngineOptions,
    },
}

pub struct RenderJob {
    pub avatar: Avatar,
    pub keys: KeyScript,
    pub out: PathBuf,
    pub size: u32,
    pub views: u32,
    /// Also write each frame's points as frame_NNNNN.ply (neural avatar only).
    pub points: bool,
    /// Draw the neural avatar as its triangulated map surface instead of splats.
    pub surface: bool,
    /// The neural avatar's splat level (see `engine::appearance`); `None` picks the
    /// adapter's default.
    pub splat_level: Option<usize>,
    /// Apply the bundle's refiner (when it has one).
    pub refine: bool,
}

#[derive(serde::Serialize)]
struct FrameRecord {
    index: usize,
    action: Action,
    root: [f32; 3],
    files: Vec<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    clamped: Option<usize>,
}

/// The avatar being driven, frame by frame.
enum Driver {
    Teacher(Box<Teacher>),
    Neural(Box<Engine>, MapSurface),
}

/// One step's result: the mesh to draw (and for the neural avatar the engine's splat
/// buffer and count), the root, and for the neural avatar its points, clamped values and
/// (frame, cpu) ms.
struct Step {
    mesh: Mesh,
    splats: Option<(wgpu::Buffer, usize)>,
    root: Vec3,
    neural: Option<(Vec<Vec3>, usize, [f64; 2])>,
}

impl Driver {
    fn new(job: &RenderJob, gpu: &GpuContext) -> anyhow::Result<Self> {
        let avatar = &job.avatar;
        Ok(match avatar {
            Avatar::Teacher {
                character,
                clips,
                description,
            } => {
                let character = load_character_with(character, clips)?;
                let description = Description::find(&character, description.as_deref())?;
                Driver::Teacher(Box::new(Teacher::new(character, description)?))
            }
            Avatar::Bundle { dir, options } => {
                let level = job
                    .splat_level
                    .unwrap_or_else(|| appearance::default_level(gpu));
                let options = EngineOptions {
                    splat_level: (!job.surface).then_some(level),
                    refine: job.refine,
                    ..options.clone()
                };
                let engine = Engine::new(gpu, dir, &options)?;
                let surface = engine.surface();
                Driver::Neural(Box::new(engine), surface)
            }
        })
    }

    /// Steps the avatar (the neural one makes its splats on the GPU as part of the
    /// frame, when asked for at load).
    fn step(&mut self, action: Action) -> anyhow::Result<Step> {
        Ok(match self {
            Driver::Teacher(teacher) => {
                teacher.step(action);
                Step {
                    mesh: teacher.mesh(),
                    splats: None,
                    root: teacher.root(),
                    neural: None,
                }
            }
            Driver::Neural(engine, surface) => {
                let frame = engine.step(action)?;
                Step {
                    splats: engine.splats().map(|(b, n)| (b.clone(), n)),
                    mesh: surface.mesh(&frame.points),
                    root: frame.root,
                    neural: Some((frame.points, frame.clamped, [frame.gpu_ms, frame.cpu_ms])),
                }
            }
        })
    }
}

/// Renders the session; `progress` is told each frame. Returns the frames written.
pub fn render(
    job: &RenderJob,
    gpu: GpuContext,
    progress: &dyn Fn(u64, u64),
) -> anyhow::Result<usize> {
    let mut driver = Driver::new(job, &gpu)?;
    std::fs::create_dir_all(&job.out).map_err(|e| anyhow::anyhow!("{}: {e}", job.out.display()))?;
    let mut offscreen = Offscreen::new(gpu, job.size, job.size);
    let yaws: Vec<f32> = (0..job.views)
        .map(|k| std::f32::consts::PI + std::f32::consts::TAU * k as f32 / job.views as f32)
        .collect();
    let (mut step_ms, mut render_ms, mut write_ms) = (0.0, 0.0, 0.0);
    let (mut model_ms, mut clamped_total) = ([0.0; 2], 0);
    let mut distance = None;
    let mut frames = Vec::new();
    let total = job.keys.len();
    for index in 0..total {
        let action = job.keys.action_at(index);
        let clock = Instant::now();
        let step = driver.step(action)?;
        step_ms += clock.elapsed().as_secs_f64() * 1e3;
        let (lo, hi) = step.mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE));
        let distance = *distance.get_or_insert_with(|| {
            // The whole first frame's bounding sphere in view, with room for the motion.
            let sphere =
                1.15 * (hi - lo).length() * 0.5 / (crate::render::camera::FOV_Y * 0.5).sin();
            ((hi - lo).max_element() * 1.8).max(sphere)
        });
        // The teacher is framed head to feet (the root's ground position, the mesh's
        // vertical middle); the neural avatar follows its root.
        let target = match &driver {
            Driver::Teacher(_) => Vec3::new(step.root.x, (lo.y + hi.y) * 0.5, step.root.z),
            Driver::Neural(..) => step.root,
        };
        let mut files = Vec::new();
        for (k, &yaw) in yaws.iter().enumerate() {
            let camera = OrbitCamera {
                target,
                yaw,
                pitch: 0.2,
                distance,
            };
            let clock = Instant::now();
            let image = match &step.splats {
                Some((buffer, count)) => {
                    offscreen.render_splats(buffer, *count, &camera, &DrawOptions::default())?
                }
                None => {
                    // The teacher in the light its renders were baked with.
                    let light = match &driver {
                        Driver::Teacher(teacher) => Some(character_light(teacher.locomotion.yaw)),
                        Driver::Neural(..) => None,
                    };
                    let options = DrawOptions {
                        light,
                        ..DrawOptions::default()
                    };
                    offscreen.render(&step.mesh, &camera, &options)?
                }
            };
            render_ms += clock.elapsed().as_secs_f64() * 1e3;
            let clock = Instant::now();
            let file = format!("frame_{index:05}_v{k}.png");
            write_png_atomic(&job.out.join(&file), &image)?;
            write_ms += clock.elapsed().as_secs_f64() * 1e3;
            files.push(file);
        }
        let mut clamped = None;
        if let Some((points, frame_clamped, ms)) = &step.neural {
            for (total, part) in model_ms.iter_mut().zip(ms) {
                *total += part;
            }
            clamped_total += frame_clamped;
            clamped = Some(*frame_clamped);
            if job.points {
                let file = format!("frame_{index:05}.ply");
                write_atomic(&job.out.join(&file), &ply(points))?;
                files.push(file);
            }
        }
        frames.push(FrameRecord {
            index,
            action,
            root: step.root.to_array(),
            files,
            clamped,
        });
        progress(index as u64 + 1, total as u64);
    }
    let source = match (&job.avatar, &driver) {
        (Avatar::Teacher { character, .. }, _) => {
            serde_json::json!({ "teacher": character.display().to_string() })
        }
        (Avatar::Bundle { dir, options }, Driver::Neural(engine, _)) => serde_json::json!({
            "bundle": dir.display().to_string(),
            "seed": options.seed,
            "ddim_steps": engine.sampling().steps,
            "cfg_scale": engine.sampling().cfg_scale,
            "guide_idle": engine.sampling().guide_idle,
            "noise_scale": engine.sampling().noise_scale,
            "idle_cfg_scale": engine.sampling().idle_cfg_scale,
            "idle_brake_cfg_scale": engine.sampling().idle_brake_cfg_scale,
            "idle_brake_frames": engine.sampling().idle_brake_frames,
            "turn_brake_cfg_scale": engine.sampling().turn_brake_cfg_scale,
            "turn_brake_frames": engine.sampling().turn_brake_frames,
            "pca": options.pca,
            "splat_level": engine.splat_level(),
            "splats_per_frame": engine.splats().map(|(_, n)| n),
            "refiner": engine.refine(),
            "clamped_values": clamped_total,
        }),
        _ => unreachable!("the driver follows the avatar"),
    };
    let manifest = serde_json::json!({
        "source": source,
        "frame_rate": crate::avatar::locomotion::FRAME_RATE,
        "size": job.size,
        "view_yaws": yaws,
        "camera": { "pitch": 0.2, "distance": distance, "target": match job.avatar {
            Avatar::Teacher { .. } => "above the root of each frame, at the mesh's vertical middle",
            Avatar::Bundle { .. } => "the root of each frame",
        } },
        "frames": frames,
        "timings_ms": {
            "step": step_ms, "render": render_ms, "write": write_ms,
            "model_and_splats": model_ms[0], "model_cpu": model_ms[1],
        },
    });
    write_atomic(
        &job.out.join("manifest.json"),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?;
    Ok(total)
}

/// The teacher's world root after each step of `keys` (geometry only, no pictures).
pub fn teacher_roots(
    character: &std::path::Path,
    clips: &[PathBuf],
    keys: &KeyScript,
) -> anyhow::Result<Vec<Vec3>> {
    let loaded = load_character_with(character, clips)?;
    let description = Description::find(&loaded, None)?;
    let mut teacher = Teacher::new(loaded, description)?;
    Ok((0..keys.len())
        .map(|i| {
            teacher.step(keys.action_at(i));
            teacher.root()
        })
        .collect())
}

/// A binary little-endian PLY with x y z per point.
fn ply(points: &[Vec3]) -> Vec<u8> {
    let mut out = Vec::new();
    write!(
        out,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    )
    .expect("writing to memory");
    for p in points {
        out.extend(bytemuck::cast_slice(&p.to_array()));
    }
    out
}
