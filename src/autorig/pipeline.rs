//! `unica rig`: a static mesh to a rigged, animated glTF. The skeleton comes from the
//! learned predictor (or the template-fit baseline), the skin from the learned skin model
//! (or the voxel geodesic prior alone), clips are retargeted from a rigged humanoid
//! through the template, and predicted spring chains become the description's springs.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};

use super::data::{POINTS, VOXELS, surface_samples};
use super::gltf_out::{ClipOut, JointOut, RiggedMesh, write_glb};
use super::model::{SkeletonModel, SkinModel, baseline_weights, top4};
use super::retarget::{rest_offsets, retarget};
use super::skeleton::{BODY, Class, Skeleton, UnitCube};
use super::synth;
use super::voxel::{Voxels, bone_tails};
use crate::avatar::description::{ClipNames, ColliderSpec, Description, SpringChain};
use crate::avatar::rig::Transform;
use crate::avatar::{load_character, load_character_with};
use crate::mesh::Mesh;
use crate::random::Rng;

/// The clips every rigged humanoid gets (the teacher's idle, walk and run).
pub const CLIPS: [&str; 3] = ["Idle", "Walk", "Run"];

/// How the skeleton was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SkeletonSource {
    Learned,
    TemplateFit,
}

/// How the skin weights were made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SkinSource {
    Learned,
    GeodesicPrior,
}

/// The auto-rigger's models, when trained ones are present.
pub struct Models {
    pub skeleton: Option<SkeletonModel>,
    pub skin: Option<SkinModel>,
    /// β of the prior-alone weights softmax(−β·geodesic).
    pub beta: f32,
}

/// β of the geodesic prior when no trained skin model gives a fitted one.
pub const DEFAULT_BETA: f32 = 40.0;

impl Models {
    /// Loads `dir/skeleton.*` and `dir/skin.*` where present (either may be missing,
    /// not both).
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        if !dir.join("skeleton.safetensors").is_file() && !dir.join("skin.safetensors").is_file() {
            anyhow::bail!(
                "{}: no auto-rig models (skeleton.safetensors, skin.safetensors); train them (see assets/autorig/README.md) or use the baselines",
                dir.display()
            );
        }
        let skeleton = dir
            .join("skeleton.safetensors")
            .is_file()
            .then(|| SkeletonModel::load(dir))
            .transpose()?;
        let skin = dir
            .join("skin.safetensors")
            .is_file()
            .then(|| SkinModel::load(dir))
            .transpose()?;
        let beta = skin
            .as_ref()
            .and_then(|s| s.config().baseline_beta)
            .unwrap_or(DEFAULT_BETA);
        Ok(Self {
            skeleton,
            skin,
            beta,
        })
    }

    pub fn none() -> Self {
        Self {
            skeleton: None,
            skin: None,
            beta: DEFAULT_BETA,
        }
    }
}

/// The body joints of the mean synthetic humanoid at rest, each axis as a fraction of
/// its mesh's bounds (computed once).
fn mean_humanoid() -> &'static [Vec3] {
    static MEAN: std::sync::OnceLock<Vec<Vec3>> = std::sync::OnceLock::new();
    MEAN.get_or_init(|| {
        const SAMPLES: u64 = 24;
        let mut mean = vec![Vec3::ZERO; BODY.len()];
        for seed in 0..SAMPLES {
            let c = synth::of_class(seed, Class::Humanoid, 0.0);
            let (lo, hi) = c.mesh.bounds().expect("a synthetic mesh");
            for (k, (name, _)) in BODY.iter().enumerate() {
                let j = c
                    .skeleton
                    .names
                    .iter()
                    .position(|n| n == name)
                    .expect("body joint");
                mean[k] += (c.skeleton.joints[j] - lo) / (hi - lo) / SAMPLES as f32;
            }
        }
        mean
    })
}

/// The template-fit baseline: the mean synthetic humanoid's body joints, each axis
/// scaled into the mesh's bounds (what a bounding-box template fit gives).
pub fn template_fit(mesh: &Mesh) -> Skeleton {
    let mean = mean_humanoid();
    let (lo, hi) = mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE));
    Skeleton {
        class: Class::Humanoid,
        joints: mean.iter().map(|&m| lo + m * (hi - lo)).collect(),
        parents: BODY.iter().map(|(_, p)| *p).collect(),
        names: BODY.iter().map(|(n, _)| n.to_string()).collect(),
        spring: vec![false; BODY.len()],
    }
}

/// The skeleton of `mesh` (its own units): predicted when a model is given, else the
/// template fit.
pub fn skeleton_for(
    mesh: &Mesh,
    model: Option<&SkeletonModel>,
    seed: u64,
) -> anyhow::Result<(Skeleton, SkeletonSource)> {
    let Some(model) = model else {
        return Ok((template_fit(mesh), SkeletonSource::TemplateFit));
    };
    let cube = UnitCube::of_points(&mesh.positions);
    let unit = cube.mesh_to_unit(mesh);
    let (points, normals) = surface_samples(&unit, POINTS, &mut Rng::new(seed));
    let skeleton = model.predict(&points, &normals, Some(Class::Humanoid), 0.0, seed)?;
    Ok((
        skeleton.map_joints(|p| cube.from_unit(p)),
        SkeletonSource::Learned,
    ))
}

/// Full skin weights `[vertex][joint]` of `mesh` for `skeleton` (both in the mesh's
/// units), from the skin model or the geodesic prior alone.
pub fn skin_for(mesh: &Mesh, skeleton: &Skeleton, models: &Models) -> (Vec<Vec<f32>>, SkinSource) {
    let cube = UnitCube::of_points(&mesh.positions);
    let unit = cube.mesh_to_unit(mesh);
    let joints: Vec<Vec3> = skeleton.joints.iter().map(|&p| cube.to_unit(p)).collect();
    let geodesic = Voxels::new(&unit, VOXELS).geodesic(&unit.positions, &joints, &skeleton.parents);
    let flat: Vec<f32> = geodesic.concat();
    match &models.skin {
        Some(model) => {
            let tails = bone_tails(&joints, &skeleton.parents);
            let weights = model.weights(&unit.positions, &unit.normals, &joints, &tails, &flat);
            (weights, SkinSource::Learned)
        }
        None => (
            baseline_weights(models.beta, &flat, skeleton.len()),
            SkinSource::GeodesicPrior,
        ),
    }
}

/// What `unica rig` made.
pub struct Summary {
    pub skeleton: SkeletonSource,
    pub skin: SkinSource,
    pub joints: usize,
    pub spring_chains: usize,
    pub clips: usize,
    pub description: PathBuf,
}

/// Rigs the mesh of `input` (any skin it has is ignored) into `out` (.glb) plus the
/// teacher's description beside it, clips retargeted from `clips_from` (plus the clips of
/// the animation libraries `clip_files`, merged by joint name): its clips named
/// Idle/Walk/Run, else those its description (found or inferred) names.
pub fn rig_file(
    input: &Path,
    out: &Path,
    models: &Models,
    clips_from: &Path,
    clip_files: &[std::path::PathBuf],
    seed: u64,
    progress: &dyn Fn(&str),
) -> anyhow::Result<Summary> {
    let character = load_character(input)?;
    let mesh = character.rest_mesh();
    if mesh.indices.is_empty() {
        anyhow::bail!("{}: the mesh has no triangles to rig", input.display());
    }
    progress("skeleton");
    let (skeleton, skeleton_source) = skeleton_for(&mesh, models.skeleton.as_ref(), seed)?;
    if skeleton.class != Class::Humanoid {
        anyhow::bail!(
            "{}: the predicted skeleton is not humanoid; only humanoids get the template's clips",
            input.display()
        );
    }
    progress("skin weights");
    let (weights, skin_source) = skin_for(&mesh, &skeleton, models);
    let (skin_joints, skin_weights): (Vec<[u16; 4]>, Vec<[f32; 4]>) =
        weights.iter().map(|w| top4(w)).unzip();
    progress("clips");
    let source = load_character_with(clips_from, clip_files)?;
    let named = CLIPS.iter().all(|name| source.clip(name).is_ok());
    let roles: [String; 3] = if named {
        CLIPS.map(String::from)
    } else {
        let described = crate::avatar::description::Description::find(&source, None)?.clips;
        [described.idle, described.walk, described.run]
    };
    let clips: Vec<ClipOut> = CLIPS
        .iter()
        .zip(&roles)
        .map(|(name, role)| {
            let mut clip = retarget(&source, role, &skeleton)?;
            clip.name = name.to_string();
            Ok(clip)
        })
        .collect::<anyhow::Result<_>>()?;
    let joints: Vec<JointOut> = rest_offsets(&skeleton)
        .into_iter()
        .enumerate()
        .map(|(j, offset)| JointOut {
            name: skeleton.names[j].clone(),
            parent: skeleton.parents[j],
            rest: Transform {
                translation: offset,
                rotation: Quat::IDENTITY,
                scale: Vec3::ONE,
            },
        })
        .collect();
    progress("writing");
    write_glb(
        out,
        &RiggedMesh {
            name: &character.name,
            mesh: &mesh,
            joints: &joints,
            skin_joints: &skin_joints,
            skin_weights: &skin_weights,
            clips: &clips,
        },
    )?;
    let description = description_for(&skeleton);
    let description_path = out.with_extension("avatar.json");
    crate::files::write_atomic(
        &description_path,
        serde_json::to_string_pretty(&description)?.as_bytes(),
    )?;
    Ok(Summary {
        skeleton: skeleton_source,
        skin: skin_source,
        joints: skeleton.len(),
        spring_chains: description.spring_chains.len(),
        clips: clips.len(),
        description: description_path,
    })
}

/// The teacher's description of a rigged humanoid: template clips and bones, colliders
/// on legs, hips, spine and head, and one spring chain per predicted chain root.
pub fn description_for(skeleton: &Skeleton) -> Description {
    let collider = |bone: &str, to: Option<&str>| ColliderSpec {
        bone: bone.into(),
        to: to.map(Into::into),
        radius: None,
    };
    let spring_chains = (0..skeleton.len())
        .filter(|&j| skeleton.spring[j] && skeleton.parents[j].is_some_and(|p| !skeleton.spring[p]))
        .map(|j| SpringChain {
            root: skeleton.names[j].clone(),
            stiffness: 1.5,
            drag: 0.4,
            gravity: 0.3,
        })
        .collect();
    Description {
        clips: ClipNames {
            idle: CLIPS[0].into(),
            walk: CLIPS[1].into(),
            run: CLIPS[2].into(),
        },
        waist_bones: vec!["Hips".into(), "Abdomen".into()],
        feet: vec!["Foot.L".into(), "Foot.R".into()],
        forward: "+z".into(),
        walk_speed: None,
        run_speed: None,
        loose_parts: Vec::new(),
        colliders: vec![
            collider("UpperLeg.L", Some("LowerLeg.L")),
            collider("UpperLeg.R", Some("LowerLeg.R")),
            collider("LowerLeg.L", Some("Foot.L")),
            collider("LowerLeg.R", Some("Foot.R")),
            collider("Hips", None),
            collider("Abdomen", Some("Chest")),
            collider("Head", None),
        ],
        spring_chains,
        inferred: None,
    }
}
