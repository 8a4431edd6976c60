//! Drawing a generated frame as a surface: neighbouring foreground pixels of the same
//! view become two triangles (oriented toward that view), so the map's points draw as the
//! six views' sheets with the scene renderer. Triangles with an edge over three times the
//! median neighbour distance in the given pose (across depth jumps) are left out.
//! Coloured by the bundle's per-pixel colours (else one colour). Splats are made by
//! `engine::appearance`.

use glam::Vec3;

use crate::mesh::Mesh;
use crate::posmap::table::VIEWS;
use crate::posmap::{MAP_SIZE, SurfaceTable};

/// The colour of bundles without per-pixel colours (a light violet).
pub const COLOR: Vec3 = Vec3::new(0.55, 0.5, 0.7);

/// Fixed triangles over the foreground points of a map.
#[derive(Clone, Debug)]
pub struct MapSurface {
    indices: Vec<u32>,
    colors: Vec<Vec3>,
}

impl MapSurface {
    /// `pixels`: the foreground pixels; `rest`: their points in one pose; `colors`: their
    /// linear RGB, if known.
    pub fn new(pixels: &[u32], rest: &[Vec3], colors: Option<&[Vec3]>) -> Self {
        let mut index = vec![u32::MAX; MAP_SIZE * MAP_SIZE];
        for (i, &p) in pixels.iter().enumerate() {
            index[p as usize] = i as u32;
        }
        let quads = quads(pixels, &index);
        let mut edges: Vec<f32> = quads
            .iter()
            .map(|&[a, b, ..]| rest[a as usize].distance(rest[b as usize]))
            .collect();
        edges.sort_by(f32::total_cmp);
        let median = edges.get(edges.len() / 2).copied().unwrap_or(0.0);
        let max_edge = 3.0 * median;
        let mut indices = Vec::new();
        for (view, [a, b, c, d]) in quads
            .into_iter()
            .map(|q| (SurfaceTable::view_of(pixels_of(q, pixels)), q))
        {
            for tri in [[a, c, b], [b, c, d]] {
                let [pa, pb, pc] = tri.map(|i| rest[i as usize]);
                if pa.distance(pb).max(pb.distance(pc)).max(pc.distance(pa)) > max_edge {
                    continue;
                }
                let facing = (pb - pa).cross(pc - pa).dot(VIEWS[view].toward()) >= 0.0;
                indices.extend(if facing {
                    tri
                } else {
                    [tri[0], tri[2], tri[1]]
                });
            }
        }
        let colors = colors.map_or_else(|| vec![COLOR; rest.len()], <[Vec3]>::to_vec);
        Self { indices, colors }
    }

    pub fn triangles(&self) -> usize {
        self.indices.len() / 3
    }

    /// The mesh of one frame's points.
    pub fn mesh(&self, points: &[Vec3]) -> Mesh {
        let mut mesh = Mesh {
            positions: points.to_vec(),
            normals: Vec::new(),
            colors: self.colors.clone(),
            indices: self.indices.clone(),
        };
        mesh.compute_normals();
        mesh
    }
}

/// The 2×2 blocks of foreground pixels within one view, as point indices [top-left,
/// top-right, bottom-left, bottom-right].
fn quads(pixels: &[u32], index: &[u32]) -> Vec<[u32; 4]> {
    let mut out = Vec::new();
    for &p in pixels {
        let (row, col) = (p as usize / MAP_SIZE, p as usize % MAP_SIZE);
        if row + 1 >= MAP_SIZE || col + 1 >= MAP_SIZE {
            continue;
        }
        let view = SurfaceTable::view_of(p);
        let quad = [
            p as usize,
            p as usize + 1,
            p as usize + MAP_SIZE,
            p as usize + MAP_SIZE + 1,
        ];
        if quad
            .iter()
            .all(|&q| index[q] != u32::MAX && SurfaceTable::view_of(q as u32) == view)
        {
            out.push(quad.map(|q| index[q]));
        }
    }
    out
}

/// The pixel of a quad's first point.
fn pixels_of(quad: [u32; 4], pixels: &[u32]) -> u32 {
    pixels[quad[0] as usize]
}
