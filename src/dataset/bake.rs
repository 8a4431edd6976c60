//! `unica bake`: drives the teacher through the transition table — a standing start, then
//! every ordered pair of distinct actions (3-5 s of the first, 5 s of the second) — and
//! writes the dataset. Deterministic: the same inputs give the same bytes.

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::{ANCHOR, ClipInfo, DatasetManifest, FORMAT, GROUP, VERSION};
use crate::action::Action;
use crate::avatar::description::Description;
use crate::avatar::load_character_with;
use crate::avatar::locomotion::FRAME_RATE;
use crate::avatar::reference::Reference;
use crate::avatar::teacher::Teacher;
use crate::files::{write_atomic, write_png_atomic};
use crate::gpu::{GpuContext, GpuOptions};
use crate::mesh::Mesh;
use crate::posmap::{GroupNorm, MAP_SIZE};
use crate::render::OrbitCamera;
use crate::render::offscreen::Offscreen;
use crate::render::scene::DrawOptions;
use crate::tensors::{self, TensorData};

/// The preview shows the middle frame of every third clip.
const PREVIEW_EVERY: usize = 3;

#[derive(Clone, Debug, Default)]
pub struct BakeOptions {
    /// Animation libraries (glTF/GLB) whose clips join the character's, by joint name.
    pub clips: Vec<PathBuf>,
    /// An explicit avatar description instead of the one found for the character.
    pub description: Option<PathBuf>,
    /// A few short clips (tests, smoke runs) instead of the full table.
    pub quick: bool,
    /// Also write preview.png: position maps and posed point clouds of sampled frames.
    pub preview: bool,
    /// Skip the ground-truth RGB renders (which need a GPU adapter, lavapipe will do).
    pub no_renders: bool,
    /// Where nonzero, bake [`switch_plan`] with this many phases instead of the table.
    pub switch_phases: usize,
    /// Render every this many frames [default: [`RENDER_EVERY`]]; 1 renders every pose
    /// (the evaluation's free-running comparison then finds its nearest pose among all).
    pub render_every: Option<usize>,
}

/// Ground-truth renders: size, every how many frames by default (training needs no
/// more), and the rest-pose cameras.
pub const RENDER_SIZE: u32 = 512;
pub const RENDER_EVERY: usize = 5;
const REST_CAMERAS: usize = 50;
/// Direction toward the light in the character's frame (it faces +Z).
const LIGHT: Vec3 = crate::render::scene::CHARACTER_LIGHT;

/// One clip of the plan: (first action, second action, frames of each).
type Planned = (Action, Action, usize, usize);

/// Frames between the key changes of successive [`switch_plan`] clips of one pair.
pub const PHASE_STEP: usize = 3;

/// Extra training data for key changes at every gait phase (the table changes key at 3,
/// 4 or 5 s, so each transition is seen at one phase of the stride, and a model trained
/// long on it turned only from those phases: pressed elsewhere, the Witch ran on for up
/// to 16 frames before turning). Each change from or to Forward — the others are
/// its quarter turns, which the trainer's `quarter_turns` supplies — `phases` times, the
/// key changed at 3 s + k·[`PHASE_STEP`] frames (k = 1..=phases), then 2 s of the second.
pub fn switch_plan(phases: usize) -> Vec<Planned> {
    use Action::{Backward, Forward, Idle, Left, Right};
    let pairs = [
        (Forward, Backward),
        (Forward, Left),
        (Forward, Right),
        (Forward, Idle),
        (Idle, Forward),
    ];
    let first = 3 * FRAME_RATE as usize;
    let second = 2 * FRAME_RATE as usize;
    pairs
        .iter()
        .flat_map(|&(a, b)| (1..=phases).map(move |k| (a, b, first + k * PHASE_STEP, second)))
        .collect()
}

/// The transition table: a standing start, then all 20 ordered pairs of distinct actions.
pub fn plan(quick: bool) -> Vec<Planned> {
    if quick {
        return vec![
            (Action::Idle, Action::Idle, 8, 0),
            (Action::Idle, Action::Forward, 6, 12),
            (Action::Forward, Action::Left, 12, 12),
            (Action::Forward, Action::Backward, 12, 14),
        ];
    }
    let second = 5 * FRAME_RATE as usize;
    let mut clips = vec![(Action::Idle, Action::Idle, 3 * FRAME_RATE as usize, 0)];
    for a in Action::ALL {
        for b in Action::ALL {
            if a != b {
                let first = (3 + clips.len() % 3) * FRAME_RATE as usize;
                clips.push((a, b, first, second));
            }
        }
    }
    clips
}

/// Bakes `character` into `out` (created if needed); `progress` is told each frame.
pub fn bake(
    character: &Path,
    out: &Path,
    options: &BakeOptions,
    progress: &dyn Fn(u64, u64),
) -> anyhow::Result<DatasetManifest> {
    let loaded = load_character_with(character, &options.clips)?;
    let description = Description::find(&loaded, options.description.as_deref())?;
    let start = Teacher::new(loaded, description)?;
    let mut reference = Reference::new(&start)?;
    let coverage = reference.report(&start);
    let clips_dir = out.join("clips");
    std::fs::create_dir_all(&clips_dir)
        .map_err(|e| anyhow::anyhow!("{}: {e}", clips_dir.display()))?;
    write_reference(&start, &reference, &out.join("reference.safetensors"))?;

    let render_every = options.render_every.unwrap_or(RENDER_EVERY).max(1);
    let mut renders = if options.no_renders {
        None
    } else {
        let gpu = GpuContext::headless(&GpuOptions::from_env())?;
        Some(GroundTruth::new(gpu, out, &start)?)
    };
    let plan = if options.switch_phases > 0 {
        switch_plan(options.switch_phases)
    } else {
        plan(options.quick)
    };
    let total: usize = plan.iter().map(|(_, _, a, b)| a + b).sum();
    let mut done = 0;
    let mut clips = Vec::new();
    let mut previews = Vec::new();
    let mut reach = 0.0f32;
    let bones = start.character.rig.bones.len();
    // The clips are independent runs of the teacher from the same start: they run on
    // every core, a batch of them at a time, and are written (and rendered, on the one
    // GPU) in order, so the dataset is the same whatever the number of cores.
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let wanted = ClipWants {
        render_every: renders.as_ref().map(|_| render_every),
        preview: options.preview,
    };
    for (b, entries) in plan.chunks(workers).enumerate() {
        let first_index = b * workers;
        let runs: Vec<ClipRun> = std::thread::scope(|scope| {
            let handles: Vec<_> = entries
                .iter()
                .enumerate()
                .map(|(k, &entry)| {
                    let (start, reference, wanted) = (&start, &reference, &wanted);
                    scope.spawn(move || run_clip(start, reference, first_index + k, entry, wanted))
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("a clip's teacher run panicked"))
                .collect()
        });
        for (k, (run, &(first, second, first_frames, _))) in
            runs.into_iter().zip(entries).enumerate()
        {
            let index = first_index + k;
            if let Some(renders) = renders.as_mut() {
                for (f, mesh, facing) in &run.renders {
                    renders.frame(index, *f, mesh, *facing)?;
                }
            }
            previews.extend(run.previews);
            reach = reach.max(GroupNorm::reach(&run.bounds, &run.roots, GROUP, ANCHOR));
            let frames = run.actions.len();
            let file = format!("clips/clip_{index:03}.safetensors");
            let flat_roots: Vec<f32> = run.roots.iter().flat_map(|r| r.to_array()).collect();
            tensors::write(
                &out.join(&file),
                &[
                    ("skin", TensorData::f32(&[frames, bones, 3, 4], &run.skin)),
                    ("actions", TensorData::i32(&[frames], &run.actions)),
                    ("root", TensorData::f32(&[frames, 3], &flat_roots)),
                ],
            )?;
            clips.push(ClipInfo {
                file,
                frames,
                first,
                second,
                switch_frame: first_frames,
            });
            done += frames;
            progress(done as u64, total as u64);
        }
    }
    if let Some(renders) = renders {
        renders.finish(render_every)?;
    }
    // Every group inside the unit cube with a margin, whatever the proportions (the
    // Witch's motion fits at the extent's scale, which stays).
    reference.norm = reference.norm.fitted(reach);
    let p = start.locomotion.params;
    let manifest = DatasetManifest {
        format: FORMAT.into(),
        version: VERSION,
        avatar: start.character.name.clone(),
        character: character.display().to_string(),
        clip_files: options
            .clips
            .iter()
            .map(|c| c.display().to_string())
            .collect(),
        frame_rate: FRAME_RATE,
        actions: Action::ALL.iter().map(|a| a.to_string()).collect(),
        map_size: MAP_SIZE,
        foreground_pixels: reference.table.len(),
        vertices: start.character.skinned.bind.positions.len(),
        bones: start.character.rig.bones.len(),
        norm_scale: reference.norm.scale,
        walk_speed: p.walk_speed,
        run_speed: p.run_speed,
        clips,
        coverage: serde_json::to_value(&coverage)?,
    };
    write_atomic(
        &out.join("manifest.json"),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?;
    if options.preview {
        write_png_atomic(
            &out.join("preview.png"),
            &contact_sheet(&reference, &previews),
        )?;
    }
    Ok(manifest)
}

/// What a clip's run should keep beyond the dataset: meshes to render (every this many
/// frames) and the middle frame for the preview.
struct ClipWants {
    render_every: Option<usize>,
    preview: bool,
}

/// One clip's teacher run: the dataset's tensors (flat skinning matrices, actions, roots),
/// each frame's bounds, and the frames to render (frame, mesh, facing) and preview.
struct ClipRun {
    skin: Vec<f32>,
    actions: Vec<i32>,
    roots: Vec<Vec3>,
    bounds: Vec<(Vec3, Vec3)>,
    renders: Vec<(usize, Mesh, f32)>,
    previews: Vec<(Vec<Vec3>, Vec<Vec3>, Vec3)>,
}

/// Runs the teacher from `start` through one clip of the plan.
fn run_clip(
    start: &Teacher,
    reference: &Reference,
    index: usize,
    (first, second, first_frames, second_frames): (Action, Action, usize, usize),
    wanted: &ClipWants,
) -> ClipRun {
    let mut teacher = start.clone();
    let frames = first_frames + second_frames;
    let mesh_indices = &start.character.skinned.bind.indices;
    let mut run = ClipRun {
        skin: Vec::new(),
        actions: Vec::new(),
        roots: Vec::new(),
        bounds: Vec::new(),
        renders: Vec::new(),
        previews: Vec::new(),
    };
    for f in 0..frames {
        let action = if f < first_frames { first } else { second };
        // Frame f is the pose before step f; its action moves it to frame f + 1.
        let mesh = teacher.mesh();
        let points = reference.gather(&mesh.positions, mesh_indices);
        let root = GroupNorm::root(&points, &reference.waist);
        run.roots.push(root);
        run.bounds.push(points.iter().fold(
            (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        ));
        for m in teacher.skin_matrices() {
            run.skin
                .extend_from_slice(&m.transpose().to_cols_array()[..12]);
        }
        run.actions.push(action.id() as i32);
        let preview = wanted.preview && f == frames / 2 && index.is_multiple_of(PREVIEW_EVERY);
        if preview {
            run.previews.push((mesh.positions.clone(), points, root));
        }
        if wanted.render_every.is_some_and(|every| f % every == 0) {
            run.renders.push((f, mesh, teacher.locomotion.yaw));
        }
        teacher.step(action);
    }
    run
}

/// Writes the ground-truth RGB renders: RGBA PNGs (alpha = coverage, so black and white
/// backgrounds are both a composite away) from four cameras around the character (front,
/// right, back, left in its own frame) with a light fixed in its frame, and 50 cameras
/// on a cylinder around the rest pose; every camera in renders/cameras.json.
struct GroundTruth {
    offscreen: Offscreen,
    dir: PathBuf,
    extent: f32,
    cameras: Vec<serde_json::Value>,
    writer: PngWriter,
}

/// Encodes and writes PNGs on every core but one while the GPU draws the next: a 512²
/// render encodes in about as long as it takes to draw on a GPU. Errors come back at
/// [`PngWriter::finish`] (the first one, naming its file).
struct PngWriter {
    queue: Option<std::sync::mpsc::SyncSender<(PathBuf, image::RgbaImage)>>,
    workers: Vec<std::thread::JoinHandle<Result<(), crate::files::WriteError>>>,
}

impl PngWriter {
    fn new() -> Self {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let count = cores.saturating_sub(1).max(1);
        let (queue, jobs) = std::sync::mpsc::sync_channel::<(PathBuf, image::RgbaImage)>(2 * count);
        let jobs = std::sync::Arc::new(std::sync::Mutex::new(jobs));
        let workers = (0..count)
            .map(|_| {
                let jobs = jobs.clone();
                std::thread::spawn(move || {
                    loop {
                        let job = jobs.lock().expect("the PNG queue").recv();
                        let Ok((path, image)) = job else {
                            return Ok(());
                        };
                        write_png_atomic(&path, &image)?;
                    }
                })
            })
            .collect();
        Self {
            queue: Some(queue),
            workers,
        }
    }

    fn write(&mut self, path: PathBuf, image: image::RgbaImage) -> anyhow::Result<()> {
        let queue = self.queue.as_ref().expect("writing before finish");
        if queue.send((path, image)).is_err() {
            // Every worker stopped, on an error: report the first, naming its file.
            self.join()?;
            anyhow::bail!("the PNG writers stopped");
        }
        Ok(())
    }

    /// Waits for every PNG; the first error, if any.
    fn finish(mut self) -> anyhow::Result<()> {
        Ok(self.join()?)
    }

    fn join(&mut self) -> Result<(), crate::files::WriteError> {
        drop(self.queue.take());
        let mut first = Ok(());
        for worker in self.workers.drain(..) {
            let result = worker.join().expect("a PNG writer panicked");
            if first.is_ok() {
                first = result;
            }
        }
        first
    }
}

impl GroundTruth {
    fn new(gpu: GpuContext, out: &Path, start: &Teacher) -> anyhow::Result<Self> {
        let dir = out.join("renders");
        let rest = start.mesh();
        let (lo, hi) = rest.bounds().expect("a character has vertices");
        let mut truth = Self {
            offscreen: Offscreen::new(gpu, RENDER_SIZE, RENDER_SIZE),
            dir,
            extent: (hi - lo).max_element(),
            cameras: Vec::new(),
            writer: PngWriter::new(),
        };
        let centre = (lo + hi) * 0.5;
        for k in 0..REST_CAMERAS {
            // 10 headings on each of 5 heights of a cylinder.
            let yaw = std::f32::consts::TAU * (k % 10) as f32 / 10.0;
            let pitch = -0.4 + 0.2 * (k / 10) as f32;
            let camera = truth.camera(centre, yaw, pitch);
            truth.shoot(&format!("rest/cam_{k:02}.png"), &rest, camera, LIGHT, None)?;
        }
        Ok(truth)
    }

    fn camera(&self, target: Vec3, yaw: f32, pitch: f32) -> OrbitCamera {
        OrbitCamera {
            target,
            yaw,
            pitch,
            distance: self.extent * 1.6,
        }
    }

    fn shoot(
        &mut self,
        file: &str,
        mesh: &Mesh,
        camera: OrbitCamera,
        light: Vec3,
        frame: Option<(usize, usize)>,
    ) -> anyhow::Result<()> {
        let options = DrawOptions {
            grid: false,
            background: wgpu::Color::TRANSPARENT,
            light: Some(light),
        };
        let image = self.offscreen.render(mesh, &camera, &options)?;
        let path = self.dir.join(file);
        if let Some(folder) = path.parent().filter(|f| !f.is_dir()) {
            std::fs::create_dir_all(folder)
                .map_err(|e| anyhow::anyhow!("{}: {e}", folder.display()))?;
        }
        self.writer.write(path, image)?;
        self.cameras.push(serde_json::json!({
            "file": file,
            "clip_frame": frame,
            "camera": camera,
            "view_projection": camera.view_projection(1.0).to_cols_array(),
        }));
        Ok(())
    }

    fn frame(&mut self, clip: usize, frame: usize, mesh: &Mesh, facing: f32) -> anyhow::Result<()> {
        let light = crate::render::scene::character_light(facing);
        let (lo, hi) = mesh.bounds().expect("a character has vertices");
        for (view, name) in ["front", "right", "back", "left"].iter().enumerate() {
            // Yaw 0 looks from +Z: a camera at the character's facing sees its front.
            let yaw = facing - view as f32 * std::f32::consts::FRAC_PI_2;
            let camera = self.camera((lo + hi) * 0.5, yaw, 0.1);
            self.shoot(
                &format!("clip_{clip:03}/f{frame:04}_{name}.png"),
                mesh,
                camera,
                light,
                Some((clip, frame)),
            )?;
        }
        Ok(())
    }

    fn finish(self, every: usize) -> anyhow::Result<()> {
        self.writer.finish()?;
        let json =
            serde_json::json!({ "size": RENDER_SIZE, "every": every, "cameras": self.cameras });
        write_atomic(
            &self.dir.join("cameras.json"),
            serde_json::to_string_pretty(&json)?.as_bytes(),
        )?;
        Ok(())
    }
}

fn write_reference(teacher: &Teacher, reference: &Reference, path: &Path) -> anyhow::Result<()> {
    let s = &teacher.character.skinned;
    let flat3 = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array()).collect::<Vec<f32>>();
    let n = reference.table.len();
    let v = s.bind.positions.len();
    let as_i32 = |v: &[u32]| v.iter().map(|&x| x as i32).collect::<Vec<i32>>();
    tensors::write(
        path,
        &[
            (
                "bind_positions",
                TensorData::f32(&[v, 3], &flat3(&s.bind.positions)),
            ),
            ("colors", TensorData::f32(&[v, 3], &flat3(&s.bind.colors))),
            (
                "joints",
                TensorData::i32(
                    &[v, 4],
                    &s.joints
                        .iter()
                        .flat_map(|j| j.map(i32::from))
                        .collect::<Vec<_>>(),
                ),
            ),
            (
                "weights",
                TensorData::f32(
                    &[v, 4],
                    &s.weights.iter().flatten().copied().collect::<Vec<_>>(),
                ),
            ),
            (
                "triangles",
                TensorData::i32(&[s.bind.indices.len() / 3, 3], &as_i32(&s.bind.indices)),
            ),
            (
                "pixels",
                TensorData::i32(&[n], &as_i32(&reference.table.pixels)),
            ),
            (
                "pixel_triangles",
                TensorData::i32(&[n], &as_i32(&reference.table.triangles)),
            ),
            (
                "barycentrics",
                TensorData::f32(
                    &[n, 3],
                    &reference
                        .table
                        .barycentrics
                        .iter()
                        .flatten()
                        .copied()
                        .collect::<Vec<_>>(),
                ),
            ),
            (
                "waist",
                TensorData::i32(&[reference.waist.len()], &as_i32(&reference.waist)),
            ),
        ],
    )?;
    Ok(())
}

/// One row per sampled frame: its position map (normalised around its own root, xyz as
/// rgb) and the posed mesh's vertices seen from the front and from the side.
fn contact_sheet(
    reference: &Reference,
    frames: &[(Vec<Vec3>, Vec<Vec3>, Vec3)],
) -> image::RgbaImage {
    const TILE: u32 = 256;
    let mut sheet = image::RgbaImage::from_pixel(
        3 * TILE,
        TILE * frames.len().max(1) as u32,
        image::Rgba([0, 0, 0, 255]),
    );
    for (row, (vertices, points, root)) in frames.iter().enumerate() {
        let y0 = row as u32 * TILE;
        let unit = reference.norm.to_unit(points, *root);
        for (&pixel, p) in reference.table.pixels.iter().zip(&unit) {
            let (r, c) = (pixel / MAP_SIZE as u32, pixel % MAP_SIZE as u32);
            let rgb = p.clamp(Vec3::ZERO, Vec3::ONE) * 255.0;
            for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                sheet.put_pixel(
                    2 * c + dx,
                    y0 + 2 * r + dy,
                    image::Rgba([rgb.x as u8, rgb.y as u8, rgb.z as u8, 255]),
                );
            }
        }
        for (tile, axis) in [(1u32, Vec3::X), (2, Vec3::Z)] {
            for v in vertices {
                let q = reference.norm.to_unit(&[*v], *root)[0];
                let (x, y) = (q.dot(axis), 1.0 - q.y);
                if (0.0..1.0).contains(&x) && (0.0..1.0).contains(&y) {
                    sheet.put_pixel(
                        tile * TILE + (x * TILE as f32) as u32,
                        y0 + (y * TILE as f32) as u32,
                        image::Rgba([220, 220, 220, 255]),
                    );
                }
            }
        }
    }
    sheet
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn switch_plan_moves_each_key_change_through_a_stride() {
        let clips = switch_plan(4);
        assert_eq!(clips.len(), 5 * 4);
        for pair in clips.chunks(4) {
            let (a, b) = (pair[0].0, pair[0].1);
            assert!(a != b && (a == Action::Forward || b == Action::Forward));
            let switches: Vec<usize> = pair.iter().map(|c| c.2).collect();
            assert_eq!(switches, vec![93, 96, 99, 102]);
            assert!(pair.iter().all(|c| (c.0, c.1, c.3) == (a, b, 60)));
        }
        assert!(switch_plan(0).is_empty());
    }
}
