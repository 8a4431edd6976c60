//! One lockstep run: the teacher and the engine driven by the same key script, the
//! engine's frames drawn by the shipped splat path and the teacher's mesh from the same
//! cameras, each generated frame scored against the teacher's frames of the same script
//! within a window of the same index, and both paths kept for the motion comparison.

use std::path::PathBuf;
use std::rc::Rc;

use glam::Vec3;

use crate::action::KeyScript;
use crate::avatar::description::Description;
use crate::avatar::humanoid;
use crate::avatar::load_character_with;
use crate::avatar::reference::Reference;
use crate::avatar::teacher::Teacher;
use crate::engine::appearance::Appearance;
use crate::engine::{Engine, EngineOptions};
use crate::gpu::GpuContext;
use crate::gpu::kernel::Precision;
use crate::mesh::Mesh;
use crate::posmap::{GroupNorm, SurfaceTable};
use crate::render::OrbitCamera;
use crate::render::camera::FOV_Y;
use crate::render::offscreen::Offscreen;
use crate::render::scene::{DrawOptions, character_light};
use crate::splat::raster::Rasterizer;

use super::motion::{FootSample, body_offset, facing_deg, foot_sample};
use super::pixels::{self, BACKGROUNDS, LinearImage, Silhouette};

/// Share of the image height the standing teacher fills in the full-body views.
const FILL: f32 = 0.72;

/// The teacher is drawn at this many times the image size and box-filtered down (16
/// samples a pixel): its rasteriser takes one sample a pixel, and the splats it is
/// compared with are filtered (the rasteriser's 0.3 px² blur), so a one-sample teacher
/// charges every silhouette pixel its own aliasing. Measured on the shipped Witch (quick
/// strict eval at 512², one seed): the ceiling on white 15.5 dB with one sample, 16.5
/// with 4, 16.7 with 16 at level 1024; 17.6, 19.0, 19.4 at level 256.
pub const TEACHER_SAMPLES: u32 = 4;

/// One camera around the teacher's root, turned with the teacher's facing.
pub struct EvalView {
    pub name: &'static str,
    /// From the teacher's front (0) toward its left (+90), degrees.
    pub yaw_deg: f32,
    pub pitch_deg: f32,
    /// The upper body, closer.
    pub close: bool,
}

/// The 4 cardinal views and 4 the training renders never had.
pub const VIEWS: [EvalView; 8] = [
    view("front", 0.0, 6.0, false),
    view("left", 90.0, 6.0, false),
    view("back", 180.0, 6.0, false),
    view("right", 270.0, 6.0, false),
    view("front-left 45°", 45.0, 6.0, false),
    view("front-right 45°", 315.0, 6.0, false),
    view("above 30°", 0.0, 30.0, false),
    view("upper body", 20.0, 8.0, true),
];

const fn view(name: &'static str, yaw_deg: f32, pitch_deg: f32, close: bool) -> EvalView {
    EvalView {
        name,
        yaw_deg,
        pitch_deg,
        close,
    }
}

/// A face is scored in views within this many degrees of the teacher's front.
const FACE_VIEW_DEG: f32 = 60.0;

pub struct LockstepOptions {
    pub bundle: PathBuf,
    pub character: PathBuf,
    pub clips: Vec<PathBuf>,
    pub seed: u64,
    pub keys: KeyScript,
    /// Image size (square).
    pub size: u32,
    /// Score every this many frames.
    pub score_every: usize,
    /// Teacher frames within this many of the same index ...
    pub window: usize,
    /// ... every this many.
    pub window_step: usize,
    /// The engine's own splat level, then the other levels drawn from its points ...
    pub engine_level: usize,
    /// ... at the scored frames whose index is a multiple of this (a 1024-level frame of
    /// 250k splats takes seconds to draw on a CPU driver).
    pub fine_every: usize,
    pub levels: Vec<usize>,
}

/// Scores of one view: per background (BACKGROUNDS order) PSNR and SSIM, the
/// silhouette, and the face and hand crops' PSNR where scored.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ViewScore {
    pub view: usize,
    #[serde(with = "super::decibels")]
    pub psnr_db: [f64; 3],
    pub ssim: [f64; 3],
    pub silhouette: Silhouette,
    #[serde(with = "super::decibels")]
    pub face_psnr_db: Option<[f64; 3]>,
    #[serde(with = "super::decibels")]
    pub hands_psnr_db: Option<[f64; 3]>,
}

/// One scored frame at one level.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FrameScore {
    pub index: usize,
    pub level: usize,
    /// The teacher frame of the best score in the window.
    pub best_index: usize,
    pub best: Vec<ViewScore>,
    pub same: Vec<ViewScore>,
    /// The teacher's own geometry through the same appearance path.
    pub ceiling: Vec<ViewScore>,
}

/// Saved per seed (`unica eval --resume`), all but the sheet, which is written as a PNG.
#[derive(serde::Serialize, serde::Deserialize)]
pub struct LockstepRun {
    /// Roots (waist means of the map points) of the start and after each step.
    pub teacher_roots: Vec<Vec3>,
    pub engine_roots: Vec<Vec3>,
    /// Facings (degrees) of the same frames, each from its own points.
    pub teacher_facing: Vec<f32>,
    pub engine_facing: Vec<f32>,
    /// The left and right foot of the same frames (empty where no foot joints were
    /// found), each from its own points.
    pub teacher_feet: Vec<Vec<FootSample>>,
    pub engine_feet: Vec<Vec<FootSample>>,
    /// Per frame scored at the engine's level: the mean image change to the next frame
    /// (`pixels::mean_change`, both frames from the scored frame's cameras), generated and
    /// teacher.
    pub flicker: Vec<(f64, f64)>,
    /// The loose parts' (spring-chain pixels') centre on the body of the same frames
    /// (`motion::body_offset`; empty where the teacher has no spring chains).
    pub teacher_swing: Vec<Vec3>,
    pub engine_swing: Vec<Vec3>,
    pub scores: Vec<FrameScore>,
    /// Fraction of the image height the teacher fills, per full-body view (smallest seen).
    pub fill: f32,
    /// Seconds: the teacher's frames, the engine's, splats made by the appearance stage,
    /// drawing (and the window search), scoring.
    pub seconds: [f64; 5],
    /// The first scored frame at the headline level on grey: the teacher, the ceiling
    /// and the generated frame (rows) from every view (columns).
    #[serde(skip)]
    pub sheet: Option<image::RgbaImage>,
}

/// The teacher's frames: points, roots, facings, the meshes to draw and the joints.
struct TeacherFrames {
    points: Vec<Vec<Vec3>>,
    roots: Vec<Vec3>,
    facing: Vec<f32>,
    meshes: Vec<Option<Mesh>>,
    /// The light's yaw (the character's) per frame.
    yaw: Vec<f32>,
    head: Vec<Vec3>,
    hands: Vec<[Vec3; 2]>,
    feet: Vec<Vec<FootSample>>,
    swing: Vec<Vec3>,
}

/// The map pixels (indices into the table's foreground list) whose triangle's three
/// vertices all follow most a joint that `keep` accepts.
fn pixels_following(
    teacher: &Teacher,
    table: &SurfaceTable,
    keep: impl Fn(usize) -> bool,
) -> Vec<u32> {
    let skinned = &teacher.character.skinned;
    let node_of = |v: u32| teacher.character.rig.bones[skinned.dominant_bone(v as usize)].node;
    (0..table.len() as u32)
        .filter(|&i| {
            let t = 3 * table.triangles[i as usize] as usize;
            skinned.bind.indices[t..t + 3]
                .iter()
                .all(|&v| keep(node_of(v)))
        })
        .collect()
}

/// The map pixels of the loose parts: those that follow a spring joint.
fn spring_pixels(teacher: &Teacher, table: &SurfaceTable) -> Vec<u32> {
    let springs: Vec<usize> = teacher
        .springs
        .chains
        .iter()
        .flat_map(|c| c.nodes())
        .collect();
    pixels_following(teacher, table, |node| springs.contains(&node))
}

/// The mean of `points[pixels[..]]`; None for no pixels.
fn centre_of(points: &[Vec3], pixels: &[u32]) -> Option<Vec3> {
    (!pixels.is_empty())
        .then(|| pixels.iter().map(|&i| points[i as usize]).sum::<Vec3>() / pixels.len() as f32)
}

/// The map pixels of the left and right foot: those that follow the foot joint or a joint
/// below it (toes). Empty when the character has no foot joints to find.
fn foot_pixels(teacher: &Teacher, table: &SurfaceTable) -> Vec<Vec<u32>> {
    let character = &teacher.character;
    let rig = &character.rig;
    let find = |name| humanoid::find_loosely(rig, character.vrm.as_ref(), name);
    let (Some(left), Some(right)) = (find("Foot.L"), find("Foot.R")) else {
        return Vec::new();
    };
    [left, right]
        .iter()
        .map(|&foot| pixels_following(teacher, table, |node| rig.is_under(node, foot)))
        .collect()
}

/// Each foot's sample in one frame's map points (none where the feet were not found).
fn foot_samples(points: &[Vec3], feet: &[Vec<u32>]) -> Vec<FootSample> {
    feet.iter()
        .filter_map(|foot| foot_sample(points, foot))
        .collect()
}

/// Where the cameras stand: the standing teacher's height, the height they aim at and
/// their distance for the full body.
struct Framing {
    height: f32,
    ground: f32,
    middle: f32,
    distance: f32,
    size: u32,
}

impl Framing {
    fn camera(&self, view: &EvalView, facing_deg: f32, root: Vec3) -> OrbitCamera {
        let (y, distance) = if view.close {
            (self.ground + 0.72 * self.height, self.distance * 0.45)
        } else {
            (self.middle, self.distance)
        };
        OrbitCamera {
            target: Vec3::new(root.x, y, root.z),
            yaw: (facing_deg + view.yaw_deg).to_radians(),
            pitch: view.pitch_deg.to_radians(),
            distance,
        }
    }

    /// Pixel position of `p` and pixels per metre at the camera's target.
    fn project(&self, camera: &OrbitCamera, p: Vec3) -> (f32, f32, f32) {
        let clip = camera.view_projection(1.0) * p.extend(1.0);
        let ndc = clip.truncate() / clip.w.max(1e-6);
        let size = self.size as f32;
        let per_metre = size / (2.0 * camera.distance * (FOV_Y * 0.5).tan());
        (
            (ndc.x + 1.0) * 0.5 * size,
            (1.0 - ndc.y) * 0.5 * size,
            per_metre,
        )
    }
}

pub fn run(
    gpu: &GpuContext,
    options: &LockstepOptions,
    progress: &dyn Fn(&str, u64, u64),
) -> anyhow::Result<LockstepRun> {
    let clock = std::time::Instant::now();
    let steps = options.keys.len();
    let scored: Vec<usize> = (1..=steps)
        .filter(|i| i % options.score_every == 0)
        .collect();
    let window = |i: usize| {
        let lo = i.saturating_sub(options.window).max(1);
        let hi = (i + options.window).min(steps);
        let mut js: Vec<usize> = (lo..=hi)
            .filter(|j| j.abs_diff(i) % options.window_step == 0)
            .collect();
        if !js.contains(&i) {
            js.push(i);
        }
        js
    };
    let mut needed = vec![false; steps + 1];
    for &i in &scored {
        for j in window(i) {
            needed[j] = true;
        }
        // The frame after, for flicker.
        if i < steps {
            needed[i + 1] = true;
        }
    }

    // The teacher, every frame.
    let loaded = load_character_with(&options.character, &options.clips)?;
    let description = Description::find(&loaded, None)?;
    let mut teacher = Teacher::new(loaded, description)?;
    let reference = Reference::new(&teacher)?;
    let find = |name: &str| {
        humanoid::find_loosely(&teacher.character.rig, teacher.character.vrm.as_ref(), name)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: no {name} joint found for the face and hand crops",
                    options.character.display()
                )
            })
    };
    let joints = [find("Head")?, find("Wrist.L")?, find("Wrist.R")?];
    let indices = teacher.character.skinned.bind.indices.clone();
    let feet = foot_pixels(&teacher, &reference.table);
    let loose = spring_pixels(&teacher, &reference.table);
    let mut frames = TeacherFrames {
        points: Vec::new(),
        roots: Vec::new(),
        facing: Vec::new(),
        meshes: Vec::new(),
        yaw: Vec::new(),
        head: Vec::new(),
        hands: Vec::new(),
        feet: Vec::new(),
        swing: Vec::new(),
    };
    let mut rest: Vec<Vec3> = Vec::new();
    for (index, &kept) in needed.iter().enumerate() {
        if index > 0 {
            teacher.step(options.keys.action_at(index - 1));
        }
        let mesh = teacher.mesh();
        let points = reference.gather(&mesh.positions, &indices);
        let root = GroupNorm::root(&points, &reference.waist);
        let centred: Vec<Vec3> = points.iter().map(|&p| p - root).collect();
        if index == 0 {
            rest = centred.clone();
        }
        let facing = facing_deg(&centred, &rest);
        frames
            .swing
            .extend(centre_of(&points, &loose).map(|c| body_offset(c, root, facing)));
        frames.facing.push(facing);
        frames.roots.push(root);
        frames.feet.push(foot_samples(&points, &feet));
        frames.points.push(points);
        frames.yaw.push(teacher.locomotion.yaw);
        let world = teacher.world();
        let at = |n: usize| world[n].w_axis.truncate();
        frames.head.push(at(joints[0]));
        frames.hands.push([at(joints[1]), at(joints[2])]);
        frames.meshes.push((kept || index == 0).then_some(mesh));
        progress("teacher", index as u64, steps as u64);
    }
    let (lo, hi) = frames.meshes[0]
        .as_ref()
        .and_then(Mesh::bounds)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "{}: the character has no vertices",
                options.character.display()
            )
        })?;
    let height = hi.y - lo.y;
    let framing = Framing {
        height,
        ground: lo.y,
        middle: (lo.y + hi.y) * 0.5,
        distance: height / (FILL * 2.0 * (FOV_Y * 0.5).tan()),
        size: options.size,
    };
    let teacher_seconds = clock.elapsed().as_secs_f64();

    // The engine, every frame; the scored ones drawn and compared.
    let mut engine = Engine::new(
        gpu,
        &options.bundle,
        &EngineOptions {
            seed: options.seed,
            splat_level: Some(options.engine_level),
            refine: true,
            ..Default::default()
        },
    )?;
    if engine.bundle.pixels != reference.table.pixels {
        anyhow::bail!(
            "{}: the bundle's map is not {}'s (its foreground pixels differ); give the character it was made from",
            options.bundle.display(),
            options.character.display()
        );
    }
    let waist = engine.bundle.waist.clone();
    let mut looks = Vec::new();
    for &level in &options.levels {
        looks.push((
            level,
            Appearance::new(gpu, &engine.bundle, Precision::F32, level)?,
        ));
    }
    let mut offscreen = Offscreen::new(gpu.clone(), options.size, options.size);
    let mut teacher_offscreen = Offscreen::new(
        gpu.clone(),
        options.size * TEACHER_SAMPLES,
        options.size * TEACHER_SAMPLES,
    );
    let mut flicker = Vec::new();
    let mut flicker_start: Option<FlickerStart> = None;
    let standing = engine.standing_points();
    let root_of = |points: &[Vec3]| GroupNorm::root(points, &waist);
    let facing_of = |points: &[Vec3], root: Vec3| {
        let centred: Vec<Vec3> = points.iter().map(|&p| p - root).collect();
        facing_deg(&centred, &rest)
    };
    let start = root_of(&standing);
    let mut engine_roots = vec![start];
    let mut engine_facing = vec![facing_of(&standing, start)];
    let mut engine_feet = vec![foot_samples(&standing, &feet)];
    let mut engine_swing: Vec<Vec3> = centre_of(&standing, &loose)
        .map(|c| body_offset(c, start, engine_facing[0]))
        .into_iter()
        .collect();
    let mut scores = Vec::new();
    let mut fill = 1.0f32;
    let mut sheet = None;
    let (mut engine_seconds, mut draw_seconds, mut appearance_seconds) = (0.0, 0.0, 0.0);
    let mut score_seconds = 0.0;
    progress("engine", 0, steps as u64);
    for index in 1..=steps {
        let lap = std::time::Instant::now();
        let frame = engine.step(options.keys.action_at(index - 1))?;
        let root = root_of(&frame.points);
        engine_roots.push(root);
        engine_facing.push(facing_of(&frame.points, root));
        engine_feet.push(foot_samples(&frame.points, &feet));
        let facing = *engine_facing.last().expect("pushed above");
        engine_swing.extend(centre_of(&frame.points, &loose).map(|c| body_offset(c, root, facing)));
        engine_seconds += lap.elapsed().as_secs_f64();
        if let Some(start) = flicker_start.take().filter(|f| f.index + 1 == index) {
            // The frame after a scored one, from the scored frame's cameras (both sides).
            let (buffer, count) = engine
                .splats()
                .ok_or_else(|| anyhow::anyhow!("the engine made no splats"))?;
            let got = draw_splats(&mut offscreen, buffer, count, &start.cameras)?;
            let mesh = frames.meshes[index]
                .as_ref()
                .expect("the frame after a scored one is kept");
            let want = draw_teacher(
                &mut teacher_offscreen,
                mesh,
                frames.yaw[index],
                &start.teacher_cameras,
            )?;
            flicker.push((
                pixels::mean_change(&start.generated, &got),
                pixels::mean_change(&start.teacher, &want),
            ));
        }
        if scored.contains(&index) {
            let lap = std::time::Instant::now();
            let facing = frames.facing[index];
            let cameras: Vec<OrbitCamera> = VIEWS
                .iter()
                .map(|v| framing.camera(v, facing, root))
                .collect();
            // Each level's generated images: the engine's own splats at its level, the
            // others drawn from its points through the same appearance stage.
            let mut generated: Vec<(usize, Vec<LinearImage>)> = Vec::new();
            let (buffer, count) = engine
                .splats()
                .ok_or_else(|| anyhow::anyhow!("the engine made no splats"))?;
            let own = draw_splats(&mut offscreen, buffer, count, &cameras)?;
            generated.push((options.engine_level, own));
            for (level, look) in looks.iter_mut() {
                if *level == options.engine_level || index % options.fine_every != 0 {
                    continue;
                }
                let t = std::time::Instant::now();
                let splats = look.splats(&engine.bundle, &frame.points)?;
                appearance_seconds += t.elapsed().as_secs_f64();
                let buffer = Rasterizer::upload(gpu, &splats)?;
                let images = draw_splats(&mut offscreen, &buffer, splats.len(), &cameras)?;
                generated.push((*level, images));
            }
            // The teacher's frames in the window, drawn from the same cameras about their
            // own roots; the best by the mean grey-background PSNR over the views.
            let teacher_cameras = |j: usize| -> Vec<OrbitCamera> {
                cameras
                    .iter()
                    .map(|c| OrbitCamera {
                        target: Vec3::new(frames.roots[j].x, c.target.y, frames.roots[j].z),
                        ..*c
                    })
                    .collect()
            };
            let mut best: Vec<(f64, usize, Rc<Vec<LinearImage>>)> = Vec::new();
            let mut same: Option<Rc<Vec<LinearImage>>> = None;
            for j in window(index) {
                let mesh = frames.meshes[j]
                    .as_ref()
                    .expect("every frame of a window is kept");
                let images = Rc::new(draw_teacher(
                    &mut teacher_offscreen,
                    mesh,
                    frames.yaw[j],
                    &teacher_cameras(j),
                )?);
                for (k, (_, got)) in generated.iter().enumerate() {
                    let mean = got
                        .iter()
                        .zip(images.iter())
                        .map(|(g, w)| pixels::psnr(g, w, 0.5).min(100.0))
                        .sum::<f64>()
                        / images.len() as f64;
                    if best.len() <= k {
                        best.push((f64::NEG_INFINITY, j, images.clone()));
                    }
                    if mean > best[k].0 {
                        best[k] = (mean, j, images.clone());
                    }
                }
                if j == index {
                    same = Some(images);
                }
            }
            let same = same.expect("the window holds its own index");
            fill = fill.min(filled(&same, options.size));
            flicker_start = Some(FlickerStart {
                index,
                cameras: cameras.clone(),
                teacher_cameras: teacher_cameras(index),
                generated: generated[0].1.clone(),
                teacher: same.to_vec(),
            });
            for (k, (level, got)) in generated.iter().enumerate() {
                let (_, best_index, want) = &best[k];
                let look = looks
                    .iter_mut()
                    .find(|(l, _)| l == level)
                    .map(|(_, look)| look)
                    .expect("every level has an appearance");
                let t = std::time::Instant::now();
                let splats = look.splats(&engine.bundle, &frames.points[index])?;
                appearance_seconds += t.elapsed().as_secs_f64();
                let buffer = Rasterizer::upload(gpu, &splats)?;
                let ceiling_images = draw_splats(
                    &mut offscreen,
                    &buffer,
                    splats.len(),
                    &teacher_cameras(index),
                )?;
                let score_all =
                    |got: &[LinearImage], want: &[LinearImage], j: usize| -> Vec<ViewScore> {
                        got.iter()
                            .zip(want)
                            .enumerate()
                            .map(|(v, (g, w))| {
                                let camera = OrbitCamera {
                                    target: Vec3::new(
                                        frames.roots[j].x,
                                        cameras[v].target.y,
                                        frames.roots[j].z,
                                    ),
                                    ..cameras[v]
                                };
                                score(g, w, v, &framing, &camera, &frames, j)
                            })
                            .collect()
                    };
                if sheet.is_none()
                    && *level == options.levels.iter().copied().max().unwrap_or(*level)
                {
                    sheet = Some(contact_sheet(&[&same, &ceiling_images, got]));
                }
                let t = std::time::Instant::now();
                let frame_score = FrameScore {
                    index,
                    level: *level,
                    best_index: *best_index,
                    best: score_all(got, want, *best_index),
                    same: score_all(got, &same, index),
                    ceiling: score_all(&ceiling_images, &same, index),
                };
                score_seconds += t.elapsed().as_secs_f64();
                scores.push(frame_score);
            }
            draw_seconds += lap.elapsed().as_secs_f64();
        }
        progress("engine", index as u64, steps as u64);
    }
    Ok(LockstepRun {
        teacher_feet: frames.feet,
        engine_feet,
        teacher_swing: frames.swing,
        engine_swing,
        flicker,
        teacher_roots: frames.roots,
        engine_roots,
        teacher_facing: frames.facing,
        engine_facing,
        scores,
        fill,
        seconds: [
            teacher_seconds,
            engine_seconds,
            appearance_seconds,
            draw_seconds - appearance_seconds - score_seconds,
            score_seconds,
        ],
        sheet,
    })
}

/// A scored frame's images and cameras, kept to compare the next frame with (flicker).
struct FlickerStart {
    index: usize,
    cameras: Vec<OrbitCamera>,
    teacher_cameras: Vec<OrbitCamera>,
    generated: Vec<LinearImage>,
    teacher: Vec<LinearImage>,
}

/// The teacher's `mesh` in its light (the character's at `yaw`) from each camera, drawn
/// at [`TEACHER_SAMPLES`]² samples a pixel.
fn draw_teacher(
    offscreen: &mut Offscreen,
    mesh: &Mesh,
    yaw: f32,
    cameras: &[OrbitCamera],
) -> anyhow::Result<Vec<LinearImage>> {
    let light = DrawOptions {
        light: Some(character_light(yaw)),
        ..plain()
    };
    cameras
        .iter()
        .map(|camera| {
            let image = offscreen.render(mesh, camera, &light)?;
            Ok(LinearImage::from_srgb8(&image).downsample(TEACHER_SAMPLES as usize))
        })
        .collect()
}

/// `count` splats of `buffer` drawn from each camera.
fn draw_splats(
    offscreen: &mut Offscreen,
    buffer: &wgpu::Buffer,
    count: usize,
    cameras: &[OrbitCamera],
) -> anyhow::Result<Vec<LinearImage>> {
    cameras
        .iter()
        .map(|camera| {
            let image = offscreen.render_splats(buffer, count, camera, &plain())?;
            Ok(LinearImage::from_srgb8(&image))
        })
        .collect()
}

/// Drawn over a transparent background with no grid: alpha is coverage.
fn plain() -> DrawOptions {
    DrawOptions {
        grid: false,
        background: wgpu::Color::TRANSPARENT,
        light: None,
    }
}

/// The smallest share of the image height the figure spans in the full-body views.
fn filled(images: &[LinearImage], size: u32) -> f32 {
    images
        .iter()
        .zip(&VIEWS)
        .filter(|(_, v)| !v.close)
        .map(|(image, _)| {
            let rows: Vec<usize> = (0..image.height)
                .filter(|&y| {
                    (0..image.width).any(|x| image.rgba[y * image.width + x][3] >= pixels::SOLID)
                })
                .collect();
            match (rows.first(), rows.last()) {
                (Some(a), Some(b)) => (b - a + 1) as f32 / size as f32,
                _ => 0.0,
            }
        })
        .fold(1.0, f32::min)
}

/// All scores of one view: whole image on each background, silhouette, and the face and
/// hand crops placed from teacher frame `j`'s joints.
fn score(
    got: &LinearImage,
    want: &LinearImage,
    view: usize,
    framing: &Framing,
    camera: &OrbitCamera,
    frames: &TeacherFrames,
    j: usize,
) -> ViewScore {
    let each = |f: &dyn Fn(f32) -> f64| BACKGROUNDS.map(|(_, b)| f(b));
    let crop = |centre: Vec3, metres: f32| {
        let (x, y, per_metre) = framing.project(camera, centre);
        let side = (metres * per_metre).round().max(11.0) as usize;
        let (x0, y0) = (x as i64 - side as i64 / 2, y as i64 - side as i64 / 2);
        (got.crop(x0, y0, side, side), want.crop(x0, y0, side, side))
    };
    let facing = frames.facing[j];
    let sees_face =
        super::motion::wrap_deg(camera.yaw.to_degrees() - facing).abs() <= FACE_VIEW_DEG;
    let face_psnr_db = sees_face.then(|| {
        // The face: above the head joint (the neck end of the head bone).
        let centre = frames.head[j] + Vec3::Y * 0.06 * framing.height;
        let (g, w) = crop(centre, 0.16 * framing.height);
        each(&|b| pixels::psnr(&g, &w, b))
    });
    let hands = frames.hands[j].map(|h| crop(h, 0.12 * framing.height));
    let hands_psnr_db = Some(each(&|b| {
        hands
            .iter()
            .map(|(g, w)| pixels::psnr(g, w, b).min(100.0))
            .sum::<f64>()
            / 2.0
    }));
    ViewScore {
        view,
        psnr_db: each(&|b| pixels::psnr(got, want, b)),
        ssim: each(&|b| pixels::ssim(got, want, b)),
        silhouette: pixels::silhouette(got, want),
        face_psnr_db,
        hands_psnr_db,
    }
}

/// Rows of images shown on grey, side by side.
fn contact_sheet(rows: &[&[LinearImage]]) -> image::RgbaImage {
    let (w, h) = (rows[0][0].width as u32, rows[0][0].height as u32);
    let columns = rows.iter().map(|r| r.len()).max().unwrap_or(0) as u32;
    let mut sheet = image::RgbaImage::new(w * columns, h * rows.len() as u32);
    for (r, row) in rows.iter().enumerate() {
        for (c, image) in row.iter().enumerate() {
            for (i, p) in image.shown(0.5).iter().enumerate() {
                let (x, y) = ((i % image.width) as u32, (i / image.width) as u32);
                let px = p.map(|v| (v * 255.0).round() as u8);
                sheet.put_pixel(
                    c as u32 * w + x,
                    r as u32 * h + y,
                    image::Rgba([px[0], px[1], px[2], 255]),
                );
            }
        }
    }
    sheet
}
