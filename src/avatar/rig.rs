//! The skeleton of a character: nodes in parent-before-child order with rest transforms,
//! the bones that skin the mesh, world transforms of a pose, and linear blend skinning.

use glam::{Mat4, Quat, Vec3};

use crate::mesh::Mesh;

/// A local transform: translation, rotation, scale (applied scale first).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform {
    pub translation: Vec3,
    pub rotation: Quat,
    pub scale: Vec3,
}

impl Default for Transform {
    fn default() -> Self {
        Self {
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::ONE,
        }
    }
}

impl Transform {
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }

    /// Interpolates translation and scale linearly and rotation along the shortest arc.
    pub fn blend(&self, other: &Transform, t: f32) -> Transform {
        Transform {
            translation: self.translation.lerp(other.translation, t),
            rotation: self.rotation.slerp(other.rotation, t),
            scale: self.scale.lerp(other.scale, t),
        }
    }
}

#[derive(Clone, Debug)]
pub struct Node {
    pub name: String,
    /// Always an index smaller than this node's own.
    pub parent: Option<usize>,
    pub rest: Transform,
}

/// One skinning matrix source: a node and its inverse bind matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bone {
    pub node: usize,
    pub inverse_bind: Mat4,
}

#[derive(Clone, Debug, Default)]
pub struct Rig {
    pub nodes: Vec<Node>,
    pub bones: Vec<Bone>,
}

impl Rig {
    pub fn find(&self, name: &str) -> Option<usize> {
        self.nodes.iter().position(|n| n.name == name)
    }

    /// Whether node `node` is `top` or below it.
    pub fn is_under(&self, node: usize, top: usize) -> bool {
        let mut n = Some(node);
        while let Some(k) = n {
            if k == top {
                return true;
            }
            n = self.nodes[k].parent;
        }
        false
    }

    /// The rest pose: every node's local rest transform.
    pub fn rest_pose(&self) -> Vec<Transform> {
        self.nodes.iter().map(|n| n.rest).collect()
    }

    /// World matrices of a pose given as local transforms, `root` applied above the roots.
    pub fn world(&self, local: &[Transform], root: Mat4) -> Vec<Mat4> {
        let mut world: Vec<Mat4> = Vec::with_capacity(self.nodes.len());
        for (node, transform) in self.nodes.iter().zip(local) {
            let parent = node.parent.map_or(root, |p| world[p]);
            world.push(parent * transform.matrix());
        }
        world
    }

    /// Skinning matrices (world × inverse bind) of every bone for world matrices `world`.
    pub fn skin_matrices(&self, world: &[Mat4]) -> Vec<Mat4> {
        self.bones
            .iter()
            .map(|b| world[b.node] * b.inverse_bind)
            .collect()
    }

    /// Adds a bone unless the same (node, inverse bind) pair exists; returns its index.
    pub fn bone(&mut self, bone: Bone) -> usize {
        match self.bones.iter().position(|b| *b == bone) {
            Some(i) => i,
            None => {
                self.bones.push(bone);
                self.bones.len() - 1
            }
        }
    }
}

/// Where a group of vertices came from: its mesh (node name) and material name.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Part {
    pub mesh: String,
    pub material: String,
}

/// A mesh in bind space with up to four bone influences per vertex.
#[derive(Clone, Debug, Default)]
pub struct SkinnedMesh {
    /// Bind-space positions, normals; colours and triangles as in [`Mesh`].
    pub bind: Mesh,
    pub joints: Vec<[u16; 4]>,
    /// Normalised: each vertex's weights sum to 1.
    pub weights: Vec<[f32; 4]>,
    /// Index into `parts` per vertex.
    pub part: Vec<u16>,
    pub parts: Vec<Part>,
}

impl SkinnedMesh {
    /// Linear blend skinning with the given skinning matrices.
    pub fn pose(&self, skin: &[Mat4]) -> Mesh {
        let mut positions = Vec::with_capacity(self.bind.positions.len());
        let mut normals = Vec::with_capacity(self.bind.positions.len());
        for (i, (&p, &n)) in self
            .bind
            .positions
            .iter()
            .zip(&self.bind.normals)
            .enumerate()
        {
            let m = blend_matrix(skin, self.joints[i], self.weights[i]);
            positions.push(m.transform_point3(p));
            normals.push(m.transform_vector3(n).normalize_or(Vec3::Y));
        }
        Mesh {
            positions,
            normals,
            colors: self.bind.colors.clone(),
            indices: self.bind.indices.clone(),
        }
    }

    pub fn append(&mut self, other: SkinnedMesh) {
        let base = self.parts.len() as u16;
        self.bind.append(other.bind);
        self.joints.extend(other.joints);
        self.weights.extend(other.weights);
        self.part.extend(other.part.into_iter().map(|p| p + base));
        self.parts.extend(other.parts);
    }

    /// The bone with the largest weight on vertex `v`.
    pub fn dominant_bone(&self, v: usize) -> usize {
        let k = (0..4)
            .max_by(|&a, &b| self.weights[v][a].total_cmp(&self.weights[v][b]))
            .expect("four weights");
        self.joints[v][k] as usize
    }

    /// Vertices whose part has mesh `mesh` (any if `None`) and a material in `materials`
    /// (any if empty).
    pub fn select(&self, mesh: Option<&str>, materials: &[String]) -> Vec<usize> {
        let wanted: Vec<bool> = self
            .parts
            .iter()
            .map(|p| {
                mesh.is_none_or(|m| p.mesh == m)
                    && (materials.is_empty() || materials.contains(&p.material))
            })
            .collect();
        (0..self.part.len())
            .filter(|&v| wanted[self.part[v] as usize])
            .collect()
    }
}

/// The weighted sum of a vertex's bone matrices.
pub fn blend_matrix(skin: &[Mat4], joints: [u16; 4], weights: [f32; 4]) -> Mat4 {
    let mut m = Mat4::ZERO;
    for (&j, &w) in joints.iter().zip(&weights) {
        if w != 0.0 {
            m += skin[j as usize] * w;
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_bone_rig() -> Rig {
        let mut rig = Rig::default();
        rig.nodes.push(Node {
            name: "root".into(),
            parent: None,
            rest: Transform::default(),
        });
        rig.nodes.push(Node {
            name: "child".into(),
            parent: Some(0),
            rest: Transform {
                translation: Vec3::new(0.0, 1.0, 0.0),
                ..Default::default()
            },
        });
        let rest = rig.world(&rig.rest_pose(), Mat4::IDENTITY);
        for (node, world) in rest.iter().enumerate() {
            rig.bone(Bone {
                node,
                inverse_bind: world.inverse(),
            });
        }
        rig
    }

    #[test]
    fn rest_pose_skinning_is_identity() {
        let rig = two_bone_rig();
        let skin = rig.skin_matrices(&rig.world(&rig.rest_pose(), Mat4::IDENTITY));
        for m in &skin {
            assert!(m.abs_diff_eq(Mat4::IDENTITY, 1e-6));
        }
    }

    #[test]
    fn rotating_the_root_carries_the_child() {
        let rig = two_bone_rig();
        let mut pose = rig.rest_pose();
        pose[0].rotation = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        let world = rig.world(&pose, Mat4::IDENTITY);
        // The child at (0,1,0) swings to (-1,0,0).
        assert!(
            world[1]
                .w_axis
                .truncate()
                .abs_diff_eq(Vec3::new(-1.0, 0.0, 0.0), 1e-6)
        );
        let mesh = SkinnedMesh {
            bind: Mesh {
                positions: vec![Vec3::new(0.0, 2.0, 0.0)],
                normals: vec![Vec3::X],
                colors: vec![Vec3::ONE],
                indices: vec![],
            },
            joints: vec![[0, 1, 0, 0]],
            weights: vec![[0.5, 0.5, 0.0, 0.0]],
            ..Default::default()
        };
        let posed = mesh.pose(&rig.skin_matrices(&world));
        // Both bones rotate the point (0,2,0) about the origin to (-2,0,0).
        assert!(posed.positions[0].abs_diff_eq(Vec3::new(-2.0, 0.0, 0.0), 1e-5));
        assert!(posed.normals[0].abs_diff_eq(Vec3::Y, 1e-5));
    }

    #[test]
    fn half_weights_blend_linearly() {
        let skin = [
            Mat4::IDENTITY,
            Mat4::from_translation(Vec3::new(2.0, 0.0, 0.0)),
        ];
        let m = blend_matrix(&skin, [0, 1, 0, 0], [0.5, 0.5, 0.0, 0.0]);
        assert!(
            m.transform_point3(Vec3::ZERO)
                .abs_diff_eq(Vec3::new(1.0, 0.0, 0.0), 1e-6)
        );
    }

    #[test]
    fn duplicate_bones_are_shared() {
        let mut rig = two_bone_rig();
        let again = rig.bones[1];
        assert_eq!(rig.bone(again), 1);
        assert_eq!(rig.bones.len(), 2);
    }

    #[test]
    fn transform_blend_endpoints_and_midpoint() {
        let a = Transform::default();
        let b = Transform {
            translation: Vec3::new(2.0, 0.0, 0.0),
            rotation: Quat::from_rotation_y(1.0),
            scale: Vec3::splat(3.0),
        };
        assert_eq!(a.blend(&b, 0.0), a);
        let mid = a.blend(&b, 0.5);
        assert!(mid.translation.abs_diff_eq(Vec3::new(1.0, 0.0, 0.0), 1e-6));
        assert!(mid.rotation.abs_diff_eq(Quat::from_rotation_y(0.5), 1e-6));
        assert!(mid.scale.abs_diff_eq(Vec3::splat(2.0), 1e-6));
    }
}
