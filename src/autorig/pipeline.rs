//! `unica rig`: a static mesh to a rigged, animated glTF. The skeleton comes from the
//! learned predictor (or the template-fit baseline), the skin from the learned skin model
//! (or the voxel geodesic prior alone), clips are retargeted from a rigged humanoid
//! through the template, and predicted spring chains (those on the mesh) become VRM 1.0
//! spring bones in the written file, beside its VRM humanoid map.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};

use super::data::{POINTS, VOXELS, surface_samples};
use super::gltf_out::{ClipOut, JointOut, RiggedMesh, write_glb};
use super::metrics::edge_stretch;
use super::model::{SkeletonModel, SkinModel, baseline_weights, top4};
use super::retarget::{rest_offsets, retarget};
use super::skeleton::{BODY, Class, Skeleton, UnitCube};
use super::smoothing;
use super::spring_chains::{chain_roots, springs_on_loose_parts, swinging};
use super::synth;
use super::voxel::{Voxels, bone_tails, segment_distance};
use crate::avatar::character::Character;
use crate::avatar::description::{ClipNames, Description};
use crate::avatar::humanoid::vrm_name;
use crate::avatar::rig::Transform;
use crate::avatar::springs::median_radius;
use crate::avatar::vrm::{Vrm, VrmCollider, VrmJoint, VrmSpring};
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
            let c = synth::of_class(seed, Class::Humanoid, 0.0, false);
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
/// units), from the skin model or the geodesic prior alone, then smoothed along the
/// surface ([`smoothing::smooth`]).
pub fn skin_for(mesh: &Mesh, skeleton: &Skeleton, models: &Models) -> (Vec<Vec<f32>>, SkinSource) {
    let cube = UnitCube::of_points(&mesh.positions);
    let unit = cube.mesh_to_unit(mesh);
    let joints: Vec<Vec3> = skeleton.joints.iter().map(|&p| cube.to_unit(p)).collect();
    let geodesic = Voxels::new(&unit, VOXELS).geodesic(&unit.positions, &joints, &skeleton.parents);
    let flat: Vec<f32> = geodesic.concat();
    let tails = bone_tails(&joints, &skeleton.parents);
    let (mut weights, source) = match &models.skin {
        Some(model) => (
            model.weights(&unit.positions, &unit.normals, &joints, &tails, &flat),
            SkinSource::Learned,
        ),
        None => (
            baseline_weights(models.beta, &flat, skeleton.len()),
            SkinSource::GeodesicPrior,
        ),
    };
    smoothing::smooth(&unit, &mut weights, smoothing::ROUNDS);
    (weights, source)
}

/// What `unica rig` made.
pub struct Summary {
    pub skeleton: SkeletonSource,
    pub skin: SkinSource,
    pub joints: usize,
    /// Spring chains written (VRM springs that swing at least one joint).
    pub spring_chains: usize,
    /// Predicted chains left out: not on a loose part, or a single joint (nothing swings).
    pub dropped_chains: usize,
    /// The joint each written spring chain hangs from, in the order of the VRM springs.
    pub chain_parents: Vec<String>,
    pub clips: usize,
    pub description: PathBuf,
    /// Tearing: the largest edge stretch (posed / rest length) over [`STRETCH_KEYS`]
    /// (`None` where the written rig could not be driven; a warning says why).
    pub stretch: Option<f32>,
    /// What became of the template's finger joints.
    pub hands: Hands,
    /// The sampling seed of the rig written, and each try's (seed, largest edge stretch).
    pub seed: u64,
    pub tries: Vec<(u64, Option<f32>)>,
}

/// The drive that measures tearing: stand, go toward +Z, turn to +X, turn to -Z, stop
/// (the moves speed up to a run).
pub const STRETCH_KEYS: &str = "10I 40W 20A 30S 20I";

/// The largest edge stretch of the rigged character at `path` (its description beside
/// it) driven by the teacher through [`STRETCH_KEYS`]; edges shorter than 0.1 % of the
/// height are not counted.
pub fn walk_stretch(path: &Path) -> anyhow::Result<f32> {
    use crate::avatar::teacher::Teacher;
    let character = load_character(path)?;
    let rest = character.rest_mesh();
    let height = rest.height();
    let description = Description::find(&character, None)?;
    let mut teacher = Teacher::new(character, description)?;
    let mut worst: f32 = 1.0;
    let script = crate::action::KeyScript::parse(STRETCH_KEYS)?;
    for frame in 0..script.len() {
        teacher.step(script.action_at(frame));
        let posed = teacher.mesh();
        worst = worst.max(edge_stretch(
            &rest.positions,
            &posed.positions,
            &rest.indices,
            1e-3 * height,
        ));
    }
    Ok(worst)
}

/// How `unica rig` rigs: where the clips come from, the sampling seed, hands or not.
pub struct RigOptions<'a> {
    /// The rigged humanoid whose clips are retargeted.
    pub clips_from: &'a Path,
    /// Animation libraries merged into `clips_from`'s clips by joint name.
    pub clip_files: &'a [PathBuf],
    /// The surface sampling seed of the first try.
    pub seed: u64,
    /// How many skeletons to predict (from surface samplings `seed`, `seed + 1`, …); the
    /// rig that tears least over the walk is written (see [`rig_file`]).
    pub tries: u64,
    /// Offer the template's finger joints (when the skeleton has them); they are kept
    /// only where they do not tear the mesh (see [`HAND_TEARING`]).
    pub hands: bool,
}

/// The finger joints are dropped when the rig with them stretches an edge over the walk
/// more than this many times as far as the rig without them: a mitten hand, or fingers
/// the mesh does not separate, tear into spikes when the retargeted clips curl joints
/// placed in them (the T-posed synthetic humanoid of tests/autorig: 14.5 with the finger
/// joints, 3.9 without; the Witch, whose fingers are modelled, keeps them).
pub const HAND_TEARING: f32 = 1.5;

/// What became of the template's finger joints.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Hands {
    /// Kept: the skeleton has them and they do not tear the mesh.
    Kept,
    /// Not asked for (`--no-hands`), or the skeleton has none.
    None,
    /// Dropped because the rig with them stretched the mesh this far over the walk
    /// (the rig without them is in the summary's `stretch`).
    DroppedTearing(f32),
}

/// Rigs the mesh of `input` (any skin it has is ignored) into `out` (.glb) plus the
/// teacher's description beside it, clips retargeted from `options.clips_from` (plus the
/// clips of its animation libraries, merged by joint name): its clips named Idle/Walk/Run,
/// else those its description (found or inferred) names. The .glb carries VRM 1.0's
/// humanoid map and the spring chains with their colliders (`VRMC_vrm`,
/// `VRMC_springBone`). Finger joints are kept only where they do not tear the mesh
/// ([`HAND_TEARING`]): the rig is then made and measured both ways.
///
/// With the skeleton model, `options.tries` skeletons are predicted from different
/// samplings of the surface (seeds `options.seed`, `options.seed + 1`, …) and the rig
/// whose walk stretches an edge least is written (the first of those within 1 %,
/// [`TRIES_MARGIN`]). The model's
/// spring chains vary most between samplings: on the Witch, sampling 0 puts chains on
/// her hair and hat only (5.35), sampling 2 also one on her skirt (5.26), samplings 1,
/// 4 and 5 put four to six on her skirt that tear it (10.1-11.9).
pub fn rig_file(
    input: &Path,
    out: &Path,
    models: &Models,
    options: &RigOptions,
    progress: &dyn Fn(&str),
) -> anyhow::Result<Summary> {
    let character = load_character(input)?;
    let mesh = character.rest_mesh();
    if mesh.indices.is_empty() {
        anyhow::bail!("{}: the mesh has no triangles to rig", input.display());
    }
    let source = load_character_with(options.clips_from, options.clip_files)?;
    // The template fit does not depend on the sampling: one try.
    let tries = if models.skeleton.is_some() {
        options.tries.max(1)
    } else {
        1
    };
    let mut best: Option<(Summary, PathBuf)> = None;
    let mut measured = Vec::new();
    for k in 0..tries {
        let seed = options.seed + k;
        let path = if k == 0 {
            out.to_path_buf()
        } else {
            out.with_extension(format!("try{k}.glb"))
        };
        if tries > 1 {
            progress(&format!("try {} of {tries} (sampling seed {seed})", k + 1));
        }
        let mut summary = rig_once(
            &character, &mesh, &source, input, &path, models, options, seed, progress,
        )?;
        summary.seed = seed;
        measured.push((seed, summary.stretch));
        // Better by more than 1 %: rigid parts measure 1.00 give or take rounding.
        let better = best.as_ref().is_none_or(|(kept, _)| {
            summary
                .stretch
                .is_some_and(|s| kept.stretch.is_none_or(|k| s < TRIES_MARGIN * k))
        });
        if better {
            if let Some((_, old)) = best.take() {
                remove_rig(&old, out);
            }
            best = Some((summary, path));
        } else {
            remove_rig(&path, out);
        }
    }
    let (mut summary, path) = best.expect("at least one try");
    if path != out {
        std::fs::rename(&path, out)
            .map_err(|e| anyhow::anyhow!("{}: cannot replace it: {e}", out.display()))?;
        let _ = std::fs::remove_file(path.with_extension("avatar.json"));
        summary.description = out.with_extension("avatar.json");
    }
    summary.tries = measured;
    Ok(summary)
}

/// A later try replaces the best so far only when its largest edge stretch is below this
/// share of that one's.
pub const TRIES_MARGIN: f32 = 0.99;

/// Removes a try's rig at `path` and its description, unless it is `out`'s (the
/// description beside `out` is the one every try writes alike).
fn remove_rig(path: &Path, out: &Path) {
    if path != out {
        let _ = std::fs::remove_file(path);
        let _ = std::fs::remove_file(path.with_extension("avatar.json"));
    }
}

/// One try of [`rig_file`]: the skeleton from the surface sampling `seed`, its rig
/// written at `out` (with and without finger joints where it has them).
#[allow(clippy::too_many_arguments)]
fn rig_once(
    character: &Character,
    mesh: &Mesh,
    source: &Character,
    input: &Path,
    out: &Path,
    models: &Models,
    options: &RigOptions,
    seed: u64,
    progress: &dyn Fn(&str),
) -> anyhow::Result<Summary> {
    progress("skeleton");
    let (skeleton, skeleton_source) = skeleton_for(mesh, models.skeleton.as_ref(), seed)?;
    if skeleton.class != Class::Humanoid {
        anyhow::bail!(
            "{}: the predicted skeleton is not humanoid; only humanoids get the template's clips",
            input.display()
        );
    }
    let body = skeleton.without_hands();
    let has_fingers = body.len() < skeleton.len();
    let rig = |skeleton: &Skeleton, path: &Path| {
        write_rig(
            &character.name,
            mesh,
            skeleton,
            source,
            models,
            path,
            progress,
        )
    };
    if !(options.hands && has_fingers) {
        let written = rig(&body, out)?;
        return Ok(written.summary(skeleton_source, Hands::None));
    }
    let with = rig(&skeleton, out)?;
    let Some(stretch_with) = with.stretch else {
        return Ok(with.summary(skeleton_source, Hands::Kept));
    };
    progress("the same rig without finger joints");
    let spare = out.with_extension("no-hands.glb");
    let without = rig(&body, &spare)?;
    // Both descriptions are the same; the one beside `out` stays.
    let _ = std::fs::remove_file(&without.description);
    let tears = without
        .stretch
        .is_some_and(|stretch| stretch_with > HAND_TEARING * stretch);
    if tears {
        std::fs::rename(&spare, out)
            .map_err(|e| anyhow::anyhow!("{}: cannot replace it: {e}", out.display()))?;
        let summary = Written {
            description: with.description,
            ..without
        };
        Ok(summary.summary(skeleton_source, Hands::DroppedTearing(stretch_with)))
    } else {
        let _ = std::fs::remove_file(&spare);
        Ok(with.summary(skeleton_source, Hands::Kept))
    }
}

/// One skeleton's rig as written: what the summary reports of it.
struct Written {
    skin: SkinSource,
    joints: usize,
    spring_chains: usize,
    dropped_chains: usize,
    chain_parents: Vec<String>,
    clips: usize,
    description: PathBuf,
    stretch: Option<f32>,
}

impl Written {
    fn summary(self, skeleton: SkeletonSource, hands: Hands) -> Summary {
        Summary {
            seed: 0,
            tries: Vec::new(),
            skeleton,
            skin: self.skin,
            joints: self.joints,
            spring_chains: self.spring_chains,
            dropped_chains: self.dropped_chains,
            chain_parents: self.chain_parents,
            clips: self.clips,
            description: self.description,
            stretch: self.stretch,
            hands,
        }
    }
}

/// Skins `mesh` to `skeleton` (spring chains kept only on loose parts), retargets the
/// clips of `source`, writes the .glb at `out` with the description beside it, and
/// measures the walk's tearing.
fn write_rig(
    name: &str,
    mesh: &Mesh,
    skeleton: &Skeleton,
    source: &Character,
    models: &Models,
    out: &Path,
    progress: &dyn Fn(&str),
) -> anyhow::Result<Written> {
    let chains_before = chain_roots(skeleton).len();
    let skeleton = springs_on_loose_parts(skeleton, mesh);
    progress("skin weights");
    let (weights, skin_source) = skin_for(mesh, &skeleton, models);
    let (skin_joints, skin_weights): (Vec<[u16; 4]>, Vec<[f32; 4]>) =
        weights.iter().map(|w| top4(w)).unzip();
    progress("clips");
    let named = CLIPS.iter().all(|name| source.clip(name).is_ok());
    let roles: [String; 3] = if named {
        CLIPS.map(String::from)
    } else {
        let described = crate::avatar::description::Description::find(source, None)?.clips;
        [described.idle, described.walk, described.run]
    };
    let clips: Vec<ClipOut> = CLIPS
        .iter()
        .zip(&roles)
        .map(|(name, role)| {
            let mut clip = retarget(source, role, &skeleton)?;
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
    let vrm = vrm_for(&skeleton, mesh, &weights);
    progress("writing");
    write_glb(
        out,
        &RiggedMesh {
            name,
            mesh,
            joints: &joints,
            skin_joints: &skin_joints,
            skin_weights: &skin_weights,
            clips: &clips,
            vrm: Some(&vrm),
        },
    )?;
    let description = description_for();
    let description_path = out.with_extension("avatar.json");
    crate::files::write_atomic(
        &description_path,
        serde_json::to_string_pretty(&description)?.as_bytes(),
    )?;
    progress("tearing (edge stretch over a walk)");
    let stretch = walk_stretch(out)
        .inspect_err(|e| log::warn!("{}: tearing not measured: {e:#}", out.display()))
        .ok();
    Ok(Written {
        skin: skin_source,
        joints: skeleton.len(),
        spring_chains: vrm.springs.len(),
        dropped_chains: chains_before - vrm.springs.len(),
        chain_parents: swinging(&skeleton)
            .iter()
            .filter_map(|chain| skeleton.parents[chain[0]].map(|p| skeleton.names[p].clone()))
            .collect(),
        clips: clips.len(),
        description: description_path,
        stretch,
    })
}

/// VRM 1.0's view of a rigged humanoid: the humanoid map of its template joints, one
/// spring per chain of at least two joints (the last is the tail) and capsule colliders
/// on the legs, hips, spine and head with radii measured from the skin.
pub fn vrm_for(skeleton: &Skeleton, mesh: &Mesh, weights: &[Vec<f32>]) -> Vrm {
    let height = mesh.height();
    let humanoid = (0..skeleton.len())
        .filter_map(|j| vrm_name(&skeleton.names[j]).map(|bone| (bone, j)))
        .collect();
    let find = |name: &str| skeleton.names.iter().position(|n| n == name);
    let colliders: Vec<VrmCollider> = COLLIDERS
        .iter()
        .filter_map(|&(bone, to)| {
            let node = find(bone)?;
            let to = to.and_then(find);
            let a = skeleton.joints[node];
            let b = to.map(|t| skeleton.joints[t]);
            // The median distance to the axis of the vertices this joint mostly moves.
            let distances: Vec<f32> = (0..mesh.positions.len())
                .filter(|&v| weights[v][node] > 0.5)
                .map(|v| {
                    let p = mesh.positions[v];
                    b.map_or(p.distance(a), |b| segment_distance(p, a, b))
                })
                .collect();
            Some(VrmCollider {
                node,
                offset: Vec3::ZERO,
                radius: median_radius(distances, height),
                tail: b.map(|b| b - a),
            })
        })
        .collect();
    let springs = swinging(skeleton)
        .into_iter()
        .enumerate()
        .map(|(i, chain)| VrmSpring {
            name: format!("chain{i}"),
            joints: chain
                .iter()
                .map(|&node| VrmJoint {
                    stiffness: 1.5,
                    drag: 0.4,
                    gravity_power: 0.3,
                    hit_radius: 0.01 * height,
                    ..VrmJoint::new(node)
                })
                .collect(),
            collider_groups: vec![0],
        })
        .collect();
    Vrm {
        humanoid,
        springs,
        collider_groups: vec![(0..colliders.len()).collect()],
        colliders,
    }
}

/// Colliders of a rigged humanoid: (bone, capsule end bone).
const COLLIDERS: [(&str, Option<&str>); 7] = [
    ("UpperLeg.L", Some("LowerLeg.L")),
    ("UpperLeg.R", Some("LowerLeg.R")),
    ("LowerLeg.L", Some("Foot.L")),
    ("LowerLeg.R", Some("Foot.R")),
    ("Hips", None),
    ("Abdomen", Some("Chest")),
    ("Head", None),
];

/// The teacher's description of a rigged humanoid: template clips and bones (its spring
/// chains and colliders are in the file, as VRM spring bones).
pub fn description_for() -> Description {
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
        colliders: Vec::new(),
        spring_chains: Vec::new(),
        inferred: None,
    }
}
