//! What the viewport shows: the neural avatar of a bundle (with the teacher beside it
//! when its character file loads), the teacher alone, a static mesh when the character
//! cannot be animated, the splats of a file (PLY, compressed PLY, .splat), or a
//! placeholder, with the reason. A splat file shows no placeholder (it needs no
//! character).

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::neural::{NeuralAvatar, NeuralStart, Settings, Update};
use crate::action::{Action, KeyScript};
use crate::avatar::description::Description;
use crate::avatar::load_character_with;
use crate::avatar::teacher::Teacher;
use crate::engine::surface::MapSurface;
use crate::gpu::GpuContext;
use crate::mesh::Mesh;
use crate::render::{GpuMesh, SceneRenderer};
use crate::splat::raster::Rasterizer;

/// Where the teacher stands when it runs beside the neural avatar.
pub const TEACHER_OFFSET: Vec3 = Vec3::new(1.5, 0.0, 0.0);

/// The neural avatar and what the window draws of it.
pub struct Neural {
    pub avatar: NeuralAvatar,
    /// The bundle folder it was opened from.
    dir: PathBuf,
    /// Live settings, known once the bundle is loaded.
    pub settings: Option<Settings>,
    surface: Option<(MapSurface, GpuMesh)>,
    mesh: Mesh,
    /// The frame's splats on the GPU, and how many.
    splats: Option<(wgpu::Buffer, usize)>,
    /// The bundle has a refiner (the HUD offers it).
    pub has_refiner: bool,
    /// The bundle's own sampler: the teacher's DDIM settings and its kind (the HUD
    /// switches between the one-pass student and the teacher).
    pub bundled: Option<crate::nn::sampler::Sampling>,
    pub root: Vec3,
    pub frames: u64,
    pub clamped: usize,
    /// The worker's whole frame (report to report), ms.
    pub frame_ms: f64,
    /// Why the worker stopped, until the app takes it.
    pub failure: Option<String>,
}

impl Neural {
    /// Gives the worker the action and takes what it reported; returns the new status
    /// line when it changed (`Some(None)`: loaded).
    fn receive(
        &mut self,
        gpu: &GpuContext,
        renderer: &SceneRenderer,
        action: Action,
    ) -> Option<Option<String>> {
        self.avatar.set_action(action);
        let mut status = None;
        for update in self.avatar.poll() {
            match update {
                Update::Ready {
                    surface,
                    standing,
                    splats,
                    root,
                    settings,
                    refiner,
                    bundled,
                } => {
                    self.bundled = Some(bundled);
                    self.mesh = surface.mesh(&standing);
                    self.splats = splats;
                    self.surface = Some((*surface, renderer.upload(gpu, &self.mesh)));
                    self.root = root;
                    self.settings = Some(settings);
                    self.has_refiner = refiner;
                    status = Some(None);
                }
                Update::Frame(drawn, _) => {
                    // The surface stays when the frame brings splats and no points:
                    // the camera's follow and the labels ask for it.
                    if let (Some(points), Some((surface, gpu_mesh))) =
                        (&drawn.points, self.surface.as_mut())
                    {
                        self.mesh = surface.mesh(points);
                        gpu_mesh.write_vertices(gpu, &self.mesh);
                    }
                    if drawn.splats.is_some() {
                        self.splats = drawn.splats;
                    }
                    self.root = drawn.root;
                    self.frames = drawn.frames;
                    self.clamped = drawn.clamped_total;
                    self.frame_ms = drawn.frame_ms;
                }
                Update::Failed(e) => {
                    log::error!("neural avatar: {e}");
                    status = Some(Some(format!("The neural avatar stopped: {e}")));
                    self.failure = Some(e);
                }
            }
        }
        status
    }
}

pub struct Shown {
    pub name: String,
    /// Why the avatar is static, a placeholder, or not yet shown.
    pub problem: Option<String>,
    pub teacher: Option<Teacher>,
    pub neural: Option<Neural>,
    /// Draw the teacher beside the neural avatar.
    pub show_teacher: bool,
    /// Splats from a PLY file: buffer, count, bounds.
    file_splats: Option<(wgpu::Buffer, usize, (Vec3, Vec3))>,
    mesh: Mesh,
    gpu_mesh: GpuMesh,
    /// Changes whenever the teacher's mesh on the GPU does.
    generation: u64,
    /// Frames the teacher has stepped (beside the neural avatar: one per generated frame).
    teacher_frames: u64,
}

impl Shown {
    /// The teacher of a character file (or a static mesh, or a placeholder).
    pub fn load(
        gpu: &GpuContext,
        renderer: &SceneRenderer,
        path: Option<&Path>,
        clips: &[PathBuf],
    ) -> Self {
        Self::from_parts(gpu, renderer, character_parts(path, clips))
    }

    /// What `parts` says, its problem logged.
    fn from_parts(gpu: &GpuContext, renderer: &SceneRenderer, parts: Parts) -> Self {
        let (name, teacher, mesh, problem) = parts;
        if let Some(problem) = &problem {
            log::warn!("{problem}");
        }
        Self {
            name,
            gpu_mesh: renderer.upload(gpu, &mesh),
            mesh,
            teacher,
            neural: None,
            show_teacher: false,
            generation: 0,
            teacher_frames: 0,
            file_splats: None,
            problem,
        }
    }

    /// The splats of a splat file whose up axis is `up` (a placeholder with the reason if
    /// it cannot be read).
    pub fn splat_file(
        gpu: &GpuContext,
        renderer: &SceneRenderer,
        path: &Path,
        up: crate::splat::files::Up,
    ) -> Self {
        let name = path.display().to_string();
        let mut note = None;
        let loaded = crate::splat::files::read(path, up)
            .map_err(|e| e.to_string())
            .and_then(|kept| {
                note = kept.note();
                let splats = kept.splats;
                let first = splats.first().ok_or(format!("{name}: no splats"))?.position;
                let bounds = splats.iter().fold((first, first), |(lo, hi), s| {
                    (lo.min(s.position), hi.max(s.position))
                });
                Rasterizer::fits(gpu, splats.len()).map_err(|e| format!("{name}: {e}"))?;
                let buffer = Rasterizer::upload(gpu, &splats).map_err(|e| e.to_string())?;
                Ok((buffer, splats.len(), bounds))
            });
        match loaded {
            Ok(file_splats) => {
                let mut label = format!("{name} ({} splats)", file_splats.1);
                if let Some(note) = note {
                    log::warn!("{name}: {note}");
                    label = format!("{label}; {note}");
                }
                let parts = nothing(label);
                let mut shown = Self::from_parts(gpu, renderer, parts);
                shown.file_splats = Some(file_splats);
                shown
            }
            Err(problem) => Self::from_parts(gpu, renderer, placeholder(problem)),
        }
    }

    /// The bundle folder of the neural avatar shown, if any.
    pub fn bundle(&self) -> Option<&Path> {
        self.neural.as_ref().map(|n| n.dir.as_path())
    }

    /// The neural avatar of the bundle `dir`, loading on its worker; the teacher of
    /// `character` beside it when that file loads.
    pub fn neural(
        gpu: &GpuContext,
        renderer: &SceneRenderer,
        character: Option<&Path>,
        clips: &[PathBuf],
        start: NeuralStart,
    ) -> Self {
        let mut shown = Self::load(gpu, renderer, character, clips);
        shown.show_teacher = shown.teacher.is_some();
        // The teacher stands at its side from the first frame, not inside the avatar.
        if shown.teacher.is_some() {
            shown.offset_teacher();
            shown.gpu_mesh.write_vertices(gpu, &shown.mesh);
            shown.generation += 1;
        }
        shown.name = format!("{} (neural)", start.dir.display());
        shown.problem = Some("Loading the neural avatar…".into());
        let dir = start.dir.clone();
        shown.neural = Some(Neural {
            avatar: NeuralAvatar::start(gpu, start),
            dir,
            settings: None,
            surface: None,
            mesh: Mesh::default(),
            splats: None,
            has_refiner: false,
            bundled: None,
            root: Vec3::ZERO,
            frames: 0,
            clamped: 0,
            frame_ms: 0.0,
            failure: None,
        });
        shown
    }

    /// Advances the avatar under `action`, or under a key `script` indexed by generated
    /// frame: the teacher alone by `steps` frames; beside the neural avatar, the teacher
    /// moves one frame per generated frame (offset by `TEACHER_OFFSET`) so the two stay
    /// comparable.
    pub fn advance(
        &mut self,
        gpu: &GpuContext,
        renderer: &SceneRenderer,
        action: Action,
        script: Option<&KeyScript>,
        steps: u32,
    ) {
        let steps = match &mut self.neural {
            None => steps,
            Some(neural) => {
                let before = neural.frames;
                if let Some(problem) = neural.receive(gpu, renderer, action) {
                    self.problem = problem;
                }
                (neural.frames - before) as u32
            }
        };
        let Some(teacher) = &mut self.teacher else {
            return;
        };
        if steps == 0 {
            return;
        }
        for _ in 0..steps {
            let action = script.map_or(action, |s| s.action_at(self.teacher_frames as usize));
            teacher.step(action);
            self.teacher_frames += 1;
        }
        self.mesh = teacher.mesh();
        if self.neural.is_some() {
            self.offset_teacher();
        }
        self.gpu_mesh.write_vertices(gpu, &self.mesh);
        self.generation += 1;
    }

    /// Moves the teacher's mesh to its place beside the neural avatar.
    fn offset_teacher(&mut self) {
        self.mesh
            .positions
            .iter_mut()
            .for_each(|p| *p += TEACHER_OFFSET);
    }

    /// Whether the neural avatar is still waiting for its first generated frame (loading
    /// or generating it); None where there is no neural avatar or it stopped.
    pub fn first_frame_pending(&self) -> Option<bool> {
        let neural = self.neural.as_ref()?;
        (neural.failure.is_none() && neural.frames == 0).then_some(neural.settings.is_some())
    }

    /// Frames generated so far: the neural avatar's, else the teacher's steps. A key
    /// script is indexed by this count.
    pub fn generated_frames(&self) -> u64 {
        self.neural
            .as_ref()
            .map_or(self.teacher_frames, |n| n.frames)
    }

    /// The splats to draw: a PLY file's, or the neural avatar's when it shows splats.
    pub fn splats(&self) -> Option<(&wgpu::Buffer, usize, u64)> {
        if let Some((buffer, count, _)) = &self.file_splats {
            return Some((buffer, *count, 0));
        }
        let neural = self
            .neural
            .as_ref()
            .filter(|n| n.settings.is_none_or(|s| s.splats))?;
        neural
            .splats
            .as_ref()
            .map(|(buffer, count)| (buffer, *count, neural.frames))
    }

    /// The meshes to draw.
    pub fn gpu_meshes(&self) -> Vec<&GpuMesh> {
        let neural = self
            .neural
            .as_ref()
            .filter(|n| n.settings.is_some_and(|s| !s.splats))
            .and_then(|n| n.surface.as_ref())
            .map(|(_, m)| m);
        let alone = self.neural.is_none() && self.file_splats.is_none();
        let other = alone || (self.show_teacher && self.teacher.is_some());
        neural
            .into_iter()
            .chain(other.then_some(&self.gpu_mesh))
            .collect()
    }

    /// The light the meshes are drawn in: the teacher's renders' light, turned with it
    /// (so beside the neural avatar it is lit as the refiner's training images were);
    /// `None` (a light beside the camera) for a static mesh.
    pub fn light(&self) -> Option<glam::Vec3> {
        let teacher = self.teacher.as_ref()?;
        Some(crate::render::scene::character_light(
            teacher.locomotion.yaw,
        ))
    }

    /// Changes whenever what [`Shown::gpu_meshes`] draws does (meshes shown, the
    /// teacher's pose, the neural surface's frame): the viewport redraws only then.
    pub fn scene_generation(&self) -> (u64, u64, usize) {
        let neural = self.neural.as_ref().map_or(0, |n| n.frames + 1);
        (self.generation, neural, self.gpu_meshes().len())
    }

    /// The point the camera follows: the neural avatar's root, else the teacher's.
    pub fn focus(&self) -> Option<Vec3> {
        match (&self.neural, &self.teacher) {
            (Some(n), _) => n.surface.as_ref().map(|_| n.root),
            (None, Some(t)) => Some(t.root()),
            (None, None) => None,
        }
    }

    /// Labels for the viewport when the neural avatar and its teacher are both drawn:
    /// a world point just under each one's feet and its name.
    pub fn labels(&self) -> Vec<(Vec3, &'static str)> {
        let (Some(neural), Some(_)) = (&self.neural, &self.teacher) else {
            return Vec::new();
        };
        if !self.show_teacher || neural.surface.is_none() {
            return Vec::new();
        }
        let Some((lo, hi)) = self.mesh.bounds() else {
            return Vec::new();
        };
        let under = lo.y - 0.05;
        let teacher = Vec3::new((lo.x + hi.x) * 0.5, under, (lo.z + hi.z) * 0.5);
        let model = Vec3::new(neural.root.x, under, neural.root.z);
        vec![(model, "neural"), (teacher, "teacher")]
    }

    pub fn bounds(&self) -> (Vec3, Vec3) {
        if let Some((_, _, bounds)) = &self.file_splats {
            return *bounds;
        }
        let neural = self
            .neural
            .as_ref()
            .filter(|n| n.surface.is_some())
            .map(|n| &n.mesh);
        neural
            .unwrap_or(&self.mesh)
            .bounds()
            .unwrap_or((Vec3::ZERO, Vec3::new(0.5, 1.8, 0.5)))
    }
}

/// What the viewport shows of a character: name, teacher, mesh and the problem, if any.
type Parts = (String, Option<Teacher>, Mesh, Option<String>);

/// The teacher of a character file, its static mesh when it cannot be animated, or a
/// placeholder with the reason.
fn character_parts(path: Option<&Path>, clips: &[PathBuf]) -> Parts {
    match path.map(|p| load_character_with(p, clips)) {
        None => placeholder("no character file given (--character)".into()),
        Some(Err(e)) => placeholder(e.to_string()),
        Some(Ok(character)) => {
            let name = character.name.clone();
            let rest = character.rest_mesh();
            match Description::find(&character, None).and_then(|d| Teacher::new(character, d)) {
                Ok(teacher) => {
                    let mesh = teacher.mesh();
                    (name, Some(teacher), mesh, None)
                }
                Err(e) => (name, None, rest, Some(format!("Not animated: {e}"))),
            }
        }
    }
}

/// No character and no problem: what a splat file shows beside its splats.
fn nothing(name: String) -> Parts {
    (name, None, Mesh::default(), None)
}

fn placeholder(problem: String) -> Parts {
    let mesh = Mesh::cuboid(
        Vec3::new(-0.25, 0.0, -0.15),
        Vec3::new(0.25, 1.8, 0.15),
        Vec3::splat(0.5),
    );
    (
        "placeholder".into(),
        None,
        mesh,
        Some(format!("Showing a placeholder: {problem}")),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_missing_or_broken_character_gets_a_placeholder() {
        let (name, teacher, mesh, problem) = nothing("scene.splat (3 splats)".into());
        assert_eq!(name, "scene.splat (3 splats)");
        assert!(teacher.is_none() && mesh.positions.is_empty() && problem.is_none());
        let (name, _, mesh, problem) = character_parts(None, &[]);
        assert_eq!(name, "placeholder");
        assert!(!mesh.positions.is_empty());
        assert!(problem.unwrap().contains("no character file given"));
        let (_, _, _, problem) = character_parts(Some(Path::new("/no/such/hero.glb")), &[]);
        assert!(problem.unwrap().contains("hero.glb"));
    }

    /// `unica view` builds this: the file's splats, no placeholder mesh, no message.
    #[test]
    fn a_splat_file_shows_its_splats_and_no_placeholder() {
        let gpu = GpuContext::headless(&crate::gpu::GpuOptions::from_env()).unwrap();
        let renderer = SceneRenderer::new(&gpu);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("one.splat");
        let splat = crate::splat::ply::Splat {
            position: Vec3::new(0.0, 0.0, 1.0),
            f_dc: Vec3::ZERO,
            opacity: 0.5,
            scale: Vec3::splat(0.1),
            rotation: glam::Quat::IDENTITY,
        };
        crate::splat::dotsplat::write(&path, &[splat]).unwrap();
        let up = crate::splat::files::Up::Z;
        let shown = Shown::splat_file(&gpu, &renderer, &path, up);
        assert!(shown.problem.is_none(), "{:?}", shown.problem);
        assert!(shown.teacher.is_none() && shown.mesh.positions.is_empty());
        assert!(shown.gpu_meshes().is_empty(), "no mesh is drawn");
        assert!(
            shown.name.ends_with("one.splat (1 splats)"),
            "{}",
            shown.name
        );
        assert_eq!(shown.splats().map(|(_, n, _)| n), Some(1));
        // Read Z-up: the splat at +Z stands at +Y.
        let (lo, hi) = shown.bounds();
        assert!(lo.distance(Vec3::Y) < 1e-6 && hi.distance(Vec3::Y) < 1e-6);
        // An unreadable file: the placeholder with the file's problem.
        let bad = dir.path().join("bad.splat");
        std::fs::write(&bad, [0u8; 5]).unwrap();
        let shown = Shown::splat_file(&gpu, &renderer, &bad, up);
        let problem = shown.problem.unwrap();
        assert!(problem.starts_with("Showing a placeholder: ") && problem.contains("bad.splat"));
    }
}
