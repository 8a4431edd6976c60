//! Writing a rigged, animated character as binary glTF (.glb): one skinned mesh with
//! vertex colours, its joint hierarchy with inverse bind matrices, and clips of linear
//! joint rotations plus root translation, and VRM 1.0's humanoid map and spring bones
//! where given (`VRMC_vrm`, `VRMC_springBone`). The auto-rigger's output; the teacher's
//! loader ([`crate::avatar::load_character`]) reads it back as written.

use std::collections::HashSet;
use std::path::Path;

use glam::{Mat4, Quat, Vec3};
use serde_json::{Value, json};

use crate::avatar::rig::Transform;
use crate::avatar::vrm::Vrm;
use crate::files::{WriteError, write_atomic};
use crate::mesh::Mesh;

/// A mesh in its bind pose, skinned to a joint hierarchy, with its clips.
pub struct RiggedMesh<'a> {
    /// The mesh node's (and material's) name.
    pub name: &'a str,
    /// Bind-space positions, normals, linear RGB colours and triangles.
    pub mesh: &'a Mesh,
    /// Parents before children.
    pub joints: &'a [JointOut],
    /// Per vertex: four indices into `joints`.
    pub skin_joints: &'a [[u16; 4]],
    /// Per vertex: the four weights, non-negative and summing to 1.
    pub skin_weights: &'a [[f32; 4]],
    pub clips: &'a [ClipOut],
    /// VRM 1.0 humanoid map and spring bones to write, by joint index (joint `j` is node
    /// `j` of the file).
    pub vrm: Option<&'a Vrm>,
}

pub struct JointOut {
    /// Unique among the joints.
    pub name: String,
    /// An index smaller than this joint's own.
    pub parent: Option<usize>,
    /// The local transform in the bind pose.
    pub rest: Transform,
}

/// Keyframes interpolated linearly (rotations by slerp).
pub struct ClipOut {
    /// Unique among the clips.
    pub name: String,
    /// Seconds: non-negative and strictly increasing.
    pub times: Vec<f32>,
    /// Per joint, one local rotation per key time.
    pub rotations: Vec<Vec<Quat>>,
    /// Local translations of joint 0 (a root), one per key time; empty for none.
    pub root_translations: Vec<Vec3>,
}

/// A rigged mesh that was not written, and why.
#[derive(Debug, thiserror::Error)]
pub enum GlbError {
    #[error("cannot write the rigged mesh as glTF: {0}")]
    Invalid(String),
    #[error(transparent)]
    Write(#[from] WriteError),
}

/// Writes `rigged` to `path` as a .glb, atomically, after checking it is consistent.
pub fn write_glb(path: &Path, rigged: &RiggedMesh) -> Result<(), GlbError> {
    let bind_world = validate(rigged)?;
    let (json, bin) = document(rigged, &bind_world);
    write_atomic(path, &glb(&json, &bin)?)?;
    Ok(())
}

/// Checks every length, index and value the file depends on; returns each joint's world
/// matrix in the bind pose.
fn validate(rigged: &RiggedMesh) -> Result<Vec<Mat4>, GlbError> {
    let mesh = rigged.mesh;
    let joints = rigged.joints;
    if joints.is_empty() {
        return Err(GlbError::Invalid("the rig has no joints".into()));
    }
    if let Some(vrm) = rigged.vrm {
        let nodes = vrm.humanoid.iter().map(|(_, n)| *n).chain(
            vrm.springs
                .iter()
                .flat_map(|s| s.joints.iter().map(|j| j.node))
                .chain(vrm.colliders.iter().map(|c| c.node)),
        );
        if let Some(n) = nodes.into_iter().find(|&n| n >= joints.len()) {
            return Err(GlbError::Invalid(format!(
                "VRM extensions name node {n} of {} joints",
                joints.len()
            )));
        }
    }
    let mut names = HashSet::new();
    let mut world: Vec<Mat4> = Vec::with_capacity(joints.len());
    for (i, joint) in joints.iter().enumerate() {
        let name = &joint.name;
        if !names.insert(name.as_str()) {
            return Err(GlbError::Invalid(format!("two joints are named '{name}'")));
        }
        if let Some(parent) = joint.parent.filter(|&p| p >= i) {
            return Err(GlbError::Invalid(format!(
                "joint {i} '{name}' has parent {parent}, which does not come before it"
            )));
        }
        let rest = &joint.rest;
        let finite =
            rest.translation.is_finite() && rest.rotation.is_finite() && rest.scale.is_finite();
        if !finite || rest.rotation.length() < 1e-6 {
            return Err(GlbError::Invalid(format!(
                "joint '{name}' has a non-finite rest transform or a zero rotation"
            )));
        }
        let parent = joint.parent.map_or(Mat4::IDENTITY, |p| world[p]);
        let bind = parent * rest_matrix(rest);
        if !bind.is_finite() || bind.determinant().abs() < 1e-12 {
            return Err(GlbError::Invalid(format!(
                "joint '{name}' has a bind matrix with no inverse (zero scale?)"
            )));
        }
        world.push(bind);
    }

    let n = mesh.positions.len();
    for (what, len) in [
        ("normals", mesh.normals.len()),
        ("colours", mesh.colors.len()),
        ("skin joint sets", rigged.skin_joints.len()),
        ("skin weight sets", rigged.skin_weights.len()),
    ] {
        if len != n {
            return Err(GlbError::Invalid(format!(
                "the mesh has {n} positions but {len} {what}"
            )));
        }
    }
    let vectors = [&mesh.positions, &mesh.normals, &mesh.colors];
    if !vectors.iter().all(|v| v.iter().all(|x| x.is_finite())) {
        return Err(GlbError::Invalid(
            "the mesh has a non-finite position, normal or colour".into(),
        ));
    }
    if mesh.indices.is_empty() || !mesh.indices.len().is_multiple_of(3) {
        return Err(GlbError::Invalid(format!(
            "the mesh has {} indices, not a whole, non-zero number of triangles",
            mesh.indices.len()
        )));
    }
    if let Some(&bad) = mesh.indices.iter().find(|&&i| i as usize >= n) {
        return Err(GlbError::Invalid(format!(
            "triangle index {bad} is past the {n} vertices"
        )));
    }
    for (v, (set, weights)) in rigged
        .skin_joints
        .iter()
        .zip(rigged.skin_weights)
        .enumerate()
    {
        if let Some(&bad) = set.iter().find(|&&j| j as usize >= joints.len()) {
            return Err(GlbError::Invalid(format!(
                "vertex {v}: joint index {bad} is past the {} joints",
                joints.len()
            )));
        }
        let total: f32 = weights.iter().sum();
        let usable = weights.iter().all(|w| w.is_finite()) && weights.iter().all(|&w| w >= 0.0);
        if !usable || (total - 1.0).abs() > 1e-3 {
            return Err(GlbError::Invalid(format!(
                "vertex {v}: weights {weights:?} are not finite, non-negative and summing to 1"
            )));
        }
    }

    let mut clip_names = HashSet::new();
    for clip in rigged.clips {
        let name = &clip.name;
        if !clip_names.insert(name.as_str()) {
            return Err(GlbError::Invalid(format!("two clips are named '{name}'")));
        }
        let times = &clip.times;
        let increasing = times.windows(2).all(|w| w[0] < w[1]);
        if times.is_empty() || !times.iter().all(|t| t.is_finite()) || times[0] < 0.0 || !increasing
        {
            return Err(GlbError::Invalid(format!(
                "clip '{name}': key times {times:?} are not non-empty, non-negative and \
                 strictly increasing"
            )));
        }
        if clip.rotations.len() != joints.len() {
            return Err(GlbError::Invalid(format!(
                "clip '{name}' has rotations for {} joints, not the rig's {}",
                clip.rotations.len(),
                joints.len()
            )));
        }
        for (joint, keys) in joints.iter().zip(&clip.rotations) {
            if keys.len() != times.len() {
                return Err(GlbError::Invalid(format!(
                    "clip '{name}': joint '{}' has {} rotations for {} key times",
                    joint.name,
                    keys.len(),
                    times.len()
                )));
            }
            let finite = keys.iter().all(|q| q.is_finite());
            if !finite || keys.iter().any(|q| q.length() < 1e-6) {
                return Err(GlbError::Invalid(format!(
                    "clip '{name}': joint '{}' has a non-finite or zero rotation",
                    joint.name
                )));
            }
        }
        let translations = &clip.root_translations;
        if !translations.is_empty() && translations.len() != times.len() {
            return Err(GlbError::Invalid(format!(
                "clip '{name}' has {} root translations for {} key times",
                translations.len(),
                times.len()
            )));
        }
        if !translations.iter().all(|t| t.is_finite()) {
            return Err(GlbError::Invalid(format!(
                "clip '{name}' has a non-finite root translation"
            )));
        }
    }
    Ok(world)
}

/// The local matrix of a rest transform as the file stores it (unit rotation).
fn rest_matrix(rest: &Transform) -> Mat4 {
    Mat4::from_scale_rotation_translation(rest.scale, rest.rotation.normalize(), rest.translation)
}

const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// The binary chunk under construction, with the buffer views and accessors into it.
#[derive(Default)]
struct Buffer {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Buffer {
    /// Appends one view holding `data` and an accessor of `count` elements over it;
    /// returns the accessor's index.
    fn push(
        &mut self,
        data: &[u8],
        count: usize,
        mut accessor: Value,
        target: Option<u32>,
    ) -> usize {
        self.bytes.resize(self.bytes.len().next_multiple_of(4), 0);
        let mut view = json!({
            "buffer": 0,
            "byteOffset": self.bytes.len(),
            "byteLength": data.len(),
        });
        if let Some(target) = target {
            view["target"] = json!(target);
        }
        self.bytes.extend_from_slice(data);
        accessor["bufferView"] = json!(self.views.len());
        accessor["count"] = json!(count);
        self.views.push(view);
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// Float elements of `N` components, with per-component bounds when `bounds`.
    fn floats<const N: usize>(
        &mut self,
        items: &[[f32; N]],
        target: Option<u32>,
        bounds: bool,
    ) -> usize {
        let kind = match N {
            1 => "SCALAR",
            3 => "VEC3",
            4 => "VEC4",
            16 => "MAT4",
            _ => unreachable!("no glTF accessor type has {N} components"),
        };
        let mut accessor = json!({"componentType": FLOAT, "type": kind});
        if bounds {
            let mut min = [f32::INFINITY; N];
            let mut max = [f32::NEG_INFINITY; N];
            for item in items {
                for c in 0..N {
                    min[c] = min[c].min(item[c]);
                    max[c] = max[c].max(item[c]);
                }
            }
            accessor["min"] = json!(min.to_vec());
            accessor["max"] = json!(max.to_vec());
        }
        let data: Vec<u8> = items
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        self.push(&data, items.len(), accessor, target)
    }
}

/// The glTF JSON and binary chunk of a validated rigged mesh whose joints have the
/// world bind matrices `bind_world`.
fn document(rigged: &RiggedMesh, bind_world: &[Mat4]) -> (Value, Vec<u8>) {
    let mesh = rigged.mesh;
    let joints = rigged.joints;
    let mut buffer = Buffer::default();

    let positions: Vec<[f32; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    let normals: Vec<[f32; 3]> = mesh
        .normals
        .iter()
        .map(|n| n.normalize_or(Vec3::Y).to_array())
        .collect();
    let colours: Vec<[f32; 3]> = mesh.colors.iter().map(|c| c.to_array()).collect();
    let weights: Vec<[f32; 4]> = rigged
        .skin_weights
        .iter()
        .map(|w| {
            let total: f32 = w.iter().sum();
            w.map(|x| x / total)
        })
        .collect();
    let position = buffer.floats(&positions, Some(ARRAY_BUFFER), true);
    let normal = buffer.floats(&normals, Some(ARRAY_BUFFER), false);
    let colour = buffer.floats(&colours, Some(ARRAY_BUFFER), false);
    let weight = buffer.floats(&weights, Some(ARRAY_BUFFER), false);
    let joint_bytes: Vec<u8> = rigged
        .skin_joints
        .iter()
        .flatten()
        .flat_map(|j| j.to_le_bytes())
        .collect();
    let joint = buffer.push(
        &joint_bytes,
        rigged.skin_joints.len(),
        json!({"componentType": UNSIGNED_SHORT, "type": "VEC4"}),
        Some(ARRAY_BUFFER),
    );
    let index_bytes: Vec<u8> = mesh.indices.iter().flat_map(|i| i.to_le_bytes()).collect();
    let indices = buffer.push(
        &index_bytes,
        mesh.indices.len(),
        json!({"componentType": UNSIGNED_INT, "type": "SCALAR"}),
        Some(ELEMENT_ARRAY_BUFFER),
    );
    let inverse_bind: Vec<[f32; 16]> = bind_world
        .iter()
        .map(|m| m.inverse().to_cols_array())
        .collect();
    let inverse_bind = buffer.floats(&inverse_bind, None, false);

    // Nodes 0..joints are the joints; the mesh node comes last, a root of its own.
    let mesh_node = joints.len();
    let mut nodes: Vec<Value> = joints
        .iter()
        .map(|j| {
            json!({
                "name": j.name,
                "translation": j.rest.translation.to_array(),
                "rotation": j.rest.rotation.normalize().to_array(),
                "scale": j.rest.scale.to_array(),
            })
        })
        .collect();
    for (i, joint) in joints.iter().enumerate() {
        if let Some(parent) = joint.parent {
            let children = &mut nodes[parent]["children"];
            if children.is_null() {
                *children = json!([]);
            }
            children
                .as_array_mut()
                .expect("children is an array")
                .push(json!(i));
        }
    }
    nodes.push(json!({"name": rigged.name, "mesh": 0, "skin": 0}));
    let roots: Vec<usize> = (0..joints.len())
        .filter(|&i| joints[i].parent.is_none())
        .chain([mesh_node])
        .collect();

    let animations: Vec<Value> = rigged
        .clips
        .iter()
        .map(|clip| animation(&mut buffer, clip))
        .collect();

    let mut json = json!({
        "asset": {"version": "2.0", "generator": "unica autorig"},
        "scene": 0,
        "scenes": [{"nodes": roots}],
        "nodes": nodes,
        "meshes": [{
            "name": rigged.name,
            "primitives": [{
                "attributes": {
                    "POSITION": position,
                    "NORMAL": normal,
                    "COLOR_0": colour,
                    "JOINTS_0": joint,
                    "WEIGHTS_0": weight,
                },
                "indices": indices,
                "material": 0,
                "mode": 4,
            }],
        }],
        // White, so the vertex colours are the base colour.
        "materials": [{
            "name": rigged.name,
            "pbrMetallicRoughness": {
                "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
            },
        }],
        "skins": [{
            "joints": (0..joints.len()).collect::<Vec<_>>(),
            "inverseBindMatrices": inverse_bind,
        }],
        "animations": animations,
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [{"byteLength": buffer.bytes.len()}],
    });
    if let Some(vrm) = rigged.vrm {
        let extensions = vrm.to_json(rigged.name);
        json["extensionsUsed"] = json!(extensions.keys().collect::<Vec<_>>());
        json["extensions"] = Value::Object(extensions);
    }
    (json, buffer.bytes)
}

/// One clip: a rotation channel per joint and, if it has them, joint 0's translations,
/// all sharing the clip's key times.
fn animation(buffer: &mut Buffer, clip: &ClipOut) -> Value {
    let times: Vec<[f32; 1]> = clip.times.iter().map(|&t| [t]).collect();
    let input = buffer.floats(&times, None, true);
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    let mut channel = |output: usize, node: usize, path: &str| {
        channels.push(json!({
            "sampler": samplers.len(),
            "target": {"node": node, "path": path},
        }));
        samplers.push(json!({"input": input, "output": output, "interpolation": "LINEAR"}));
    };
    for (node, keys) in clip.rotations.iter().enumerate() {
        let keys: Vec<[f32; 4]> = keys.iter().map(|q| q.normalize().to_array()).collect();
        channel(buffer.floats(&keys, None, false), node, "rotation");
    }
    if !clip.root_translations.is_empty() {
        let keys: Vec<[f32; 3]> = clip
            .root_translations
            .iter()
            .map(|t| t.to_array())
            .collect();
        channel(buffer.floats(&keys, None, false), 0, "translation");
    }
    json!({"name": clip.name, "samplers": samplers, "channels": channels})
}

/// The GLB container: a 12-byte header, the JSON chunk padded with spaces and the binary
/// chunk padded with zeros, each to 4 bytes.
fn glb(json: &Value, bin: &[u8]) -> Result<Vec<u8>, GlbError> {
    let json = json.to_string().into_bytes();
    let json_len = json.len().next_multiple_of(4);
    let bin_len = bin.len().next_multiple_of(4);
    let total = 12 + 8 + json_len + 8 + bin_len;
    let as_u32 = |n: usize| {
        u32::try_from(n)
            .map(u32::to_le_bytes)
            .map_err(|_| GlbError::Invalid(format!("{total} bytes are too many for one .glb file")))
    };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&as_u32(total)?);
    out.extend_from_slice(&as_u32(json_len)?);
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.resize(20 + json_len, b' ');
    out.extend_from_slice(&as_u32(bin_len)?);
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out.resize(total, 0);
    Ok(out)
}
