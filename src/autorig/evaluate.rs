//! `unica rig-eval`: the auto-rigger measured on characters its models never saw —
//! held-out synthetic pairs and a rigged file (the Witch) with its skin removed — for the
//! learned models and the geometric baselines side by side (results.json, report.md).

use std::path::Path;

use glam::{Mat4, Vec3};
use serde_json::{Value, json};

use super::data::VOXELS;
use super::data::{Sample, dense, sample_path, skin_of_character};
use super::metrics::{b2b, j2b, j2j, motion_l2, random_poses, skin_l1};
use super::model::{baseline_weights, top4};
use super::pipeline::{Models, skeleton_for, template_fit};
use super::skeleton::{BODY, Class, Skeleton, UnitCube, of_character};
use super::smoothing;
use super::spring_chains::{LOOSE_DEPTH, loose_springs, swinging, swinging_chains};
use super::tokens::{decode, encode, naive_length};
use super::voxel::{Voxels, bone_tails, segment_distance};
use crate::avatar::load_character;
use crate::mesh::Mesh;

/// Random poses per synthetic character for motion L2, and their largest turn.
const POSES: usize = 8;
const POSE_DEGREES: f32 = 30.0;

/// Full rows `[vertex][joint]` keeping only each vertex's top four, renormalised.
fn top4_rows(weights: &[Vec<f32>]) -> Vec<Vec<f32>> {
    weights
        .iter()
        .map(|w| {
            let (joints, values) = top4(w);
            dense(joints.iter().map(|&j| j as usize).zip(values), w.len())
        })
        .collect()
}

/// Skeleton distances as JSON.
fn skeleton_scores(predicted: &Skeleton, truth: &Skeleton) -> [f32; 3] {
    [
        j2j(predicted, truth),
        j2b(predicted, truth),
        b2b(predicted, truth),
    ]
}

fn mean(rows: &[[f32; 3]]) -> Value {
    let n = rows.len().max(1) as f32;
    let m = |k: usize| rows.iter().map(|r| r[k]).sum::<f32>() / n;
    json!({"count": rows.len(), "j2j": m(0), "j2b": m(1), "b2b": m(2)})
}

fn average(values: &[f32]) -> f32 {
    values.iter().sum::<f32>() / values.len().max(1) as f32
}

/// Skin weights `[vertex][joint]` of a skeleton on vertices from the model (if any) and
/// the prior alone, all bones kept (scored through [`top4_rows`]).
fn skin_pair(
    models: &Models,
    vertices: &[Vec3],
    normals: &[Vec3],
    skeleton: &Skeleton,
    geodesic: &[f32],
) -> (Option<Vec<Vec<f32>>>, Vec<Vec<f32>>) {
    let learned = models.skin.as_ref().map(|m| {
        let tails = bone_tails(&skeleton.joints, &skeleton.parents);
        m.weights(vertices, normals, &skeleton.joints, &tails, geodesic)
    });
    let prior = baseline_weights(models.beta, geodesic, skeleton.len());
    (learned, prior)
}

/// Evaluates on the last `holdout` pairs of `data` and, when given, the rigged `witch`.
pub fn evaluate(
    data: &Path,
    holdout: usize,
    count: usize,
    witch: Option<&Path>,
    models: &Models,
    progress: &dyn Fn(usize, usize),
) -> anyhow::Result<Value> {
    let mut learned_all = Vec::new();
    let (mut learned_humanoid, mut fit_humanoid) = (Vec::new(), Vec::new());
    let (mut l1_learned, mut l1_prior, mut motion_learned, mut motion_prior) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut token_lengths: Vec<[f32; 3]> = Vec::new();
    // Humanoids' spring chains: [true, predicted, kept on loose parts] for plain bodies
    // (no true chain) and bodies with loose parts.
    let (mut chains_plain, mut chains_loose) = (Vec::new(), Vec::new());
    let first = count.saturating_sub(holdout);
    for (done, index) in (first..count).enumerate() {
        let sample = Sample::read(&sample_path(data, index))?;
        let truth = &sample.skeleton;
        let outline = Mesh {
            positions: sample.points.clone(),
            ..Default::default()
        };
        if let Some(model) = &models.skeleton {
            let predicted =
                model.predict(&sample.points, &sample.normals, None, 0.0, index as u64)?;
            let scores = skeleton_scores(&predicted, truth);
            learned_all.push(scores);
            if truth.class == Class::Humanoid {
                learned_humanoid.push(scores);
                let height = truth_height(&sample.points);
                let kept = loose_springs(&predicted, &sample.points, &sample.normals, height);
                // The stored skeleton has no spring flags; its tokens do.
                let springs = decode(&sample.tokens)?;
                let counts = [
                    swinging_chains(&springs) as f32,
                    swinging_chains(&predicted) as f32,
                    swinging_chains(&kept) as f32,
                    chains_along(&kept, &springs, LOOSE_DEPTH * height) as f32,
                ];
                if counts[0] == 0.0 {
                    chains_plain.push(counts);
                } else {
                    chains_loose.push(counts);
                }
            }
        }
        if truth.class == Class::Humanoid {
            fit_humanoid.push(skeleton_scores(&template_fit(&outline), truth));
        }
        let mut chains_only = truth.clone();
        chains_only.class = Class::Other;
        token_lengths.push([
            naive_length(truth) as f32,
            encode(&chains_only)?.len() as f32,
            sample.tokens.len() as f32,
        ]);
        let geodesic = sample.geodesic.concat();
        let (learned, prior) = skin_pair(
            models,
            &sample.vertices,
            &sample.vertex_normals,
            truth,
            &geodesic,
        );
        let poses = random_poses(truth, POSES, POSE_DEGREES, index as u64);
        if let Some(learned) = &learned {
            let learned = top4_rows(learned);
            l1_learned.push(skin_l1(&learned, &sample.skin));
            motion_learned.push(motion_l2(&sample.vertices, &learned, &sample.skin, &poses));
        }
        let prior = top4_rows(&prior);
        l1_prior.push(skin_l1(&prior, &sample.skin));
        motion_prior.push(motion_l2(&sample.vertices, &prior, &sample.skin, &poses));
        progress(done + 1, holdout);
    }
    let total = |k: usize| token_lengths.iter().map(|t| t[k]).sum::<f32>();
    let mut report = json!({
        "synthetic": {
            "samples": holdout,
            "tokens": {
                "naive": total(0) / holdout as f32,
                "chains": total(1) / holdout as f32,
                "with_templates": total(2) / holdout as f32,
                "chains_reduction": 1.0 - total(1) / total(0),
                "templates_reduction": 1.0 - total(2) / total(0),
            },
            "skeleton": {
                "learned_all": mean(&learned_all),
                "learned_humanoid": mean(&learned_humanoid),
                "template_fit_humanoid": mean(&fit_humanoid),
            },
            "skin": {
                "learned": {"l1": average(&l1_learned), "motion_l2": average(&motion_learned), "count": l1_learned.len()},
                "geodesic_prior": {"l1": average(&l1_prior), "motion_l2": average(&motion_prior), "count": l1_prior.len()},
            },
            "motion": format!("{POSES} random poses per character, each joint turned up to {POSE_DEGREES}°"),
            "spring_chains": {
                "about": "humanoids' spring chains of 2+ joints per character: true, predicted, and kept on loose parts (joints within LOOSE_DEPTH of the height from the surface, on a part thinner than THIN_PART); plain = no true chain",
                "plain": chain_counts(&chains_plain),
                "with_loose_parts": chain_counts(&chains_loose),
            },
        }
    });
    if let Some(path) = witch {
        report["witch"] = evaluate_rigged(path, models)?;
    }
    report["beta"] = json!(models.beta);
    Ok(report)
}

/// The height (y extent) of a point set.
fn truth_height(points: &[Vec3]) -> f32 {
    let (lo, hi) = points.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(p.y), hi.max(p.y))
    });
    (hi - lo).max(1e-6)
}

/// Mean chains per character (true, predicted, kept) and how many characters have any
/// predicted or kept chain.
/// How many of `kept`'s swinging chains lie along `truth`'s spring chains: every joint
/// within `reach` of a true spring bone (a bone ending in a spring joint).
pub fn chains_along(kept: &Skeleton, truth: &Skeleton, reach: f32) -> usize {
    let bones: Vec<(Vec3, Vec3)> = (0..truth.len())
        .filter(|&j| truth.spring[j])
        .filter_map(|j| truth.bone(j))
        .collect();
    let along = |p: Vec3| {
        bones
            .iter()
            .any(|&(a, b)| segment_distance(p, a, b) <= reach)
    };
    swinging(kept)
        .iter()
        .filter(|chain| chain.iter().all(|&j| along(kept.joints[j])))
        .count()
}

fn chain_counts(rows: &[[f32; 4]]) -> Value {
    let n = rows.len().max(1) as f32;
    let mean = |k: usize| rows.iter().map(|r| r[k]).sum::<f32>() / n;
    let any = |k: usize| rows.iter().filter(|r| r[k] > 0.0).count();
    json!({
        "characters": rows.len(),
        "true_per_character": mean(0),
        "predicted_per_character": mean(1),
        "kept_per_character": mean(2),
        "kept_along_true_per_character": mean(3),
        "characters_with_predicted": any(1),
        "characters_with_kept": any(2),
    })
}

/// The 20 body joints of the humanoid template (by name), if all are present.
fn body_of(skeleton: &Skeleton) -> Option<Skeleton> {
    let index: Vec<usize> = BODY
        .iter()
        .map(|(name, _)| skeleton.names.iter().position(|n| n == name))
        .collect::<Option<_>>()?;
    Some(Skeleton {
        class: Class::Humanoid,
        joints: index.iter().map(|&j| skeleton.joints[j]).collect(),
        parents: BODY.iter().map(|(_, p)| *p).collect(),
        names: BODY.iter().map(|(n, _)| n.to_string()).collect(),
        spring: vec![false; BODY.len()],
    })
}

/// A rigged character against its own rig: skeletons from its mesh alone, skins on its
/// own skeleton, motion from its own walk clip.
fn evaluate_rigged(path: &Path, models: &Models) -> anyhow::Result<Value> {
    let character = load_character(path)?;
    let mesh = character.rest_mesh();
    let cube = UnitCube::of_points(&mesh.positions);
    let truth_world = of_character(&character);
    let truth = truth_world.map_joints(|p| cube.to_unit(p));
    let to_unit = |s: &Skeleton| s.map_joints(|p| cube.to_unit(p));
    let mut out = json!({
        "file": path.display().to_string(),
        "vertices": mesh.positions.len(),
        "joints": truth.len(),
    });
    let truth_body = body_of(&truth);
    let score = |predicted: &Skeleton| {
        let [a, b, c] = skeleton_scores(predicted, &truth);
        let body = body_of(predicted)
            .zip(truth_body.as_ref())
            .map(|(p, t)| skeleton_scores(&p, t));
        json!({"j2j": a, "j2b": b, "b2b": c, "joints": predicted.len(),
            "body": body.map(|[a, b, c]| json!({"j2j": a, "j2b": b, "b2b": c}))})
    };
    out["template_fit"] = score(&to_unit(&template_fit(&mesh)));
    if models.skeleton.is_some() {
        let (predicted, _) = skeleton_for(&mesh, models.skeleton.as_ref(), 0)?;
        let predicted = to_unit(&predicted);
        out["learned"] = score(&predicted);
        out["learned"]["spring_joints"] = json!(predicted.spring.iter().filter(|&&s| s).count());
    }
    // Skins on the true skeleton.
    let unit_mesh = cube.mesh_to_unit(&mesh);
    let geodesic = Voxels::new(&unit_mesh, VOXELS)
        .geodesic(&unit_mesh.positions, &truth.joints, &truth.parents)
        .concat();
    let (learned, prior) = skin_pair(
        models,
        &unit_mesh.positions,
        &unit_mesh.normals,
        &truth,
        &geodesic,
    );
    let truth_skin: Vec<Vec<f32>> = skin_of_character(&character, &truth_world)
        .iter()
        .map(|pairs| dense(pairs.iter().copied(), truth.len()))
        .collect();
    // The walk clip through her own rig: skinning matrices per skeleton joint.
    let rig = &character.rig;
    let walk = character.clip("Walk")?;
    let poses: Vec<Vec<Mat4>> = (0..10)
        .map(|f| {
            let mut local = rig.rest_pose();
            walk.sample(walk.duration * f as f32 / 10.0, &mut local);
            let world = rig.world(&local, Mat4::IDENTITY);
            truth_world
                .names
                .iter()
                .map(|name| {
                    let node = rig.find(name).expect("a joint of the rig");
                    let bone = rig.bones.iter().find(|b| b.node == node);
                    bone.map_or(world[node], |b| world[node] * b.inverse_bind)
                })
                .collect()
        })
        .collect();
    let motion = |weights: &[Vec<f32>]| {
        motion_l2(&mesh.positions, weights, &truth_skin, &poses) / cube.half_extent
    };
    let score = |weights: &[Vec<f32>]| {
        let top = top4_rows(weights);
        json!({"l1": skin_l1(&top, &truth_skin), "motion_l2": motion(&top)})
    };
    // Each also smoothed along her surface, as `unica rig` writes it (`pipeline::skin_for`).
    let smoothed = |mut weights: Vec<Vec<f32>>| {
        smoothing::smooth(&unit_mesh, &mut weights, smoothing::ROUNDS);
        weights
    };
    out["geodesic_prior"] = score(&prior);
    out["geodesic_prior_smoothed"] = score(&smoothed(prior));
    if let Some(learned) = learned {
        out["learned_skin"] = score(&learned);
        out["learned_skin_smoothed"] = score(&smoothed(learned));
    }
    out["unit"] = json!({"half_extent": cube.half_extent});
    Ok(out)
}

/// The report as Markdown tables (the numbers of `results.json`).
pub fn markdown(report: &Value) -> String {
    let f = |v: &Value| v.as_f64().map_or("–".into(), |x| format!("{x:.4}"));
    let s = &report["synthetic"];
    let k = &s["skeleton"];
    let mut out = String::from(
        "# Auto-rig evaluation\n\nDistances in the unit cube of each character's mesh ([-1, 1] on its longest side). Skin L1: per vertex, summed over bones (0-2), top 4 bones per vertex. Motion L2: mean vertex distance after posing with predicted vs true weights under the same motion.\n\n",
    );
    out += &format!(
        "## Held-out synthetic characters ({} pairs)\n\n| skeleton | characters | J2J | J2B | B2B |\n| --- | --- | --- | --- | --- |\n",
        s["samples"]
    );
    for (name, key) in [
        ("learned, all classes", "learned_all"),
        ("learned, humanoids", "learned_humanoid"),
        (
            "template fit (baseline), humanoids",
            "template_fit_humanoid",
        ),
    ] {
        let r = &k[key];
        out += &format!(
            "| {name} | {} | {} | {} | {} |\n",
            r["count"],
            f(&r["j2j"]),
            f(&r["j2b"]),
            f(&r["b2b"])
        );
    }
    out += &format!(
        "\n| skin (on the true skeleton) | L1 | motion L2 |\n| --- | --- | --- |\n| learned | {} | {} |\n| geodesic prior alone (baseline, β = {}) | {} | {} |\n\n{}.\n",
        f(&s["skin"]["learned"]["l1"]),
        f(&s["skin"]["learned"]["motion_l2"]),
        f(&report["beta"]),
        f(&s["skin"]["geodesic_prior"]["l1"]),
        f(&s["skin"]["geodesic_prior"]["motion_l2"]),
        s["motion"].as_str().unwrap_or("")
    );
    let t = &s["tokens"];
    out += &format!(
        "\nTokens per skeleton: naive (6 per bone) {}, chains {} ({:.1} % fewer), chains with templates {} ({:.1} % fewer).\n",
        f(&t["naive"]),
        f(&t["chains"]),
        100.0 * t["chains_reduction"].as_f64().unwrap_or(0.0),
        f(&t["with_templates"]),
        100.0 * t["templates_reduction"].as_f64().unwrap_or(0.0)
    );
    let c = &s["spring_chains"];
    if c.is_object() {
        out += "\n| humanoids' spring chains (2+ joints) | characters | true | predicted | kept on loose parts | kept along a true chain | characters with predicted | with kept |\n| --- | --- | --- | --- | --- | --- | --- | --- |\n";
        for (name, key) in [
            ("plain bodies (no loose part)", "plain"),
            ("with loose parts", "with_loose_parts"),
        ] {
            let r = &c[key];
            out += &format!(
                "| {name} | {} | {} | {} | {} | {} | {} | {} |\n",
                r["characters"],
                f(&r["true_per_character"]),
                f(&r["predicted_per_character"]),
                f(&r["kept_per_character"]),
                f(&r["kept_along_true_per_character"]),
                r["characters_with_predicted"],
                r["characters_with_kept"]
            );
        }
        out += "\nKept: `unica rig` keeps a spring joint only within 4.5 % of the height of the surface (`LOOSE_DEPTH`), and a chain only where the body under the surface around it is thin (median thickness along the inward normal at most 4 % of the height, `THIN_PART`): hair, cloth and tails are thin; a joint deeper in the body, off it, or on a thick torso, hips or head is on no loose part. Before that rule each predicted spring joint moves to the nearest thin surface sample within 12 % of the height (`SNAP`; thin: the median thickness within `LOOSE_DEPTH` around it is, too), leaving out samples nearest an arm or hand bone and samples on a part wrapped round a bone (limbs, not loose parts). Along a true chain: every joint of the kept chain within `LOOSE_DEPTH` of a true spring bone.\n";
    }
    if let Some(w) = report.get("witch") {
        out += &format!(
            "\n## The Witch, rigged from her mesh alone, against her own rig ({} joints, {} vertices)\n\nAll joints (hers include 38 finger joints), then the 20 body-template joints alone.\n\n| skeleton | joints | J2J | J2B | B2B | body J2J | body J2B | body B2B |\n| --- | --- | --- | --- | --- | --- | --- | --- |\n",
            w["joints"], w["vertices"]
        );
        for (name, key) in [
            ("learned", "learned"),
            ("template fit (baseline)", "template_fit"),
        ] {
            let (r, b) = (&w[key], &w[key]["body"]);
            out += &format!(
                "| {name} | {} | {} | {} | {} | {} | {} | {} |\n",
                r["joints"],
                f(&r["j2j"]),
                f(&r["j2b"]),
                f(&r["b2b"]),
                f(&b["j2j"]),
                f(&b["j2b"]),
                f(&b["b2b"])
            );
        }
        out += &format!(
            "\n| skin (on her own skeleton) | L1 | motion L2 (her Walk clip, 10 frames) |\n| --- | --- | --- |\n| learned | {} | {} |\n| geodesic prior alone | {} | {} |\n| learned, smoothed along the surface (as `unica rig` writes it) | {} | {} |\n| geodesic prior alone, smoothed | {} | {} |\n",
            f(&w["learned_skin"]["l1"]),
            f(&w["learned_skin"]["motion_l2"]),
            f(&w["geodesic_prior"]["l1"]),
            f(&w["geodesic_prior"]["motion_l2"]),
            f(&w["learned_skin_smoothed"]["l1"]),
            f(&w["learned_skin_smoothed"]["motion_l2"]),
            f(&w["geodesic_prior_smoothed"]["l1"]),
            f(&w["geodesic_prior_smoothed"]["motion_l2"])
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A body joint at the origin with spring chains given as (x, z) columns of joints at
    /// heights 0, -1, -2 below it.
    fn with_chains(columns: &[(f32, f32)]) -> Skeleton {
        let mut skeleton = Skeleton {
            class: Class::Other,
            joints: vec![Vec3::ZERO],
            parents: vec![None],
            names: vec!["Body".into()],
            spring: vec![false],
        };
        for (c, &(x, z)) in columns.iter().enumerate() {
            for k in 0..3 {
                let parent = if k == 0 { 0 } else { skeleton.len() - 1 };
                skeleton.joints.push(Vec3::new(x, -(k as f32), z));
                skeleton.parents.push(Some(parent));
                skeleton.names.push(format!("Spring{c}_{k}"));
                skeleton.spring.push(true);
            }
        }
        skeleton
    }

    #[test]
    fn a_kept_chain_is_along_a_true_one_when_every_joint_is_near_a_true_spring_bone() {
        let truth = with_chains(&[(1.0, 0.0), (-1.0, 0.0)]);
        // Beside the first true chain (0.1 off), beside the second but 0.3 off, and one
        // that starts by the first and bends away.
        let mut kept = with_chains(&[(1.1, 0.0), (-1.0, 0.3)]);
        kept.joints
            .extend([Vec3::new(1.0, 0.0, 0.05), Vec3::new(1.0, -1.0, 0.05)]);
        kept.parents.extend([Some(0), Some(7)]);
        kept.names.extend(["Bent0".into(), "Bent1".into()]);
        kept.spring.extend([true, true]);
        kept.joints.push(Vec3::new(3.0, -2.0, 0.0));
        kept.parents.push(Some(8));
        kept.names.push("Bent2".into());
        kept.spring.push(true);
        assert_eq!(chains_along(&kept, &truth, 0.2), 1);
        assert_eq!(chains_along(&kept, &truth, 0.35), 2);
        // The true chains' own first bones start at the body joint, so a chain along
        // the body-to-first-joint bone counts too; none along a truth without springs.
        assert_eq!(chains_along(&truth, &truth, 0.01), 2);
        let plain = truth.keep(|j| j == 0);
        assert_eq!(chains_along(&kept, &plain, 10.0), 0);
    }
}
