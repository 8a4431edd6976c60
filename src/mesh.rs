//! A triangle mesh with per-vertex colour: plain data shared by the loaders, the renderer
//! and the bake, with the geometry helpers they need (normals, bounds, boxes).

use glam::Vec3;

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    /// Linear RGB base colour per vertex.
    pub colors: Vec<Vec3>,
    /// Triangle list.
    pub indices: Vec<u32>,
}

impl Mesh {
    /// Appends `other`, re-basing its indices.
    pub fn append(&mut self, other: Mesh) {
        let base = self.positions.len() as u32;
        self.positions.extend(other.positions);
        self.normals.extend(other.normals);
        self.colors.extend(other.colors);
        self.indices
            .extend(other.indices.into_iter().map(|i| i + base));
    }

    /// Axis-aligned bounds (min, max); `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let first = *self.positions.first()?;
        Some(
            self.positions
                .iter()
                .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
        )
    }

    /// The y extent of the positions (1 for an empty mesh).
    pub fn height(&self) -> f32 {
        self.bounds().map_or(1.0, |(lo, hi)| hi.y - lo.y)
    }

    /// Area-weighted smooth vertex normals from the triangles.
    pub fn compute_normals(&mut self) {
        let mut normals = vec![Vec3::ZERO; self.positions.len()];
        for tri in self.indices.chunks_exact(3) {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| self.positions[i as usize]);
            let n = (b - a).cross(c - a);
            for &i in tri {
                normals[i as usize] += n;
            }
        }
        self.normals = normals
            .into_iter()
            .map(|n| n.normalize_or(Vec3::Y))
            .collect();
    }

    /// An axis-aligned box with flat-shaded faces, for placeholders.
    pub fn cuboid(min: Vec3, max: Vec3, color: Vec3) -> Self {
        let corner = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { max.x } else { min.x },
                if y { max.y } else { min.y },
                if z { max.z } else { min.z },
            )
        };
        // Each face: outward normal and its 4 corners counter-clockwise seen from outside.
        let faces = [
            (
                Vec3::X,
                [
                    (true, false, true),
                    (true, false, false),
                    (true, true, false),
                    (true, true, true),
                ],
            ),
            (
                Vec3::NEG_X,
                [
                    (false, false, false),
                    (false, false, true),
                    (false, true, true),
                    (false, true, false),
                ],
            ),
            (
                Vec3::Y,
                [
                    (false, true, true),
                    (true, true, true),
                    (true, true, false),
                    (false, true, false),
                ],
            ),
            (
                Vec3::NEG_Y,
                [
                    (false, false, false),
                    (true, false, false),
                    (true, false, true),
                    (false, false, true),
                ],
            ),
            (
                Vec3::Z,
                [
                    (false, false, true),
                    (true, false, true),
                    (true, true, true),
                    (false, true, true),
                ],
            ),
            (
                Vec3::NEG_Z,
                [
                    (true, false, false),
                    (false, false, false),
                    (false, true, false),
                    (true, true, false),
                ],
            ),
        ];
        let mut mesh = Mesh::default();
        for (normal, corners) in faces {
            let base = mesh.positions.len() as u32;
            for (x, y, z) in corners {
                mesh.positions.push(corner(x, y, z));
                mesh.normals.push(normal);
                mesh.colors.push(color);
            }
            mesh.indices
                .extend([base, base + 1, base + 2, base, base + 2, base + 3]);
        }
        mesh
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cuboid_faces_wind_outward() {
        let mesh = Mesh::cuboid(Vec3::splat(-1.0), Vec3::splat(1.0), Vec3::ONE);
        assert_eq!(mesh.indices.len(), 36);
        for tri in mesh.indices.chunks_exact(3) {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| mesh.positions[i as usize]);
            let winding_normal = (b - a).cross(c - a).normalize();
            assert!(winding_normal.abs_diff_eq(mesh.normals[tri[0] as usize], 1e-6));
        }
    }

    #[test]
    fn computed_normals_match_the_flat_faces_of_a_box() {
        let mut mesh = Mesh::cuboid(Vec3::ZERO, Vec3::ONE, Vec3::ONE);
        let expected = mesh.normals.clone();
        mesh.compute_normals();
        for (got, want) in mesh.normals.iter().zip(&expected) {
            assert!(got.abs_diff_eq(*want, 1e-6), "{got} vs {want}");
        }
    }

    #[test]
    fn bounds_and_append() {
        let mut a = Mesh::cuboid(Vec3::ZERO, Vec3::ONE, Vec3::ONE);
        let b = Mesh::cuboid(Vec3::splat(2.0), Vec3::splat(3.0), Vec3::ONE);
        a.append(b);
        assert_eq!(a.bounds(), Some((Vec3::ZERO, Vec3::splat(3.0))));
        assert_eq!(*a.indices.iter().max().unwrap(), 47);
        assert_eq!(Mesh::default().bounds(), None);
    }
}
