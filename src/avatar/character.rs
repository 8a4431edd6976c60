//! Loading a character file (glTF 2.0 .gltf/.glb, or OBJ+MTL) into one skinned mesh, its
//! rig and its animation clips. A static mesh becomes a one-bone rig, so every character
//! is posed the same way.

use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec2, Vec3, Vec4};

use super::clip::{Channel, Clip, Interpolation, Values};
pub use super::load_error::CharacterError;
pub(crate) use super::load_error::fail;
use super::rig::{Bone, Node, Part, Rig, SkinnedMesh, Transform};
use super::vrm::Vrm;
use crate::mesh::Mesh;

/// A loaded character: the mesh in bind space, its rig and clips.
#[derive(Clone, Debug)]
pub struct Character {
    /// The file stem.
    pub name: String,
    pub path: PathBuf,
    pub rig: Rig,
    pub skinned: SkinnedMesh,
    pub clips: Vec<Clip>,
    /// The file's VRM 1.0 humanoid map and spring bones (`.vrm`, or glTF with them).
    pub vrm: Option<Vrm>,
}

impl Character {
    /// The mesh posed by local node transforms `local`, with `root` above the rig.
    pub fn pose_mesh(&self, local: &[Transform], root: Mat4) -> Mesh {
        let world = self.rig.world(local, root);
        self.skinned.pose(&self.rig.skin_matrices(&world))
    }

    /// The mesh in the rig's rest pose (the scene as the file shows it).
    pub fn rest_mesh(&self) -> Mesh {
        self.pose_mesh(&self.rig.rest_pose(), Mat4::IDENTITY)
    }

    pub fn clip(&self, name: &str) -> Result<&Clip, CharacterError> {
        self.clips.iter().find(|c| c.name == name).ok_or_else(|| {
            let names: Vec<&str> = self.clips.iter().map(|c| c.name.as_str()).collect();
            fail(
                &self.path,
                format!("clip '{name}' not found (clips: {})", names.join(", ")),
            )
        })
    }
}

/// Loads a character and merges the clips of animation libraries `clips` into it (see
/// [`merge_clip_files`]).
pub fn load_character_with(path: &Path, clips: &[PathBuf]) -> Result<Character, CharacterError> {
    let mut character = load_character(path)?;
    merge_clip_files(&mut character, clips)?;
    Ok(character)
}

/// Adds the animations of glTF/GLB animation libraries (files with a skeleton and clips,
/// a mesh or not) to `character`'s clips, each channel retargeted onto the character's
/// node of the same name (channels of nodes it lacks are dropped). A clip whose name is
/// taken gets the library's file stem appended.
pub fn merge_clip_files(
    character: &mut Character,
    files: &[PathBuf],
) -> Result<(), CharacterError> {
    for file in files {
        let ext = file
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        if !file.is_file() {
            return Err(fail(file, "no such file (given with --clips)"));
        }
        if !["gltf", "glb", "vrm"].contains(&ext.as_str()) {
            return Err(fail(
                file,
                format!("unsupported animation file type '.{ext}' (expected .gltf, .glb or .vrm)"),
            ));
        }
        let clips = super::gltf_check::guarded(file, || read_clip_library(file, &character.rig))?;
        let stem = file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        for mut clip in clips {
            if character.clips.iter().any(|c| c.name == clip.name) {
                clip.name = format!("{} ({stem})", clip.name);
            }
            character.clips.push(clip);
        }
    }
    Ok(())
}

/// The clips of an animation library, on `rig`'s nodes matched by name.
fn read_clip_library(path: &Path, rig: &Rig) -> Result<Vec<Clip>, CharacterError> {
    let (doc, buffers, _) = super::gltf_check::import(path)?;
    if doc.animations().len() == 0 {
        return Err(fail(path, "the file has no animations"));
    }
    let index_of: Vec<Option<usize>> = doc
        .nodes()
        .map(|n| n.name().and_then(|name| rig.find(name)))
        .collect();
    let mut clips = Vec::new();
    for animation in doc.animations() {
        let clip = read_clip(path, &animation, &buffers, &index_of)?;
        if clip.channels.is_empty() {
            log::warn!(
                "{}: clip '{}' moves no joint of the character; skipped",
                path.display(),
                clip.name
            );
            continue;
        }
        clips.push(clip);
    }
    if clips.is_empty() {
        let mut names: Vec<&str> = doc.nodes().filter_map(|n| n.name()).collect();
        names.truncate(12);
        return Err(fail(
            path,
            format!(
                "no animation moves a joint of the character by name (its nodes: {}; the character's: {})",
                names.join(", "),
                node_names(rig, 12)
            ),
        ));
    }
    Ok(clips)
}

/// The first `most` node names of `rig` — its skin joints in skin order, then the other
/// nodes — comma-separated, with "…" when there are more.
pub fn node_names(rig: &Rig, most: usize) -> String {
    let mut order: Vec<usize> = Vec::new();
    for n in rig.bones.iter().map(|b| b.node).chain(0..rig.nodes.len()) {
        if !order.contains(&n) {
            order.push(n);
        }
    }
    let mut names: Vec<&str> = order
        .iter()
        .take(most)
        .map(|&n| rig.nodes[n].name.as_str())
        .collect();
    if order.len() > most {
        names.push("…");
    }
    names.join(", ")
}

/// Loads a character by extension: `.gltf`/`.glb` or `.obj`.
pub fn load_character(path: &Path) -> Result<Character, CharacterError> {
    if !path.is_file() {
        return Err(fail(path, "no such file"));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let (rig, skinned, clips, vrm) = match ext.as_str() {
        "gltf" | "glb" | "vrm" => super::gltf_check::guarded(path, || load_gltf(path))?,
        "obj" => load_obj(path)?,
        other => {
            return Err(fail(
                path,
                format!("unsupported file type '.{other}' (expected .gltf, .glb, .vrm or .obj)"),
            ));
        }
    };
    if skinned.bind.indices.is_empty() {
        return Err(fail(path, "the file contains no triangles"));
    }
    if let Some(v) = skinned.bind.positions.iter().position(|p| !p.is_finite()) {
        return Err(fail(
            path,
            format!(
                "vertex {v} has a non-finite position {}",
                skinned.bind.positions[v]
            ),
        ));
    }
    if let Some(v) = skinned
        .weights
        .iter()
        .position(|w| !w.iter().all(|x| x.is_finite()))
    {
        return Err(fail(
            path,
            format!("vertex {v} has a non-finite skin weight"),
        ));
    }
    if let Some(b) = rig.bones.iter().position(|b| !b.inverse_bind.is_finite()) {
        return Err(fail(
            path,
            format!("bone {b} has a non-finite inverse bind matrix"),
        ));
    }
    if let Some(n) = rig.nodes.iter().find(|n| {
        !(n.rest.translation.is_finite() && n.rest.rotation.is_finite() && n.rest.scale.is_finite())
    }) {
        return Err(fail(
            path,
            format!("node '{}' has a non-finite transform", n.name),
        ));
    }
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "character".into());
    Ok(Character {
        name,
        path: path.to_path_buf(),
        rig,
        skinned,
        clips,
        vrm,
    })
}

type Loaded = (Rig, SkinnedMesh, Vec<Clip>, Option<Vrm>);

fn load_gltf(path: &Path) -> Result<Loaded, CharacterError> {
    let (doc, buffers, images) = super::gltf_check::import(path)?;
    let scene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| fail(path, "no scene"))?;

    // Nodes of the scene in breadth-first order, so parents come before children.
    let mut rig = Rig::default();
    let mut index_of = vec![None; doc.nodes().len()];
    let mut queue: std::collections::VecDeque<(gltf::Node, Option<usize>)> =
        scene.nodes().map(|n| (n, None)).collect();
    let mut mesh_nodes = Vec::new();
    while let Some((node, parent)) = queue.pop_front() {
        let ours = rig.nodes.len();
        if index_of[node.index()].is_some() {
            return Err(fail(
                path,
                format!(
                    "node {} is reached twice from the scene (a cycle or a shared child)",
                    node.index()
                ),
            ));
        }
        index_of[node.index()] = Some(ours);
        let (t, r, s) = node.transform().decomposed();
        rig.nodes.push(Node {
            name: node
                .name()
                .map(str::to_string)
                .unwrap_or_else(|| format!("node{}", node.index())),
            parent,
            rest: Transform {
                translation: Vec3::from(t),
                rotation: Quat::from_array(r).normalize(),
                scale: Vec3::from(s),
            },
        });
        if node.mesh().is_some() {
            mesh_nodes.push(node.clone());
        }
        queue.extend(node.children().map(|c| (c, Some(ours))));
    }

    let mut skinned = SkinnedMesh::default();
    for node in mesh_nodes {
        let bones: Vec<usize> = match node.skin() {
            Some(skin) => skin_bones(path, &skin, &buffers, &index_of, &mut rig)?,
            None => vec![rig.bone(Bone {
                node: index_of[node.index()].expect("mesh node is in the scene"),
                inverse_bind: Mat4::IDENTITY,
            })],
        };
        for primitive in node
            .mesh()
            .into_iter()
            .flat_map(|m| m.primitives().collect::<Vec<_>>())
        {
            if primitive.mode() != gltf::mesh::Mode::Triangles {
                log::warn!("{}: skipping a non-triangle primitive", path.display());
                continue;
            }
            let mut part = read_primitive(
                path,
                &primitive,
                &buffers,
                &images,
                &bones,
                node.skin().is_some(),
            )?;
            part.part = vec![0; part.bind.positions.len()];
            part.parts = vec![Part {
                mesh: node.name().unwrap_or_default().to_string(),
                material: primitive.material().name().unwrap_or_default().to_string(),
            }];
            skinned.append(part);
        }
    }

    let clips = doc
        .animations()
        .map(|a| read_clip(path, &a, &buffers, &index_of))
        .collect::<Result<_, _>>()?;
    let vrm = Vrm::read(doc.extensions(), &|i| index_of.get(i).copied().flatten())
        .map_err(|e| fail(path, e))?;
    Ok((rig, skinned, clips, vrm))
}

/// The rig bones of a skin's joints, in joint order.
fn skin_bones(
    path: &Path,
    skin: &gltf::Skin,
    buffers: &[gltf::buffer::Data],
    index_of: &[Option<usize>],
    rig: &mut Rig,
) -> Result<Vec<usize>, CharacterError> {
    let joints: Vec<gltf::Node> = skin.joints().collect();
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
    joints
        .iter()
        .zip(inverse_bind)
        .map(|(joint, inverse_bind)| {
            let node = index_of[joint.index()].ok_or_else(|| {
                fail(
                    path,
                    format!(
                        "skin joint '{}' is not in the scene",
                        joint.name().unwrap_or("?")
                    ),
                )
            })?;
            Ok(rig.bone(Bone { node, inverse_bind }))
        })
        .collect()
}

fn read_primitive(
    path: &Path,
    primitive: &gltf::Primitive,
    buffers: &[gltf::buffer::Data],
    images: &[gltf::image::Data],
    bones: &[usize],
    skinned: bool,
) -> Result<SkinnedMesh, CharacterError> {
    let reader = primitive.reader(|b| Some(&buffers[b.index()]));
    let positions: Vec<Vec3> = reader
        .read_positions()
        .ok_or_else(|| fail(path, "a mesh primitive has no POSITION attribute"))?
        .map(Vec3::from)
        .collect();
    let n = positions.len();
    let indices: Vec<u32> = match reader.read_indices() {
        Some(i) => i.into_u32().collect(),
        None => (0..n as u32).collect(),
    };
    if !indices.len().is_multiple_of(3) {
        return Err(fail(
            path,
            format!(
                "a triangle primitive has {} indices, not a multiple of 3",
                indices.len()
            ),
        ));
    }
    if let Some(&bad) = indices.iter().find(|&&i| i as usize >= n) {
        return Err(fail(path, format!("index {bad} is past the {n} vertices")));
    }
    let (joints, weights): (Vec<[u16; 4]>, Vec<[f32; 4]>) = if skinned {
        let joints: Vec<[u16; 4]> = reader
            .read_joints(0)
            .ok_or_else(|| fail(path, "a skinned primitive has no JOINTS_0"))?
            .into_u16()
            .collect();
        let weights: Vec<[f32; 4]> = reader
            .read_weights(0)
            .ok_or_else(|| fail(path, "a skinned primitive has no WEIGHTS_0"))?
            .into_f32()
            .collect();
        if joints.len() != n || weights.len() != n {
            return Err(fail(
                path,
                "JOINTS_0/WEIGHTS_0 count differs from POSITION count",
            ));
        }
        let mut remapped = Vec::with_capacity(n);
        let mut normalised = Vec::with_capacity(n);
        for (j, w) in joints.iter().zip(&weights) {
            let mut out = [0u16; 4];
            for k in 0..4 {
                let bone = bones.get(j[k] as usize).ok_or_else(|| {
                    fail(
                        path,
                        format!(
                            "joint index {} is past the skin's {} joints",
                            j[k],
                            bones.len()
                        ),
                    )
                })?;
                out[k] = *bone as u16;
            }
            let total: f32 = w.iter().sum();
            if w.iter().any(|x| !x.is_finite() || *x < 0.0) {
                return Err(fail(
                    path,
                    format!("a skinned vertex has weights {w:?} (not finite and non-negative)"),
                ));
            }
            if total <= 0.0 {
                return Err(fail(path, "a skinned vertex has all weights zero"));
            }
            remapped.push(out);
            normalised.push(w.map(|x| x / total));
        }
        (remapped, normalised)
    } else {
        (
            vec![[bones[0] as u16, 0, 0, 0]; n],
            vec![[1.0, 0.0, 0.0, 0.0]; n],
        )
    };
    let colors = vertex_colours(primitive, &reader, images, n);
    let mut bind = Mesh {
        positions,
        normals: Vec::new(),
        colors,
        indices,
    };
    match reader.read_normals() {
        Some(normals) => {
            bind.normals = normals
                .map(|v| Vec3::from(v).normalize_or(Vec3::Y))
                .collect()
        }
        None => bind.compute_normals(),
    }
    Ok(SkinnedMesh {
        bind,
        joints,
        weights,
        ..Default::default()
    })
}

/// Linear base colour per vertex: the material's factor times its texture at the vertex UV
/// times the vertex colour `COLOR_0`, where the primitive has them.
fn vertex_colours<'a, 's, F>(
    primitive: &gltf::Primitive,
    reader: &gltf::mesh::Reader<'a, 's, F>,
    images: &[gltf::image::Data],
    n: usize,
) -> Vec<Vec3>
where
    F: Clone + Fn(gltf::Buffer<'a>) -> Option<&'s [u8]>,
{
    let pbr = primitive.material().pbr_metallic_roughness();
    let factor = Vec4::from(pbr.base_color_factor()).truncate();
    let texture = pbr.base_color_texture().map(|info| {
        let uvs: Vec<Vec2> = reader
            .read_tex_coords(info.tex_coord())
            .map(|t| t.into_f32().map(Vec2::from).collect())
            .unwrap_or_default();
        (&images[info.texture().source().index()], uvs)
    });
    let mut colours: Vec<Vec3> = match texture {
        Some((image, uvs)) if uvs.len() == n => {
            uvs.iter().map(|&uv| factor * texel(image, uv)).collect()
        }
        _ => vec![factor; n],
    };
    let vertex: Vec<Vec3> = reader
        .read_colors(0)
        .map(|c| c.into_rgb_f32().map(Vec3::from).collect())
        .unwrap_or_default();
    if vertex.len() == n {
        for (colour, v) in colours.iter_mut().zip(vertex) {
            *colour *= v;
        }
    }
    colours
}

/// The linear colour of the texel nearest to `uv` (repeat wrapping), white if the
/// image format is not 8-bit RGB(A).
fn texel(image: &gltf::image::Data, uv: Vec2) -> Vec3 {
    let channels = match image.format {
        gltf::image::Format::R8G8B8 => 3,
        gltf::image::Format::R8G8B8A8 => 4,
        _ => return Vec3::ONE,
    };
    if image.width == 0 || image.height == 0 || !uv.is_finite() {
        return Vec3::ONE;
    }
    let x = ((uv.x.rem_euclid(1.0) * image.width as f32) as usize).min(image.width as usize - 1);
    let y = ((uv.y.rem_euclid(1.0) * image.height as f32) as usize).min(image.height as usize - 1);
    let i = (y * image.width as usize + x) * channels;
    let Some(rgb) = image.pixels.get(i..i + 3) else {
        return Vec3::ONE;
    };
    let srgb = |v: u8| {
        let c = v as f32 / 255.0;
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    Vec3::new(srgb(rgb[0]), srgb(rgb[1]), srgb(rgb[2]))
}

fn read_clip(
    path: &Path,
    animation: &gltf::Animation,
    buffers: &[gltf::buffer::Data],
    index_of: &[Option<usize>],
) -> Result<Clip, CharacterError> {
    let name = animation
        .name()
        .map(str::to_string)
        .unwrap_or_else(|| format!("clip{}", animation.index()));
    let mut channels = Vec::new();
    for channel in animation.channels() {
        let Some(node) = index_of[channel.target().node().index()] else {
            continue;
        };
        let reader = channel.reader(|b| Some(&buffers[b.index()]));
        let times: Vec<f32> = reader
            .read_inputs()
            .ok_or_else(|| fail(path, format!("clip '{name}': a channel has no key times")))?
            .collect();
        let values = match reader.read_outputs() {
            Some(gltf::animation::util::ReadOutputs::Translations(v)) => {
                Values::Translation(v.map(Vec3::from).collect())
            }
            Some(gltf::animation::util::ReadOutputs::Scales(v)) => {
                Values::Scale(v.map(Vec3::from).collect())
            }
            Some(gltf::animation::util::ReadOutputs::Rotations(v)) => {
                Values::Rotation(v.into_f32().map(Vec4::from).collect())
            }
            Some(gltf::animation::util::ReadOutputs::MorphTargetWeights(_)) => continue,
            None => {
                return Err(fail(
                    path,
                    format!("clip '{name}': a channel has no values"),
                ));
            }
        };
        let interpolation = match channel.sampler().interpolation() {
            gltf::animation::Interpolation::Linear => Interpolation::Linear,
            gltf::animation::Interpolation::Step => Interpolation::Step,
            gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
        };
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        let finite = match &values {
            Values::Translation(v) | Values::Scale(v) => v.iter().all(|x| x.is_finite()),
            Values::Rotation(v) => v.iter().all(|x| x.is_finite()),
        };
        if !finite || times.iter().any(|t| !t.is_finite()) || !times.is_sorted() {
            return Err(fail(
                path,
                format!("clip '{name}': key times or values are not finite and increasing"),
            ));
        }
        let count = match &values {
            Values::Translation(v) | Values::Scale(v) => v.len(),
            Values::Rotation(v) => v.len(),
        };
        if times.is_empty() || count != times.len() * per_key {
            return Err(fail(
                path,
                format!(
                    "clip '{name}': {} key times but {count} values",
                    times.len()
                ),
            ));
        }
        channels.push(Channel {
            node,
            times,
            interpolation,
            values,
        });
    }
    let duration = channels
        .iter()
        .filter_map(|c| c.times.last().copied())
        .fold(0.0f32, f32::max);
    Ok(Clip {
        name,
        duration,
        channels,
    })
}

fn load_obj(path: &Path) -> Result<Loaded, CharacterError> {
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
    let mut bind = Mesh::default();
    let mut parts = Vec::new();
    let mut part = Vec::new();
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
        let mut piece = Mesh {
            colors: vec![color; positions.len()],
            positions,
            indices: m.indices.clone(),
            normals: Vec::new(),
        };
        if m.normals.len() == m.positions.len() {
            piece.normals = m
                .normals
                .chunks_exact(3)
                .map(|n| Vec3::new(n[0], n[1], n[2]).normalize_or(Vec3::Y))
                .collect();
        } else {
            piece.compute_normals();
        }
        part.extend(std::iter::repeat_n(
            parts.len() as u16,
            piece.positions.len(),
        ));
        parts.push(Part {
            mesh: model.name.clone(),
            material: m
                .material_id
                .and_then(|id| materials.get(id))
                .map(|mat| mat.name.clone())
                .unwrap_or_default(),
        });
        bind.append(piece);
    }
    let rig = Rig {
        nodes: vec![Node {
            name: "root".into(),
            parent: None,
            rest: Transform::default(),
        }],
        bones: vec![Bone {
            node: 0,
            inverse_bind: Mat4::IDENTITY,
        }],
    };
    let n = bind.positions.len();
    let skinned = SkinnedMesh {
        bind,
        joints: vec![[0; 4]; n],
        weights: vec![[1.0, 0.0, 0.0, 0.0]; n],
        part,
        parts,
    };
    Ok((rig, skinned, Vec::new(), None))
}
