//! `unica rig`: a static mesh to a rigged, animated glTF. The skeleton comes from the
//! learned predictor (or the template-fit baseline), the skin from the learned skin model
//! (or the voxel geodesic prior alone), clips are retargeted from a rigged humanoid
//! through the template, and predicted spring chains (those on the mesh) become VRM 1.0
//! spring bones in the written file, beside its VRM humanoid map.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};

use super::data::{POINTS, VOXELS, outward_samples, surface_samples};
use super::gltf_out::{ClipOut, JointOut, RiggedMesh, write_glb};
use super::metrics::edge_stretch;
use super::model::{SkeletonModel, SkinModel, baseline_weights, top4};
use super::retarget::{rest_offsets, retarget};
use super::skeleton::{BODY, Class, FINGERS, Skeleton, UnitCube};
use super::smoothing;
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

/// The first joint of each spring chain (a spring joint under a non-spring one).
pub fn chain_roots(skeleton: &Skeleton) -> Vec<usize> {
    (0..skeleton.len())
        .filter(|&j| skeleton.spring[j] && skeleton.parents[j].is_some_and(|p| !skeleton.spring[p]))
        .collect()
}

/// The spring chains that swing something (at least two joints), each from its root.
pub fn swinging(skeleton: &Skeleton) -> Vec<Vec<usize>> {
    chain_roots(skeleton)
        .into_iter()
        .map(|root| chain_from(skeleton, root))
        .filter(|chain| chain.len() >= 2)
        .collect()
}

/// How many spring chains swing something ([`swinging`]).
pub fn swinging_chains(skeleton: &Skeleton) -> usize {
    swinging(skeleton).len()
}

/// A chain's joints: `root`, then its first spring child, and so on to the end.
fn chain_from(skeleton: &Skeleton, root: usize) -> Vec<usize> {
    let mut chain = vec![root];
    while let Some(next) = skeleton
        .children(*chain.last().expect("the root"))
        .find(|&c| skeleton.spring[c])
    {
        chain.push(next);
    }
    chain
}

/// A spring joint is on a loose part only when it lies within this share of the mesh's
/// height of its surface: hair strands, tails and cloth are thin (a joint in one, or on
/// a skirt's sheet, is within 1-3 % of the height of the surface), a joint deep in the
/// head, torso or hips is 6-10 % in, and one off the mesh is on no part at all. Measured
/// on 100 held-out synthetic characters (`unica rig-eval`, docs/autorig/report.md): 3 %
/// keeps 2.2 of 5.1 true chains per character, 4.5 % keeps 3.4, 6 % 4.2.
pub const LOOSE_DEPTH: f32 = 0.045;

/// A spring chain is on a loose part only where the body around it is thin: the median
/// [`thickness`] under the surface samples within [`LOOSE_DEPTH`] of its joints is at
/// most this share of the height. Hair strands, tails and cloth are thin (the Witch's
/// hair: 0.7 %; an open sheet counts as 0); a torso, hips or head is not (a block
/// humanoid's hips 6.7 %, its torso 13.9 %, a chibi's body 56 %).
pub const THIN_PART: f32 = 0.04;

/// The skeleton without spring joints that are not on a loose part: each spring joint
/// first moves onto the nearest thin surface within [`SNAP`] (see [`loose_springs`]);
/// then a chain stops at its first joint farther than [`LOOSE_DEPTH`] from the surface,
/// with everything below it, a chain on a thick part ([`THIN_PART`]) goes whole, and a
/// lone root left goes too; each chain left gets an end joint ([`with_chain_ends`]).
pub fn springs_on_loose_parts(skeleton: &Skeleton, mesh: &Mesh) -> Skeleton {
    let height = mesh.height();
    // As many samples as the skeleton model and `rig-eval` see.
    let (surface, normals) = outward_samples(mesh, POINTS, &mut Rng::new(0));
    let kept = loose_springs(skeleton, &surface, &normals, height);
    with_chain_ends(&kept, &surface, LOOSE_DEPTH * height)
}

/// The skeleton's spring chains that are on loose parts of the surface given by samples
/// and their outward normals (see [`springs_on_loose_parts`]), without end joints. The
/// spring joints are first snapped ([`snapped_to`]) onto thin samples: thin themselves
/// and in the median around them, off the arms ([`on_limbs`]) and not wrapped round a
/// bone ([`around_bones`]).
pub fn loose_springs(
    skeleton: &Skeleton,
    surface: &[Vec3],
    normals: &[Vec3],
    height: f32,
) -> Skeleton {
    let reach = LOOSE_DEPTH * height;
    let depth: Vec<f32> = (0..surface.len())
        .map(|i| thickness(surface, normals, i, height))
        .collect();
    let on_limb = on_limbs(skeleton, surface);
    let enclosing = around_bones(skeleton, surface, normals, &depth, height);
    // A target is on a thin part when the samples around it are (one sample's thickness
    // is 0 where its line misses the far wall's sparse samples).
    let thin_around = |i: usize| {
        let mut around: Vec<f32> = (0..surface.len())
            .filter(|&k| surface[k].distance_squared(surface[i]) <= reach * reach)
            .map(|k| depth[k])
            .collect();
        around.sort_by(f32::total_cmp);
        around[around.len() / 2] <= THIN_PART * height
    };
    let targets: Vec<Vec3> = (0..surface.len())
        .filter(|&i| {
            !on_limb[i] && !enclosing[i] && depth[i] <= THIN_PART * height && thin_around(i)
        })
        .map(|i| surface[i])
        .collect();
    let snapped = snapped_to(skeleton, &targets, SNAP * height);
    let near = springs_near(&snapped, surface, reach);
    let mut thick = vec![false; near.len()];
    for root in chain_roots(&near) {
        let chain = chain_from(&near, root);
        let joints: Vec<Vec3> = chain.iter().map(|&j| near.joints[j]).collect();
        let mut under: Vec<f32> = (0..surface.len())
            .filter(|&i| within(&joints, surface[i], reach))
            .map(|i| depth[i])
            .collect();
        under.sort_by(f32::total_cmp);
        if under.is_empty() || under[under.len() / 2] > THIN_PART * height {
            for j in chain {
                thick[j] = true;
            }
        }
    }
    near.keep(|j| !thick[j])
}

/// How far a predicted spring joint may move onto a thin part of the surface, as a share
/// of the height: the skeleton model puts chains a few centimetres inside the hips and
/// head, under the skirt or hair they should swing. Chains kept / kept along a true
/// chain per held-out humanoid with loose parts (50 each; `unica rig-eval` on `rig-data
/// --count 100 --seed 2900`, with `--plain` 5.1 true chains each, without 5.7):
///
/// | SNAP | plain generator | new generator |
/// | --- | --- | --- |
/// | 0 (none) | 0.58 / 0.42 | 0.48 / 0.30 |
/// | 5 % | 0.98 / 0.86 | 0.74 / 0.56 |
/// | 8 % | 1.80 / 1.64 | 1.06 / 0.74 |
/// | 12 % | 2.30 / 2.02 | 1.50 / 0.94 |
/// | 16 % | 2.86 / 2.28 | 1.92 / 1.14 |
///
/// None is kept on the 16 plain bodies at any of them. 12 %: three to five times as
/// many chains along a true one as without snapping; at 16 % more are kept, but fewer of
/// them along a true chain (80 % and 59 % against 88 % and 63 %).
pub const SNAP: f32 = 0.12;

/// Each spring joint moved to the nearest of `targets` within `reach` not taken by an
/// earlier joint (left where it is when none is, or when the nearest is within a tenth
/// of `reach` of where the chain's previous joint went: a chain never folds onto one
/// point, and two chains never start at one).
pub fn snapped_to(skeleton: &Skeleton, targets: &[Vec3], reach: f32) -> Skeleton {
    let mut out = skeleton.clone();
    let mut taken = vec![false; targets.len()];
    for j in 0..skeleton.len() {
        if !skeleton.spring[j] {
            continue;
        }
        let at = skeleton.joints[j];
        let Some(nearest) = (0..targets.len())
            .filter(|&t| !taken[t] && targets[t].distance(at) <= reach)
            .min_by(|&a, &b| targets[a].distance(at).total_cmp(&targets[b].distance(at)))
        else {
            continue;
        };
        // Parents come before children, so the parent has already moved.
        let parent = skeleton.parents[j].map(|p| out.joints[p]);
        if parent.is_none_or(|p| p.distance(targets[nearest]) > 0.1 * reach) {
            out.joints[j] = targets[nearest];
            taken[nearest] = true;
        }
    }
    out
}

/// Which surface samples are on a part wrapped round a bone of the skeleton (not a spring
/// bone): the point halfway to the far wall, `depth[i]` in along the inward normal, lies
/// within half that depth plus 1 % of the height (the predicted bones' slack) of a bone.
/// A slender leg is as thin as a skirt, but a skirt has no bone inside it.
pub fn around_bones(
    skeleton: &Skeleton,
    surface: &[Vec3],
    normals: &[Vec3],
    depth: &[f32],
    height: f32,
) -> Vec<bool> {
    let bones: Vec<(Vec3, Vec3)> = (0..skeleton.len())
        .filter(|&j| !skeleton.spring[j])
        .filter_map(|j| skeleton.bone(j))
        .collect();
    (0..surface.len())
        .map(|i| {
            let middle = surface[i] - 0.5 * depth[i] * normals[i];
            depth[i] > 0.0
                && bones
                    .iter()
                    .any(|&(a, b)| segment_distance(middle, a, b) <= 0.5 * depth[i] + 0.01 * height)
        })
        .collect()
}

/// Which surface samples lie nearest to an arm bone (upper arm, forearm, hand, fingers)
/// of the skeleton's humanoid template: hands and fingers are thin, but they are limbs
/// with bones of their own, not loose parts to hang springs on. All false for a
/// skeleton without those joints. (Not the neck: the head, its hair and hat are nearest
/// the neck's bone too; a slender neck is left out by [`around_bones`].)
pub fn on_limbs(skeleton: &Skeleton, surface: &[Vec3]) -> Vec<bool> {
    let limb = |name: &str| {
        let stem = name.split('.').next().unwrap_or(name);
        ["UpperArm", "LowerArm", "Wrist"].contains(&stem)
            || FINGERS.iter().any(|(finger, _)| stem.starts_with(finger))
    };
    // Each bone with whether it is an arm's (named by the joint it starts from).
    let bones: Vec<((Vec3, Vec3), bool)> = (0..skeleton.len())
        .filter(|&j| !skeleton.spring[j])
        .filter_map(|j| {
            Some((
                skeleton.bone(j)?,
                limb(&skeleton.names[skeleton.parents[j]?]),
            ))
        })
        .collect();
    surface
        .iter()
        .map(|&s| {
            bones
                .iter()
                .map(|&((a, b), arm)| (segment_distance(s, a, b), arm))
                .min_by(|x, y| x.0.total_cmp(&y.0))
                .is_some_and(|(_, arm)| arm)
        })
        .collect()
}

/// How thick the body is under surface sample `i`: the distance along its inward normal
/// to the nearest sample that faces away (the far wall), among those within 3 % of the
/// `height` of that line (the samples' spacing); 0 when no wall is found (an open sheet,
/// a card of hair).
pub fn thickness(surface: &[Vec3], normals: &[Vec3], i: usize, height: f32) -> f32 {
    let (from, inward) = (surface[i], -normals[i]);
    let (radius, skip) = (0.03 * height, 0.002 * height);
    let far = surface
        .iter()
        .zip(normals)
        .filter_map(|(&p, &n)| {
            let along = (p - from).dot(inward);
            let off = (p - from - along * inward).length();
            (along > skip && off < radius && n.dot(inward) > 0.3).then_some(along)
        })
        .fold(f32::INFINITY, f32::min);
    if far.is_finite() { far } else { 0.0 }
}

/// Whether some `surface` point lies within `reach` of `p`.
fn within(surface: &[Vec3], p: Vec3, reach: f32) -> bool {
    surface
        .iter()
        .any(|s| s.distance_squared(p) <= reach * reach)
}

/// The skeleton with an end joint below each chain's last joint, half its bone further
/// on (shortened until it is within `reach` of a `surface` point; none if even an eighth
/// is not): VRM's last joint of a spring is only a tail, so without an end the last
/// predicted joint would not swing.
pub fn with_chain_ends(skeleton: &Skeleton, surface: &[Vec3], reach: f32) -> Skeleton {
    let mut out = skeleton.clone();
    let near = |p: Vec3| within(surface, p, reach);
    for root in chain_roots(skeleton) {
        let last = *chain_from(skeleton, root).last().expect("the root");
        let Some(parent) = skeleton.parents[last] else {
            continue;
        };
        let (at, step) = (
            skeleton.joints[last],
            skeleton.joints[last] - skeleton.joints[parent],
        );
        let end = [0.5, 0.25, 0.125]
            .into_iter()
            .map(|f| at + f * step)
            .find(|&p| near(p));
        if let Some(end) = end {
            out.joints.push(end);
            out.parents.push(Some(last));
            out.names.push(format!("{}_end", skeleton.names[last]));
            out.spring.push(true);
        }
    }
    out
}

/// The skeleton without spring joints farther than `reach` from every `surface` point,
/// chains cut there and lone roots left out.
pub fn springs_near(skeleton: &Skeleton, surface: &[Vec3], reach: f32) -> Skeleton {
    let near = |p: Vec3| within(surface, p, reach);
    let keep: Vec<bool> = (0..skeleton.len())
        .map(|j| !skeleton.spring[j] || near(skeleton.joints[j]))
        .collect();
    let kept = skeleton.keep(|j| keep[j]);
    let lone: Vec<usize> = chain_roots(&kept)
        .into_iter()
        .filter(|&root| chain_from(&kept, root).len() < 2)
        .collect();
    kept.keep(|j| !lone.contains(&j))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A body joint at the origin with three spring chains of three joints each, going
    /// up along x = 0, x = 1 and x = 2.
    fn three_chains() -> Skeleton {
        let mut s = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO],
            parents: vec![None],
            names: vec!["Body".into()],
            spring: vec![false],
        };
        for c in 0..3 {
            for k in 0..3 {
                s.parents
                    .push(Some(if k == 0 { 0 } else { s.joints.len() - 1 }));
                s.joints.push(Vec3::new(c as f32, 1.0 + k as f32, 0.0));
                s.names.push(format!("chain{c}_{k}"));
                s.spring.push(true);
            }
        }
        s
    }

    #[test]
    fn chains_are_cut_where_they_leave_the_surface_and_get_ends() {
        let skeleton = three_chains();
        assert_eq!(chain_roots(&skeleton), vec![1, 4, 7]);
        assert_eq!(swinging_chains(&skeleton), 3);
        // The surface runs along chain 0 (to y = 4), past chain 1's first joint only,
        // and nowhere near chain 2.
        let mut surface: Vec<Vec3> = (0..=40)
            .map(|i| Vec3::new(0.0, i as f32 * 0.1, 0.0))
            .collect();
        surface.push(Vec3::new(1.0, 1.0, 0.0));
        let kept = springs_near(&skeleton, &surface, 0.2);
        // Chain 0 whole; chain 1 cut to a lone root and dropped; chain 2 gone.
        assert_eq!(kept.names, ["Body", "chain0_0", "chain0_1", "chain0_2"]);
        assert_eq!(kept.parents, [None, Some(0), Some(1), Some(2)]);
        // Its end half a bone on (y = 3.5), on the surface.
        let ended = with_chain_ends(&kept, &surface, 0.2);
        assert_eq!(ended.len(), 5);
        assert_eq!(ended.names[4], "chain0_2_end");
        assert_eq!(ended.parents[4], Some(3));
        assert_eq!(ended.joints[4], Vec3::new(0.0, 3.5, 0.0));
        assert!(ended.spring[4]);
        // Where half a bone on is off the surface, the end comes closer (a quarter).
        let short: Vec<Vec3> = surface.iter().copied().filter(|p| p.y <= 3.25).collect();
        let ended = with_chain_ends(&kept, &short, 0.06);
        assert_eq!(ended.joints[4], Vec3::new(0.0, 3.25, 0.0));
    }

    /// A box 1 tall, 0.4 wide and 0.3 deep (the body) and a plate 1 cm thick beside it
    /// (a loose part), every other triangle wound the wrong way (the vertex normals say
    /// which side is out).
    fn body_and_plate() -> Mesh {
        let mut mesh = Mesh::cuboid(
            Vec3::new(-0.2, 0.0, -0.15),
            Vec3::new(0.2, 1.0, 0.15),
            Vec3::ONE,
        );
        mesh.append(Mesh::cuboid(
            Vec3::new(0.3, 0.2, -0.005),
            Vec3::new(0.5, 0.8, 0.005),
            Vec3::ONE,
        ));
        for t in mesh.indices.chunks_exact_mut(6) {
            t.swap(1, 2);
        }
        mesh
    }

    #[test]
    fn thickness_is_the_distance_to_the_far_wall() {
        let mesh = body_and_plate();
        let (surface, normals) = outward_samples(&mesh, 8000, &mut Rng::new(1));
        let mut checked = 0;
        for i in 0..surface.len() {
            let p = surface[i];
            // Samples on the box's front face away from its edges: the back wall is 0.3 in.
            if normals[i].z > 0.99 && p.x.abs() < 0.15 && (0.05..0.95).contains(&p.y) && p.z > 0.1 {
                assert!(
                    (thickness(&surface, &normals, i, 1.0) - 0.3).abs() < 1e-4,
                    "{p}"
                );
                checked += 1;
            }
            // On the plate's faces: 1 cm.
            if normals[i].z.abs() > 0.99
                && (0.35..0.45).contains(&p.x)
                && (0.25..0.75).contains(&p.y)
            {
                assert!(
                    (thickness(&surface, &normals, i, 1.0) - 0.01).abs() < 1e-4,
                    "{p}"
                );
                checked += 1;
            }
        }
        assert!(checked > 500, "{checked}");
        // A lone sheet has no far wall.
        let sheet = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            normals: vec![Vec3::Z; 3],
            colors: vec![Vec3::ONE; 3],
            indices: vec![0, 1, 2],
        };
        let (surface, normals) = outward_samples(&sheet, 100, &mut Rng::new(1));
        assert_eq!(thickness(&surface, &normals, 0, 1.0), 0.0);
    }

    #[test]
    fn spring_joints_move_to_the_nearest_target_within_reach() {
        // Body -> a -> b -> c, the last three spring joints.
        let skeleton = Skeleton {
            class: Class::Other,
            joints: vec![
                Vec3::ZERO,
                Vec3::new(1.0, 0.0, 0.0),
                Vec3::new(1.4, 0.0, 0.0),
                Vec3::new(3.0, 0.0, 0.0),
            ],
            parents: vec![None, Some(0), Some(1), Some(2)],
            names: ["Body", "a", "b", "c"].map(String::from).to_vec(),
            spring: vec![false, true, true, true],
        };
        let targets = [
            Vec3::new(0.0, 0.1, 0.0),   // near the body joint, which never moves
            Vec3::new(1.0, 0.2, 0.0),   // a's nearest (0.2 away)
            Vec3::new(1.02, 0.22, 0.0), // b's nearest (0.44), 0.03 from where a went
            Vec3::new(3.0, 0.0, 0.6),   // c's, 0.6 away
        ];
        let snapped = snapped_to(&skeleton, &targets, 0.5);
        assert_eq!(snapped.joints[0], Vec3::ZERO);
        assert_eq!(snapped.joints[1], targets[1]);
        // b would fold onto a (within a tenth of the reach): it stays.
        assert_eq!(snapped.joints[2], skeleton.joints[2]);
        // c's nearest is out of reach: it stays, until the reach is wider.
        assert_eq!(snapped.joints[3], skeleton.joints[3]);
        let snapped = snapped_to(&skeleton, &targets, 0.7);
        assert_eq!(snapped.joints[3], targets[3]);
        // Given a target of its own (0.3 away, 0.41 from a's place), b moves.
        let own = Vec3::new(1.4, 0.3, 0.0);
        let snapped = snapped_to(&skeleton, &[targets[1], own], 0.5);
        assert_eq!(snapped.joints[1], targets[1]);
        assert_eq!(snapped.joints[2], own);
        // Two chains from one place: the first takes the nearest target, the second the
        // next (never two chains from one point).
        let twins = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO, Vec3::X, Vec3::X],
            parents: vec![None, Some(0), Some(0)],
            names: ["Body", "a", "b"].map(String::from).to_vec(),
            spring: vec![false, true, true],
        };
        let near = [Vec3::new(1.0, 0.1, 0.0), Vec3::new(1.0, -0.2, 0.0)];
        let snapped = snapped_to(&twins, &near, 0.5);
        assert_eq!(snapped.joints[1..], near);
    }

    #[test]
    fn samples_nearest_an_arm_bone_are_on_the_limbs() {
        // Chest -> Shoulder.L -> UpperArm.L -> LowerArm.L -> Wrist.L -> Index1.L, and a
        // spring chain from the chest that does not count as a bone here.
        let skeleton = Skeleton {
            class: Class::Humanoid,
            joints: vec![
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.1, 1.0, 0.0),
                Vec3::new(0.2, 1.0, 0.0),
                Vec3::new(0.5, 1.0, 0.0),
                Vec3::new(0.8, 1.0, 0.0),
                Vec3::new(0.9, 1.0, 0.0),
                Vec3::new(0.0, 1.0, -0.1),
                Vec3::new(0.6, 1.0, -0.1),
            ],
            parents: vec![
                None,
                Some(0),
                Some(1),
                Some(2),
                Some(3),
                Some(4),
                Some(0),
                Some(6),
            ],
            names: [
                "Chest",
                "Shoulder.L",
                "UpperArm.L",
                "LowerArm.L",
                "Wrist.L",
                "Index1.L",
                "Spring1",
                "Spring2",
            ]
            .map(String::from)
            .to_vec(),
            spring: vec![false, false, false, false, false, false, true, true],
        };
        let surface = [
            Vec3::new(0.35, 1.05, 0.0), // upper arm
            Vec3::new(0.65, 0.95, 0.0), // forearm
            Vec3::new(0.85, 1.0, 0.05), // hand
            Vec3::new(0.15, 1.05, 0.0), // shoulder: not a limb bone
            Vec3::new(0.0, 0.9, 0.0),   // at the chest
            Vec3::new(0.5, 1.0, -0.1),  // by the spring chain, nearest the upper arm
        ];
        assert_eq!(
            on_limbs(&skeleton, &surface),
            [true, true, true, false, false, true]
        );
        // A skeleton without arm joints has no limbs.
        let plain = skeleton.keep(|j| j == 0 || j >= 6);
        assert!(on_limbs(&plain, &surface).iter().all(|&l| !l));
    }

    #[test]
    fn a_part_wrapped_round_a_bone_is_a_limb_and_a_sheet_beside_it_is_not() {
        // A bone up the y axis (a leg 10 cm across) and a spring chain at x = 1.
        let skeleton = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO, Vec3::Y, Vec3::X, Vec3::new(1.0, 1.0, 0.0)],
            parents: vec![None, Some(0), None, Some(2)],
            names: ["Knee", "Hip", "Spring0", "Spring1"]
                .map(String::from)
                .to_vec(),
            spring: vec![false, false, true, true],
        };
        let surface = [
            Vec3::new(0.05, 0.5, 0.0), // the leg's side: 10 cm to its far wall
            Vec3::new(0.2, 0.5, 0.0),  // a sheet 20 cm out: no far wall
            Vec3::new(0.2, 0.5, 0.0),  // a 10 cm plate 20 cm out: its middle is 15 cm off
            Vec3::new(1.05, 0.5, 0.0), // round the spring chain only
        ];
        let normals = [Vec3::X; 4];
        let depth = [0.1, 0.0, 0.1, 0.1];
        let height = 2.0; // slack: 2 cm
        assert_eq!(
            around_bones(&skeleton, &surface, &normals, &depth, height),
            [true, false, false, false]
        );
        // Half the depth plus the slack: a bone 6.5 cm from the middle of the 10 cm leg
        // is within 5 + 2 cm, one 7.5 cm off is not.
        let off = skeleton.map_joints(|p| p + Vec3::new(-0.065, 0.0, 0.0));
        assert!(around_bones(&off, &surface, &normals, &depth, height)[0]);
        let far = skeleton.map_joints(|p| p + Vec3::new(-0.075, 0.0, 0.0));
        assert!(!around_bones(&far, &surface, &normals, &depth, height)[0]);
    }

    #[test]
    fn chains_on_a_thick_body_go_and_chains_on_a_thin_part_stay() {
        let mut skeleton = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::new(0.0, 0.5, 0.0)],
            parents: vec![None],
            names: vec!["Body".into()],
            spring: vec![false],
        };
        // Chain "plate" down the plate's middle; chain "back" 4 cm under the box's back
        // face (within LOOSE_DEPTH of the surface, but in a body 30 cm deep).
        for (name, x, z) in [("plate", 0.4, 0.0), ("back", 0.0, -0.11)] {
            for (k, y) in [0.7, 0.5, 0.3].into_iter().enumerate() {
                skeleton
                    .parents
                    .push(Some(if k == 0 { 0 } else { skeleton.joints.len() - 1 }));
                skeleton.joints.push(Vec3::new(x, y, z));
                skeleton.names.push(format!("{name}{k}"));
                skeleton.spring.push(true);
            }
        }
        let kept = springs_on_loose_parts(&skeleton, &body_and_plate());
        assert_eq!(
            kept.names,
            ["Body", "plate0", "plate1", "plate2", "plate2_end"]
        );
    }
}
