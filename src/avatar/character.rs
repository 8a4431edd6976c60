//! Loading a character file (glTF 2.0 .gltf/.glb, or OBJ+MTL) into its rest-pose mesh.
//! Skinned glTF meshes are posed by their joints' rest transforms, as the spec defines.

use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};

use super::Mesh;

/// A loaded character: its name (the file stem) and rest-pose mesh.
#[derive(Clone, Debug)]
pub struct Character {
    pub name: String,
    pub path: PathBuf,
    pub mesh: Mesh,
}

/// A character file that could not be used, and why.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct LoadError {
    pub path: PathBuf,
    pub problem: String,
}

fn fail(path: &Path, problem: impl Into<String>) -> LoadError {
    LoadError {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// Loads a character by extension: `.gltf`/`.glb` or `.obj`.
pub fn load_character(path: &Path) -> Result<Character, LoadError> {
    if !path.is_file() {
        return Err(fail(path, "no such file"));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let mesh = match ext.as_str() {
        "gltf" | "glb" => load_gltf(path)?,
        "obj" => load_obj(path)?,
        other => {
            return Err(fail(
                path,
                format!("unsupported file type '.{other}' (expected .gltf, .glb or .obj)"),
            ));
        }
    };
    if mesh.indices.is_empty() {
        return Err(fail(path, "the file contains no triangles"));
    }
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "character".into());
    Ok(Character {
        name,
        path: path.to_path_buf(),
        mesh,
    })
}

fn load_gltf(path: &Path) -> Result<Mesh, LoadError> {
    let (doc, buffers, _images) = gltf::import(path).map_err(|e| fail(path, e.to_string()))?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| fail(path, "no scene"))?;
    let mut world = vec![Mat4::IDENTITY; doc.nodes().len()];
    let mut stack: Vec<(gltf::Node, Mat4)> = scene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
    let mut mesh_nodes = Vec::new();
    while let Some((node, parent)) = stack.pop() {
        let global = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        world[node.index()] = global;
        if node.mesh().is_some() {
            mesh_nodes.push(node.clone());
        }
        stack.extend(node.children().map(|c| (c, global)));
    }
    let mut out = Mesh::default();
    for node in mesh_nodes {
        let skin_matrices = match node.skin() {
            Some(skin) => Some(rest_skin_matrices(path, &skin, &buffers, &world)?),
            None => None,
        };
        for primitive in node
            .mesh()
            .into_iter()
            .flat_map(|m| m.primitives().collect::<Vec<_>>())
        {
            if primitive.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            let reader = primitive.reader(|b| Some(&buffers[b.index()]));
            let positions: Vec<Vec3> = reader
                .read_positions()
                .ok_or_else(|| fail(path, "a mesh primitive has no POSITION attribute"))?
                .map(Vec3::from)
                .collect();
            let indices: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..positions.len() as u32).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
                return Err(fail(
                    path,
                    format!("index {bad} is past the {} vertices", positions.len()),
                ));
            }
            let transforms: Vec<Mat4> = match &skin_matrices {
                Some(joints) => {
                    let joint_ids = reader
                        .read_joints(0)
                        .ok_or_else(|| fail(path, "a skinned primitive has no JOINTS_0"))?
                        .into_u16();
                    let weights = reader
                        .read_weights(0)
                        .ok_or_else(|| fail(path, "a skinned primitive has no WEIGHTS_0"))?
                        .into_f32();
                    joint_ids
                        .zip(weights)
                        .map(|(j, w)| blend(path, joints, j, w))
                        .collect::<Result<_, _>>()?
                }
                None => vec![world[node.index()]; positions.len()],
            };
            if transforms.len() != positions.len() {
                return Err(fail(
                    path,
                    "JOINTS_0/WEIGHTS_0 count differs from POSITION count",
                ));
            }
            let base = primitive
                .material()
                .pbr_metallic_roughness()
                .base_color_factor();
            let color = Vec3::new(base[0], base[1], base[2]);
            let mut part = Mesh {
                positions: positions
                    .iter()
                    .zip(&transforms)
                    .map(|(p, m)| m.transform_point3(*p))
                    .collect(),
                colors: vec![color; positions.len()],
                indices,
                normals: Vec::new(),
            };
            match reader.read_normals() {
                Some(normals) => {
                    part.normals = normals
                        .zip(&transforms)
                        .map(|(n, m)| m.transform_vector3(Vec3::from(n)).normalize_or(Vec3::Y))
                        .collect()
                }
                None => part.compute_normals(),
            }
            out.append(part);
        }
    }
    Ok(out)
}

/// Joint matrices of the rest pose: joint world transform times inverse bind matrix.
fn rest_skin_matrices(
    path: &Path,
    skin: &gltf::Skin,
    buffers: &[gltf::buffer::Data],
    world: &[Mat4],
) -> Result<Vec<Mat4>, LoadError> {
    let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
    let inverse_bind: Vec<Mat4> = match skin
        .reader(|b| Some(&buffers[b.index()]))
        .read_inverse_bind_matrices()
    {
        Some(m) => m.map(|m| Mat4::from_cols_array_2d(&m)).collect(),
        None => vec![Mat4::IDENTITY; joints.len()],
    };
    if inverse_bind.len() != joints.len() {
        return Err(fail(
            path,
            format!(
                "skin '{}' has {} joints but {} inverse bind matrices",
                skin.name().unwrap_or("?"),
                joints.len(),
                inverse_bind.len()
            ),
        ));
    }
    Ok(joints
        .iter()
        .zip(inverse_bind)
        .map(|(&j, ib)| world[j] * ib)
        .collect())
}

fn blend(
    path: &Path,
    joints: &[Mat4],
    ids: [u16; 4],
    weights: [f32; 4],
) -> Result<Mat4, LoadError> {
    let total: f32 = weights.iter().sum();
    if total <= 0.0 {
        return Ok(Mat4::IDENTITY);
    }
    let mut m = Mat4::ZERO;
    for (&id, &w) in ids.iter().zip(&weights) {
        if w == 0.0 {
            continue;
        }
        let joint = joints.get(id as usize).ok_or_else(|| {
            fail(
                path,
                format!(
                    "joint index {id} is past the skin's {} joints",
                    joints.len()
                ),
            )
        })?;
        m += *joint * (w / total);
    }
    Ok(m)
}

fn load_obj(path: &Path) -> Result<Mesh, LoadError> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let (models, materials) =
        tobj::load_obj(path, &options).map_err(|e| fail(path, e.to_string()))?;
    // A missing or broken MTL file leaves the mesh grey rather than failing the load.
    let materials = materials.unwrap_or_else(|e| {
        log::warn!("{}: materials not loaded ({e}); using grey", path.display());
        Vec::new()
    });
    let mut out = Mesh::default();
    for model in models {
        let m = &model.mesh;
        let positions: Vec<Vec3> = m
            .positions
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect();
        let color = m
            .material_id
            .and_then(|id| materials.get(id))
            .and_then(|mat| mat.diffuse)
            .map(Vec3::from)
            .unwrap_or(Vec3::splat(0.7));
        let mut part = Mesh {
            colors: vec![color; positions.len()],
            positions,
            indices: m.indices.clone(),
            normals: Vec::new(),
        };
        if m.normals.len() == m.positions.len() {
            part.normals = m
                .normals
                .chunks_exact(3)
                .map(|n| Vec3::new(n[0], n[1], n[2]).normalize_or(Vec3::Y))
                .collect();
        } else {
            part.compute_normals();
        }
        out.append(part);
    }
    Ok(out)
}
