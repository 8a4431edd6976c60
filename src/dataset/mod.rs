//! The baked teacher dataset (docs/architecture.md, Files), compact: per clip the
//! skinning matrices of every frame (spring bones included), the actions and the root
//! path; one reference file with the mesh, skin weights and the pixel → surface table. A
//! frame's position map is LBS of the reference followed by the table gather
//! ([`Dataset::positions`]); `bake` writes it.

pub mod bake;

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use crate::action::Action;
use crate::posmap::{GroupNorm, MAP_SIZE};
use crate::tensors::{TensorError, TensorFile};

pub const FORMAT: &str = "unica-dataset";
pub const VERSION: u32 = 1;
/// Frames per training group and the frame whose root is centred (the 3rd).
pub const GROUP: usize = 4;
pub const ANCHOR: usize = 2;

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DatasetManifest {
    pub format: String,
    pub version: u32,
    pub avatar: String,
    /// The character file as given to `bake`.
    pub character: String,
    /// The animation libraries given to `bake` (`--clips`), if any.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub clip_files: Vec<String>,
    pub frame_rate: f32,
    /// Action names by id.
    pub actions: Vec<String>,
    pub map_size: usize,
    pub foreground_pixels: usize,
    pub vertices: usize,
    pub bones: usize,
    /// Scale of the group normalisation: 0.7 / the reference's largest extent, lowered
    /// where the baked motion would come nearer than 0.05 to the unit cube's faces.
    pub norm_scale: f32,
    pub walk_speed: f32,
    pub run_speed: f32,
    pub clips: Vec<ClipInfo>,
    /// What the position map's six views see of the reference (see `reference.rs`).
    pub coverage: serde_json::Value,
}

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct ClipInfo {
    pub file: String,
    pub frames: usize,
    pub first: Action,
    pub second: Action,
    /// First frame whose action is `second` (equal to `frames` for a one-action clip).
    pub switch_frame: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{}: {problem}", path.display())]
    Invalid { path: PathBuf, problem: String },
    #[error(transparent)]
    Tensor(#[from] TensorError),
}

fn invalid(path: &Path, problem: impl Into<String>) -> DatasetError {
    DatasetError::Invalid {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// The reference mesh and table, as stored in `reference.safetensors`.
pub struct BakedReference {
    pub bind_positions: Vec<Vec3>,
    pub joints: Vec<[i32; 4]>,
    pub weights: Vec<[f32; 4]>,
    pub triangles: Vec<u32>,
    pub pixels: Vec<u32>,
    pub pixel_triangles: Vec<u32>,
    pub barycentrics: Vec<[f32; 3]>,
    pub waist: Vec<u32>,
}

/// One clip: per frame the skinning matrices (rows 0-2 of each), the action and the root.
pub struct BakedClip {
    pub skin: Vec<[f32; 12]>,
    pub actions: Vec<i32>,
    pub root: Vec<Vec3>,
}

pub struct Dataset {
    pub dir: PathBuf,
    pub manifest: DatasetManifest,
    pub reference: BakedReference,
}

impl Dataset {
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        let manifest_path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&manifest_path)
            .map_err(|e| invalid(&manifest_path, e.to_string()))?;
        let manifest: DatasetManifest =
            serde_json::from_str(&text).map_err(|e| invalid(&manifest_path, e.to_string()))?;
        if manifest.format != FORMAT || manifest.version != VERSION {
            return Err(invalid(
                &manifest_path,
                format!(
                    "format {} v{}, expected {FORMAT} v{VERSION}",
                    manifest.format, manifest.version
                ),
            ));
        }
        let file = TensorFile::open(&dir.join("reference.safetensors"))?;
        let (v, n) = (Some(manifest.vertices), Some(manifest.foreground_pixels));
        let vec3 = |data: Vec<f32>| {
            data.chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect::<Vec<_>>()
        };
        let to_u32 = |data: Vec<i32>| data.into_iter().map(|x| x as u32).collect::<Vec<_>>();
        let reference = BakedReference {
            bind_positions: vec3(file.f32("bind_positions", &[v, Some(3)])?.0),
            joints: file
                .i32("joints", &[v, Some(4)])?
                .0
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            weights: file
                .f32("weights", &[v, Some(4)])?
                .0
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            triangles: to_u32(file.i32("triangles", &[None, Some(3)])?.0),
            pixels: to_u32(file.i32("pixels", &[n])?.0),
            pixel_triangles: to_u32(file.i32("pixel_triangles", &[n])?.0),
            barycentrics: file
                .f32("barycentrics", &[n, Some(3)])?
                .0
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect(),
            waist: to_u32(file.i32("waist", &[None])?.0),
        };
        check_reference(file.path(), &reference, manifest.bones)?;
        if manifest.clips.is_empty() {
            return Err(invalid(&manifest_path, "the manifest lists no clips"));
        }
        if !(manifest.norm_scale.is_finite() && manifest.norm_scale > 0.0) {
            return Err(invalid(
                &manifest_path,
                format!(
                    "norm_scale {} is not a positive number",
                    manifest.norm_scale
                ),
            ));
        }
        if let Some(c) = manifest.clips.iter().find(|c| c.switch_frame > c.frames) {
            return Err(invalid(
                &manifest_path,
                format!(
                    "clip {}: switch frame {} is past its {} frames",
                    c.file, c.switch_frame, c.frames
                ),
            ));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
            reference,
        })
    }

    pub fn clip(&self, index: usize) -> Result<BakedClip, DatasetError> {
        let info = &self.manifest.clips[index];
        let file = TensorFile::open(&self.dir.join(&info.file))?;
        let (f, b) = (Some(info.frames), Some(self.manifest.bones));
        let skin = file.f32("skin", &[f, b, Some(3), Some(4)])?.0;
        Ok(BakedClip {
            skin: skin
                .chunks_exact(12)
                .map(|c| c.try_into().expect("12"))
                .collect(),
            actions: file.i32("actions", &[f])?.0,
            root: file
                .f32("root", &[f, Some(3)])?
                .0
                .chunks_exact(3)
                .map(|c| Vec3::new(c[0], c[1], c[2]))
                .collect(),
        })
    }

    /// The world-space foreground points of frame `frame` of `clip`: linear blend
    /// skinning of the reference, then the table gather.
    pub fn positions(&self, clip: &BakedClip, frame: usize) -> Vec<Vec3> {
        let bones = self.manifest.bones;
        let skin: Vec<Mat4> = clip.skin[frame * bones..(frame + 1) * bones]
            .iter()
            .map(|r| {
                Mat4::from_cols(
                    Vec4::new(r[0], r[4], r[8], 0.0),
                    Vec4::new(r[1], r[5], r[9], 0.0),
                    Vec4::new(r[2], r[6], r[10], 0.0),
                    Vec4::new(r[3], r[7], r[11], 1.0),
                )
            })
            .collect();
        let r = &self.reference;
        let posed: Vec<Vec3> = r
            .bind_positions
            .iter()
            .zip(r.joints.iter().zip(&r.weights))
            .map(|(p, (j, w))| {
                (0..4)
                    .map(|k| skin[j[k] as usize].transform_point3(*p) * w[k])
                    .sum()
            })
            .collect();
        r.pixel_triangles
            .iter()
            .zip(&r.barycentrics)
            .map(|(&t, b)| {
                let i = 3 * t as usize;
                posed[r.triangles[i] as usize] * b[0]
                    + posed[r.triangles[i + 1] as usize] * b[1]
                    + posed[r.triangles[i + 2] as usize] * b[2]
            })
            .collect()
    }

    pub fn norm(&self) -> GroupNorm {
        GroupNorm {
            scale: self.manifest.norm_scale,
        }
    }
}

/// Every index in the reference points at something that exists (joints below `bones`,
/// triangle corners below the vertex count, pixel triangles below the triangle count,
/// waist entries below the pixel count) and every value is finite.
fn check_reference(path: &Path, r: &BakedReference, bones: usize) -> Result<(), DatasetError> {
    fn first_bad(
        path: &Path,
        name: &str,
        mut values: impl Iterator<Item = i64>,
        bound: usize,
    ) -> Result<(), DatasetError> {
        match values.find(|&v| v < 0 || v as u64 >= bound as u64) {
            Some(v) => Err(invalid(
                path,
                format!("'{name}' holds {v}, outside 0..{bound}"),
            )),
            None => Ok(()),
        }
    }
    let vertices = r.bind_positions.len();
    let triangles = r.triangles.len() / 3;
    let signed = |v: &[u32]| v.iter().map(|&x| x as i32 as i64).collect::<Vec<_>>();
    let joints = r.joints.iter().flatten().map(|&j| j as i64);
    first_bad(path, "joints", joints, bones)?;
    first_bad(
        path,
        "triangles",
        signed(&r.triangles).into_iter(),
        vertices,
    )?;
    let pixel_triangles = signed(&r.pixel_triangles).into_iter();
    first_bad(path, "pixel_triangles", pixel_triangles, triangles)?;
    first_bad(path, "waist", signed(&r.waist).into_iter(), r.pixels.len())?;
    if r.waist.is_empty() {
        return Err(invalid(path, "'waist' is empty"));
    }
    let finite = |name: &str, ok: bool| {
        if ok {
            Ok(())
        } else {
            Err(invalid(path, format!("'{name}' holds a non-finite value")))
        }
    };
    finite(
        "bind_positions",
        r.bind_positions.iter().all(|p| p.is_finite()),
    )?;
    finite("weights", r.weights.iter().flatten().all(|w| w.is_finite()))?;
    finite(
        "barycentrics",
        r.barycentrics.iter().flatten().all(|b| b.is_finite()),
    )?;
    Ok(())
}

/// What [`validate`] found.
#[derive(Debug, Serialize)]
pub struct Validation {
    pub clips: usize,
    pub frames: usize,
    pub groups: usize,
    /// Smallest and largest normalised value over all groups.
    pub min: f32,
    pub max: f32,
    pub switches: usize,
    /// Ground-truth renders listed in renders/cameras.json (0 when baked without).
    pub renders: usize,
}

/// Checks a baked dataset: files and shapes, actions against the switch frames, the
/// stored root against the waist pixels, and every 4-frame group normalised into [0, 1].
pub fn validate(dir: &Path) -> Result<Validation, DatasetError> {
    let data = Dataset::open(dir)?;
    let m = &data.manifest;
    if m.map_size != MAP_SIZE || m.actions.len() != Action::ALL.len() {
        return Err(invalid(
            &dir.join("manifest.json"),
            "map size or action list differs from this build",
        ));
    }
    let norm = data.norm();
    let mut report = Validation {
        clips: m.clips.len(),
        frames: 0,
        groups: 0,
        min: f32::MAX,
        max: f32::MIN,
        switches: 0,
        renders: 0,
    };
    for (index, info) in m.clips.iter().enumerate() {
        let path = dir.join(&info.file);
        let clip = data.clip(index)?;
        for (f, &a) in clip.actions.iter().enumerate() {
            let want = if f < info.switch_frame {
                info.first
            } else {
                info.second
            };
            if a != want.id() as i32 {
                return Err(invalid(
                    &path,
                    format!("frame {f} has action {a}, the manifest says {want}"),
                ));
            }
        }
        report.switches += usize::from(info.switch_frame < info.frames);
        let frames: Vec<Vec<Vec3>> = (0..info.frames).map(|f| data.positions(&clip, f)).collect();
        for (f, points) in frames.iter().enumerate() {
            if points.iter().any(|p| !p.is_finite()) {
                return Err(invalid(
                    &path,
                    format!("frame {f} has a non-finite position"),
                ));
            }
            let root = GroupNorm::root(points, &data.reference.waist);
            let off = root.distance(clip.root[f]);
            if off.is_nan() || off > 1e-3 {
                return Err(invalid(
                    &path,
                    format!(
                        "frame {f}: stored root {} but the waist pixels say {root}",
                        clip.root[f]
                    ),
                ));
            }
        }
        for start in 0..frames.len().saturating_sub(GROUP - 1) {
            let (unit, _) = norm
                .normalise(&frames[start..start + GROUP], &data.reference.waist, ANCHOR)
                .map_err(|e| invalid(&path, format!("group starting at frame {start}: {e}")))?;
            for p in unit.iter().flatten() {
                report.min = report.min.min(p.min_element());
                report.max = report.max.max(p.max_element());
            }
            report.groups += 1;
        }
        report.frames += info.frames;
    }
    let cameras = dir.join("renders/cameras.json");
    if cameras.is_file() {
        let text =
            std::fs::read_to_string(&cameras).map_err(|e| invalid(&cameras, e.to_string()))?;
        let json: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| invalid(&cameras, e.to_string()))?;
        let every = json["every"].as_u64().unwrap_or(1).max(1) as usize;
        let listed = json["cameras"].as_array().map_or(&[][..], Vec::as_slice);
        let expected = 50
            + 4 * m
                .clips
                .iter()
                .map(|c| c.frames.div_ceil(every))
                .sum::<usize>();
        if listed.len() != expected {
            return Err(invalid(
                &cameras,
                format!("{} renders listed, expected {expected}", listed.len()),
            ));
        }
        if let Some(missing) = listed
            .iter()
            .filter_map(|c| c["file"].as_str())
            .find(|f| !dir.join("renders").join(f).is_file())
        {
            return Err(invalid(&cameras, format!("render {missing} is missing")));
        }
        report.renders = listed.len();
    }
    Ok(report)
}
