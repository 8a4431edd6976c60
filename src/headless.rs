//! Headless scripted sessions (`unica render`): an avatar driven by a key script, drawn
//! from cameras that follow it, written as numbered PNGs per view plus manifest.json
//! (actions, world root path, cameras, timings). Today the teacher; the neural avatar
//! joins when the live model lands.

use std::path::PathBuf;
use std::time::Instant;

use crate::action::KeyScript;
use crate::avatar::description::Description;
use crate::avatar::load_character;
use crate::avatar::teacher::Teacher;
use crate::files::{write_atomic, write_png_atomic};
use crate::gpu::GpuContext;
use crate::render::OrbitCamera;
use crate::render::offscreen::Offscreen;
use crate::render::scene::DrawOptions;

pub struct RenderJob {
    pub character: PathBuf,
    pub description: Option<PathBuf>,
    pub keys: KeyScript,
    pub out: PathBuf,
    pub size: u32,
    pub views: u32,
}

#[derive(serde::Serialize)]
struct FrameRecord {
    index: usize,
    action: crate::action::Action,
    root: [f32; 3],
    files: Vec<String>,
}

/// Renders the session; `progress` is told each frame. Returns the frames written.
pub fn render_teacher(
    job: &RenderJob,
    gpu: GpuContext,
    progress: &dyn Fn(u64, u64),
) -> anyhow::Result<usize> {
    let character = load_character(&job.character)?;
    let description = Description::find(&character, job.description.as_deref())?;
    let mut teacher = Teacher::new(character, description)?;
    std::fs::create_dir_all(&job.out).map_err(|e| anyhow::anyhow!("{}: {e}", job.out.display()))?;
    let mut offscreen = Offscreen::new(gpu, job.size, job.size);
    let (lo, hi) = teacher.mesh().bounds().expect("a character has vertices");
    let distance = (hi - lo).max_element() * 1.8;
    let yaws: Vec<f32> = (0..job.views)
        .map(|k| std::f32::consts::PI + std::f32::consts::TAU * k as f32 / job.views as f32)
        .collect();
    let (mut step_ms, mut render_ms, mut write_ms) = (0.0, 0.0, 0.0);
    let mut frames = Vec::new();
    let total = job.keys.len();
    for index in 0..total {
        let action = job.keys.action_at(index);
        let clock = Instant::now();
        teacher.step(action);
        let mesh = teacher.mesh();
        step_ms += clock.elapsed().as_secs_f64() * 1e3;
        let root = teacher.root();
        let mut files = Vec::new();
        for (k, &yaw) in yaws.iter().enumerate() {
            let camera = OrbitCamera {
                target: root,
                yaw,
                pitch: 0.2,
                distance,
            };
            let clock = Instant::now();
            let image = offscreen.render(&mesh, &camera, &DrawOptions::default())?;
            render_ms += clock.elapsed().as_secs_f64() * 1e3;
            let clock = Instant::now();
            let file = format!("frame_{index:05}_v{k}.png");
            write_png_atomic(&job.out.join(&file), &image)?;
            write_ms += clock.elapsed().as_secs_f64() * 1e3;
            files.push(file);
        }
        frames.push(FrameRecord {
            index,
            action,
            root: root.to_array(),
            files,
        });
        progress(index as u64 + 1, total as u64);
    }
    let manifest = serde_json::json!({
        "source": "teacher",
        "character": job.character.display().to_string(),
        "frame_rate": crate::avatar::locomotion::FRAME_RATE,
        "size": job.size,
        "view_yaws": yaws,
        "camera": { "pitch": 0.2, "distance": distance, "target": "the root of each frame" },
        "frames": frames,
        "timings_ms": { "teacher": step_ms, "render": render_ms, "write": write_ms },
    });
    write_atomic(
        &job.out.join("manifest.json"),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?;
    Ok(total)
}
