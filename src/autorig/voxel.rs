//! The voxel geodesic prior (UniRig): the mesh is voxelised (surface voxels from the
//! triangles, inside voxels as whatever a flood fill from outside cannot reach), and the
//! distance from each joint's bone to each vertex is the shortest path through occupied
//! voxels (26-neighbour Dijkstra), plus the last step from the voxel to the vertex.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};

use glam::{IVec3, Vec3};

use crate::mesh::Mesh;

/// The far end of each joint's bone: the mean of its children, or for a leaf the joint
/// pushed on by half its parent bone (a lone root ends where it starts).
pub fn bone_tails(joints: &[Vec3], parents: &[Option<usize>]) -> Vec<Vec3> {
    (0..joints.len())
        .map(|j| {
            let children: Vec<Vec3> = (0..joints.len())
                .filter(|&c| parents[c] == Some(j))
                .map(|c| joints[c])
                .collect();
            if !children.is_empty() {
                children.iter().sum::<Vec3>() / children.len() as f32
            } else if let Some(p) = parents[j] {
                joints[j] + 0.5 * (joints[j] - joints[p])
            } else {
                joints[j]
            }
        })
        .collect()
}

/// The segments that joint `j` moves: one to each child, or its own tail for a leaf.
pub fn bone_segments(joints: &[Vec3], parents: &[Option<usize>], j: usize) -> Vec<(Vec3, Vec3)> {
    let children: Vec<(Vec3, Vec3)> = (0..joints.len())
        .filter(|&c| parents[c] == Some(j))
        .map(|c| (joints[j], joints[c]))
        .collect();
    if children.is_empty() {
        vec![(joints[j], bone_tails(joints, parents)[j])]
    } else {
        children
    }
}

/// Distance from `p` to the segment a–b.
pub fn segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
    p.distance(a + t * ab)
}

/// An occupancy grid over a mesh's bounds.
pub struct Voxels {
    origin: Vec3,
    size: f32,
    dims: IVec3,
    inside: Vec<bool>,
}

impl Voxels {
    /// Voxelises `mesh` with `resolution` voxels along its longest side.
    pub fn new(mesh: &Mesh, resolution: usize) -> Self {
        let (lo, hi) = mesh.bounds().unwrap_or((Vec3::ZERO, Vec3::ONE));
        let size = (hi - lo).max_element().max(1e-6) / resolution as f32;
        let origin = lo - Vec3::splat(2.0 * size);
        let dims = (((hi - lo) / size).ceil().as_ivec3() + IVec3::splat(5)).max(IVec3::ONE);
        let count = (dims.x * dims.y * dims.z) as usize;
        let mut voxels = Self {
            origin,
            size,
            dims,
            inside: vec![false; count],
        };
        let mut surface = vec![false; count];
        for tri in mesh.indices.chunks_exact(3) {
            let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| mesh.positions[i as usize]);
            let longest = a.distance(b).max(b.distance(c)).max(c.distance(a));
            let steps = ((longest / (0.5 * size)).ceil() as usize).max(1);
            for i in 0..=steps {
                for k in 0..=steps - i {
                    let (u, v) = (i as f32 / steps as f32, k as f32 / steps as f32);
                    let p = a + u * (b - a) + v * (c - a);
                    if let Some(index) = voxels.index(voxels.cell(p)) {
                        surface[index] = true;
                    }
                }
            }
        }
        // Flood the outside from a corner (the padding is always outside).
        let mut outside = vec![false; count];
        let mut queue = VecDeque::from([IVec3::ZERO]);
        outside[0] = true;
        while let Some(cell) = queue.pop_front() {
            for step in [
                IVec3::X,
                IVec3::NEG_X,
                IVec3::Y,
                IVec3::NEG_Y,
                IVec3::Z,
                IVec3::NEG_Z,
            ] {
                if let Some(n) = voxels.index(cell + step)
                    && !outside[n]
                    && !surface[n]
                {
                    outside[n] = true;
                    queue.push_back(cell + step);
                }
            }
        }
        voxels.inside = outside.iter().map(|&o| !o).collect();
        voxels
    }

    fn cell(&self, p: Vec3) -> IVec3 {
        ((p - self.origin) / self.size).floor().as_ivec3()
    }

    fn centre(&self, cell: IVec3) -> Vec3 {
        self.origin + (cell.as_vec3() + 0.5) * self.size
    }

    fn index(&self, cell: IVec3) -> Option<usize> {
        let d = self.dims;
        (cell.cmpge(IVec3::ZERO).all() && cell.cmplt(d).all())
            .then(|| (cell.x + d.x * (cell.y + d.y * cell.z)) as usize)
    }

    fn cell_of(&self, index: usize) -> IVec3 {
        let i = index as i32;
        let d = self.dims;
        IVec3::new(i % d.x, (i / d.x) % d.y, i / (d.x * d.y))
    }

    pub fn occupied(&self) -> usize {
        self.inside.iter().filter(|&&i| i).count()
    }

    /// The occupied voxel nearest `p` (its own when occupied), searching outward.
    fn nearest_inside(&self, p: Vec3) -> Option<usize> {
        let centre = self.cell(p);
        if let Some(i) = self.index(centre).filter(|&i| self.inside[i]) {
            return Some(i);
        }
        for radius in 1..self.dims.max_element() {
            let mut best: Option<(usize, f32)> = None;
            for z in -radius..=radius {
                for y in -radius..=radius {
                    for x in -radius..=radius {
                        let offset = IVec3::new(x, y, z);
                        if offset.abs().max_element() != radius {
                            continue;
                        }
                        let cell = centre + offset;
                        if let Some(i) = self.index(cell).filter(|&i| self.inside[i]) {
                            let d = self.centre(cell).distance_squared(p);
                            if best.is_none_or(|(_, b)| d < b) {
                                best = Some((i, d));
                            }
                        }
                    }
                }
            }
            if let Some((i, _)) = best {
                return Some(i);
            }
        }
        None
    }

    /// Shortest-path distances through occupied voxels from the seed points.
    fn distances(&self, seeds: &[Vec3]) -> Vec<f32> {
        let mut dist = vec![f32::INFINITY; self.inside.len()];
        let mut heap = BinaryHeap::new();
        for &s in seeds {
            if let Some(i) = self.nearest_inside(s) {
                let d = self.centre(self.cell_of(i)).distance(s);
                if d < dist[i] {
                    dist[i] = d;
                    heap.push(Visit(d, i));
                }
            }
        }
        while let Some(Visit(d, i)) = heap.pop() {
            if d > dist[i] {
                continue;
            }
            let cell = self.cell_of(i);
            for z in -1..=1 {
                for y in -1..=1 {
                    for x in -1..=1 {
                        let step = IVec3::new(x, y, z);
                        if step == IVec3::ZERO {
                            continue;
                        }
                        if let Some(n) = self.index(cell + step).filter(|&n| self.inside[n]) {
                            let nd = d + self.size * step.as_vec3().length();
                            if nd < dist[n] {
                                dist[n] = nd;
                                heap.push(Visit(nd, n));
                            }
                        }
                    }
                }
            }
        }
        dist
    }

    /// Geodesic distance `[vertex][joint]` from every joint's bone segments to every
    /// vertex. A vertex no path reaches gets twice its straight-line distance.
    pub fn geodesic(
        &self,
        vertices: &[Vec3],
        joints: &[Vec3],
        parents: &[Option<usize>],
    ) -> Vec<Vec<f32>> {
        let anchors: Vec<Option<usize>> =
            vertices.iter().map(|&v| self.nearest_inside(v)).collect();
        let columns: Vec<Vec<f32>> = (0..joints.len())
            .map(|j| {
                let segments = bone_segments(joints, parents, j);
                let mut seeds = Vec::new();
                for &(a, b) in &segments {
                    let steps = ((a.distance(b) / (0.5 * self.size)).ceil() as usize).max(1);
                    seeds.extend((0..=steps).map(|k| a.lerp(b, k as f32 / steps as f32)));
                }
                let dist = self.distances(&seeds);
                vertices
                    .iter()
                    .zip(&anchors)
                    .map(|(&p, anchor)| {
                        let straight = segments
                            .iter()
                            .map(|&(a, b)| segment_distance(p, a, b))
                            .fold(f32::INFINITY, f32::min);
                        let through = anchor
                            .map(|i| dist[i] + self.centre(self.cell_of(i)).distance(p))
                            .filter(|d| d.is_finite());
                        through.unwrap_or(2.0 * straight).max(straight)
                    })
                    .collect()
            })
            .collect();
        (0..vertices.len())
            .map(|v| columns.iter().map(|c| c[v]).collect())
            .collect()
    }
}

/// A heap entry ordered by smallest distance first.
#[derive(PartialEq)]
struct Visit(f32, usize);

impl Eq for Visit {}

impl Ord for Visit {
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then(other.1.cmp(&self.1))
    }
}

impl PartialOrd for Visit {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed U-shaped tube: two vertical boxes joined by a bridge at the bottom.
    fn u_shape() -> Mesh {
        let mut mesh = Mesh::cuboid(
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 4.0, 1.0),
            Vec3::ONE,
        );
        mesh.append(Mesh::cuboid(
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(3.0, 4.0, 1.0),
            Vec3::ONE,
        ));
        mesh.append(Mesh::cuboid(
            Vec3::new(0.5, 0.0, 0.0),
            Vec3::new(2.5, 1.0, 1.0),
            Vec3::ONE,
        ));
        mesh
    }

    #[test]
    fn a_solid_box_is_filled() {
        let mesh = Mesh::cuboid(Vec3::ZERO, Vec3::ONE, Vec3::ONE);
        let voxels = Voxels::new(&mesh, 10);
        // 10³ interior cells plus the surface layer the triangles touch.
        let occupied = voxels.occupied();
        assert!((1000..=12 * 12 * 12).contains(&occupied), "{occupied}");
    }

    #[test]
    fn the_path_goes_around_a_gap_not_across_it() {
        // A bone in the left arm of the U; a vertex at the top of the right arm is 2 units
        // away in a straight line but about 2·3 + 2 along the tube.
        let mesh = u_shape();
        let voxels = Voxels::new(&mesh, 30);
        let joints = [Vec3::new(0.5, 3.0, 0.5), Vec3::new(0.5, 3.9, 0.5)];
        let parents = [None, Some(0)];
        let top_right = Vec3::new(2.5, 3.0, 0.5);
        let next_to_bone = Vec3::new(0.9, 3.0, 0.5);
        let d = voxels.geodesic(&[top_right, next_to_bone], &joints, &parents);
        // The root's bone runs from (0.5,3) to (0.5,3.9): straight 2.0, through the U ≈ 6.
        assert!(d[0][0] > 5.0 && d[0][0] < 7.0, "{}", d[0][0]);
        assert!((d[1][0] - 0.4).abs() < 0.15, "{}", d[1][0]);
    }

    #[test]
    fn tails_follow_children_or_extend_leaves() {
        let joints = [
            Vec3::ZERO,
            Vec3::Y,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ];
        let parents = [None, Some(0), Some(1), Some(1)];
        let tails = bone_tails(&joints, &parents);
        assert_eq!(tails[0], Vec3::Y);
        assert_eq!(tails[1], Vec3::Y);
        assert_eq!(tails[2], Vec3::new(1.5, 1.0, 0.0));
        assert_eq!(bone_segments(&joints, &parents, 1).len(), 2);
    }
}
