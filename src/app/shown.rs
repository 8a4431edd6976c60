//! What the viewport shows: the teacher (a rigged character driven by the actions), a
//! static mesh when the character cannot be animated, or a placeholder, with the reason.

use std::path::Path;

use glam::Vec3;

use crate::action::Action;
use crate::avatar::description::Description;
use crate::avatar::load_character;
use crate::avatar::teacher::Teacher;
use crate::gpu::GpuContext;
use crate::mesh::Mesh;
use crate::render::{GpuMesh, SceneRenderer};

pub struct Shown {
    pub name: String,
    /// Why the character is static or a placeholder.
    pub problem: Option<String>,
    pub teacher: Option<Teacher>,
    mesh: Mesh,
    gpu_mesh: GpuMesh,
}

impl Shown {
    pub fn load(gpu: &GpuContext, renderer: &SceneRenderer, path: Option<&Path>) -> Self {
        let (name, teacher, mesh, problem) = match path.map(load_character) {
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
        };
        if let Some(problem) = &problem {
            log::warn!("{problem}");
        }
        Self {
            name,
            gpu_mesh: renderer.upload(gpu, &mesh),
            mesh,
            teacher,
            problem,
        }
    }

    /// Advances the teacher `steps` frames under `action` and uploads the new pose.
    pub fn advance(&mut self, gpu: &GpuContext, action: Action, steps: u32) {
        let Some(teacher) = &mut self.teacher else {
            return;
        };
        if steps == 0 {
            return;
        }
        for _ in 0..steps {
            teacher.step(action);
        }
        self.mesh = teacher.mesh();
        self.gpu_mesh.write_vertices(gpu, &self.mesh);
    }

    pub fn gpu_mesh(&self) -> &GpuMesh {
        &self.gpu_mesh
    }

    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE))
    }
}

type Parts = (String, Option<Teacher>, Mesh, Option<String>);

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
