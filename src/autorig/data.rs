//! Training pairs for the auto-rigger's models: a character (synthetic, or a rigged file
//! held out for evaluation) in the unit cube as surface samples, its skeleton's tokens,
//! bones, skin weights and voxel geodesic distances, one safetensors file per character
//! (format in docs/autorig/models.md), written by `unica rig-data`.

use std::path::{Path, PathBuf};

use glam::Vec3;

use super::skeleton::{Skeleton, UnitCube};
use super::tokens::{TokenError, encode};
use super::voxel::{Voxels, bone_tails};
use crate::files::{WriteError, write_atomic};
use crate::mesh::Mesh;
use crate::random::Rng;
use crate::tensors::{TensorData, write};

/// Surface samples per character for the skeleton model.
pub const POINTS: usize = 2048;
/// Vertices per character with skin weights, for the skin model.
pub const VERTICES: usize = 1024;
/// Voxels along the longest side of the unit cube for the geodesic prior.
pub const VOXELS: usize = 64;

/// `count` points spread over the surface by area, with the triangles' normals (as the
/// skeleton model was trained: the winding's).
pub fn surface_samples(mesh: &Mesh, count: usize, rng: &mut Rng) -> (Vec<Vec3>, Vec<Vec3>) {
    samples(mesh, count, rng, false)
}

/// [`surface_samples`] with each normal turned to the side of the mesh's vertex normals
/// where it has them: outward even where a file winds some triangles the wrong way.
pub fn outward_samples(mesh: &Mesh, count: usize, rng: &mut Rng) -> (Vec<Vec3>, Vec<Vec3>) {
    samples(mesh, count, rng, true)
}

fn samples(mesh: &Mesh, count: usize, rng: &mut Rng, outward: bool) -> (Vec<Vec3>, Vec<Vec3>) {
    let triangles: Vec<[Vec3; 3]> = mesh
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]].map(|i| mesh.positions[i as usize]))
        .collect();
    let outward = outward && mesh.normals.len() == mesh.positions.len();
    let mut cumulative = Vec::with_capacity(triangles.len());
    let mut total = 0.0;
    for [a, b, c] in &triangles {
        total += 0.5 * (*b - *a).cross(*c - *a).length();
        cumulative.push(total);
    }
    (0..count)
        .map(|_| {
            let target = rng.uniform() as f32 * total;
            let k = cumulative
                .partition_point(|&c| c < target)
                .min(triangles.len() - 1);
            let [a, b, c] = triangles[k];
            let (mut u, mut v) = (rng.uniform() as f32, rng.uniform() as f32);
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let mut normal = (b - a).cross(c - a).normalize_or(Vec3::Y);
            if outward {
                let corners: Vec3 = mesh.indices[3 * k..3 * k + 3]
                    .iter()
                    .map(|&i| mesh.normals[i as usize])
                    .sum();
                if normal.dot(corners) < 0.0 {
                    normal = -normal;
                }
            }
            (a + u * (b - a) + v * (c - a), normal)
        })
        .unzip()
}

/// One training pair in the unit cube.
pub struct Sample {
    pub points: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub tokens: Vec<u32>,
    pub skeleton: Skeleton,
    pub tails: Vec<Vec3>,
    pub vertices: Vec<Vec3>,
    pub vertex_normals: Vec<Vec3>,
    /// `[vertex][joint]`, rows summing to 1.
    pub skin: Vec<Vec<f32>>,
    /// `[vertex][joint]` voxel geodesic distances.
    pub geodesic: Vec<Vec<f32>>,
}

/// Builds the pair for a character given in its own units: `skin` per mesh vertex as
/// (joint, weight) pairs.
pub fn sample(
    skeleton: &Skeleton,
    mesh: &Mesh,
    skin: &[Vec<(usize, f32)>],
    seed: u64,
) -> Result<Sample, TokenError> {
    let cube = UnitCube::of_points(&mesh.positions);
    let unit_mesh = cube.mesh_to_unit(mesh);
    let skeleton = skeleton.map_joints(|p| cube.to_unit(p));
    let tokens = encode(&skeleton)?;
    let mut rng = Rng::new(seed);
    let (points, normals) = surface_samples(&unit_mesh, POINTS, &mut rng);
    let picked: Vec<usize> = (0..VERTICES)
        .map(|_| rng.below(unit_mesh.positions.len()))
        .collect();
    let vertices: Vec<Vec3> = picked.iter().map(|&v| unit_mesh.positions[v]).collect();
    let geodesic =
        Voxels::new(&unit_mesh, VOXELS).geodesic(&vertices, &skeleton.joints, &skeleton.parents);
    let skin = picked
        .iter()
        .map(|&v| dense(skin[v].iter().copied(), skeleton.len()))
        .collect();
    Ok(Sample {
        points,
        normals,
        tokens,
        tails: bone_tails(&skeleton.joints, &skeleton.parents),
        vertex_normals: picked.iter().map(|&v| unit_mesh.normals[v]).collect(),
        vertices,
        skin,
        geodesic,
        skeleton,
    })
}

/// Sparse (joint, weight) pairs as a row over all `joints`.
pub fn dense(pairs: impl IntoIterator<Item = (usize, f32)>, joints: usize) -> Vec<f32> {
    let mut row = vec![0.0; joints];
    for (j, w) in pairs {
        row[j] += w;
    }
    row
}

fn flat(vectors: &[Vec3]) -> Vec<f32> {
    vectors.iter().flat_map(|v| v.to_array()).collect()
}

impl Sample {
    pub fn write(&self, path: &Path) -> Result<(), WriteError> {
        let j = self.skeleton.len();
        let v = self.vertices.len();
        let tokens: Vec<i32> = self.tokens.iter().map(|&t| t as i32).collect();
        let parents: Vec<i32> = self
            .skeleton
            .parents
            .iter()
            .map(|p| p.map_or(-1, |p| p as i32))
            .collect();
        write(
            path,
            &[
                (
                    "points",
                    TensorData::f32(&[self.points.len(), 3], &flat(&self.points)),
                ),
                (
                    "normals",
                    TensorData::f32(&[self.normals.len(), 3], &flat(&self.normals)),
                ),
                ("tokens", TensorData::i32(&[tokens.len()], &tokens)),
                (
                    "joints",
                    TensorData::f32(&[j, 3], &flat(&self.skeleton.joints)),
                ),
                ("parents", TensorData::i32(&[j], &parents)),
                ("bone_tails", TensorData::f32(&[j, 3], &flat(&self.tails))),
                ("vertices", TensorData::f32(&[v, 3], &flat(&self.vertices))),
                (
                    "vertex_normals",
                    TensorData::f32(&[v, 3], &flat(&self.vertex_normals)),
                ),
                ("skin", TensorData::f32(&[v, j], &self.skin.concat())),
                (
                    "geodesic",
                    TensorData::f32(&[v, j], &self.geodesic.concat()),
                ),
            ],
        )
    }
}

/// Writes `count` synthetic pairs (seeds `seed`, `seed + 1`, …) into `out` on all cores,
/// then the manifest; `variety` false gives the plain generator (`synth::character`);
/// `progress(done, total)` after each.
pub fn write_synthetic(
    out: &Path,
    count: usize,
    seed: u64,
    variety: bool,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> anyhow::Result<()> {
    std::fs::create_dir_all(out)
        .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", out.display()))?;
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let done = std::sync::atomic::AtomicUsize::new(0);
    std::thread::scope(|scope| -> anyhow::Result<()> {
        let workers: Vec<_> = (0..threads)
            .map(|t| {
                let done = &done;
                scope.spawn(move || -> anyhow::Result<()> {
                    for i in (t..count).step_by(threads) {
                        let s = seed + i as u64;
                        let mut rng = Rng::new(s ^ 0x5eed);
                        let pose = rng.range(0.0, 1.0);
                        let c = super::synth::character(s, pose, variety);
                        let pair = sample(&c.skeleton, &c.mesh, &c.skin, s)
                            .map_err(|e| anyhow::anyhow!("synthetic character {s}: {e}"))?;
                        pair.write(&sample_path(out, i))?;
                        let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                        progress(n, count);
                    }
                    Ok(())
                })
            })
            .collect();
        for w in workers {
            w.join().expect("worker thread")?;
        }
        Ok(())
    })?;
    let manifest = serde_json::json!({
        "format": "unica-rig-data",
        "version": 1,
        "count": count,
        "points": POINTS,
        "vertices": VERTICES,
        "vocab": super::tokens::VOCAB,
        "seed": seed,
        "variety": variety,
    });
    write_atomic(
        &out.join("manifest.json"),
        serde_json::to_string_pretty(&manifest)?.as_bytes(),
    )?;
    Ok(())
}

pub fn sample_path(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("sample_{index:05}.safetensors"))
}

/// A rigged character's own skin as (joint of `skeleton`, weight) per vertex, joints
/// matched by name (the skeleton from [`super::skeleton::of_character`] keeps every
/// weighted node).
pub fn skin_of_character(
    character: &crate::avatar::Character,
    skeleton: &Skeleton,
) -> Vec<Vec<(usize, f32)>> {
    let rig = &character.rig;
    let joint_of_bone: Vec<Option<usize>> = rig
        .bones
        .iter()
        .map(|b| {
            skeleton
                .names
                .iter()
                .position(|n| *n == rig.nodes[b.node].name)
        })
        .collect();
    let skinned = &character.skinned;
    skinned
        .joints
        .iter()
        .zip(&skinned.weights)
        .map(|(joints, weights)| {
            joints
                .iter()
                .zip(weights)
                .filter(|(_, w)| **w > 0.0)
                .filter_map(|(&b, &w)| joint_of_bone[b as usize].map(|j| (j, w)))
                .collect()
        })
        .collect()
}

impl Sample {
    /// Reads a pair written by [`Sample::write`]; the skeleton's class comes from its
    /// tokens, names and spring flags are not stored.
    pub fn read(path: &Path) -> Result<Self, crate::tensors::TensorError> {
        use crate::tensors::TensorFile;
        let file = TensorFile::open(path)?;
        let vec3 = |name: &str| -> Result<Vec<Vec3>, crate::tensors::TensorError> {
            let (values, _) = file.f32(name, &[None, Some(3)])?;
            Ok(values.chunks_exact(3).map(Vec3::from_slice).collect())
        };
        let (tokens, _) = file.i32("tokens", &[None])?;
        let (parents, _) = file.i32("parents", &[None])?;
        let joints = vec3("joints")?;
        let vertices = vec3("vertices")?;
        let (j, v) = (joints.len(), vertices.len());
        let rows = |name: &str| -> Result<Vec<Vec<f32>>, crate::tensors::TensorError> {
            let (values, _) = file.f32(name, &[Some(v), Some(j)])?;
            Ok(values.chunks_exact(j.max(1)).map(<[f32]>::to_vec).collect())
        };
        let class = match tokens.get(1).map(|&t| t as u32) {
            Some(super::tokens::CLASS_HUMANOID) => super::skeleton::Class::Humanoid,
            Some(super::tokens::CLASS_QUADRUPED) => super::skeleton::Class::Quadruped,
            _ => super::skeleton::Class::Other,
        };
        Ok(Self {
            points: vec3("points")?,
            normals: vec3("normals")?,
            tokens: tokens.iter().map(|&t| t as u32).collect(),
            skeleton: Skeleton {
                class,
                parents: parents.iter().map(|&p| usize::try_from(p).ok()).collect(),
                names: (0..j).map(|k| format!("joint{k}")).collect(),
                spring: vec![false; j],
                joints,
            },
            tails: vec3("bone_tails")?,
            vertex_normals: vec3("vertex_normals")?,
            skin: rows("skin")?,
            geodesic: rows("geodesic")?,
            vertices,
        })
    }
}
