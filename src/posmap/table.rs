//! The pixel → surface table: the reference mesh drawn by six orthographic views into
//! one 128 × 128 map (layout of the reference implementation, each view's scale fitted to
//! the reference's extent), every foreground pixel remembering its triangle and
//! barycentric weights. A posed frame's map is then a gather: no rasterisation.

use glam::{Vec2, Vec3};

/// Width and height of the packed map.
pub const MAP_SIZE: usize = 128;

/// One orthographic view and where it lands in the packed map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    pub name: &'static str,
    /// Top-left pixel (row, column) of the view's slot and its size in pixels.
    pub row: usize,
    pub col: usize,
    pub rows: usize,
    pub cols: usize,
    /// World directions of increasing column and increasing row.
    pub right: Vec3,
    pub down: Vec3,
}

impl View {
    /// The direction toward the viewer (nearer surfaces have larger `toward · p`).
    pub fn toward(&self) -> Vec3 {
        self.down.cross(self.right)
    }
}

/// The six views, in the reference layout: back and front 96 × 48, right 96 × 32, left
/// 32 × 96 (rotated), up and down 16 × 32. The character faces +Z with +Y up.
pub const VIEWS: [View; 6] = [
    View {
        name: "back",
        row: 0,
        col: 0,
        rows: 96,
        cols: 48,
        right: Vec3::NEG_X,
        down: Vec3::NEG_Y,
    },
    View {
        name: "front",
        row: 0,
        col: 48,
        rows: 96,
        cols: 48,
        right: Vec3::X,
        down: Vec3::NEG_Y,
    },
    View {
        name: "right",
        row: 0,
        col: 96,
        rows: 96,
        cols: 32,
        right: Vec3::Z,
        down: Vec3::NEG_Y,
    },
    View {
        name: "left",
        row: 96,
        col: 0,
        rows: 32,
        cols: 96,
        right: Vec3::Y,
        down: Vec3::NEG_Z,
    },
    View {
        name: "up",
        row: 96,
        col: 96,
        rows: 16,
        cols: 32,
        right: Vec3::X,
        down: Vec3::Z,
    },
    View {
        name: "down",
        row: 112,
        col: 96,
        rows: 16,
        cols: 32,
        right: Vec3::X,
        down: Vec3::NEG_Z,
    },
];

/// How one view maps world points to its pixels: `pixel = (p · right, p · down) * scale +
/// offset` (column, row within the slot; pixel centres at .5).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projection {
    pub scale: f32,
    pub offset: Vec2,
}

impl Projection {
    pub fn project(&self, view: &View, p: Vec3) -> Vec2 {
        Vec2::new(p.dot(view.right), p.dot(view.down)) * self.scale + self.offset
    }
}

/// The table: for every foreground pixel, its triangle and barycentric weights.
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceTable {
    /// Packed pixel index (row * 128 + column) of each foreground pixel, ascending.
    pub pixels: Vec<u32>,
    pub triangles: Vec<u32>,
    pub barycentrics: Vec<[f32; 3]>,
    /// Each view's projection, in [`VIEWS`] order.
    pub projections: Vec<Projection>,
}

/// Margin left around the reference in each view (share of the slot).
const MARGIN: f32 = 0.04;

impl SurfaceTable {
    /// Draws `positions`/`indices` (the reference mesh) from the six views.
    pub fn build(positions: &[Vec3], indices: &[u32]) -> Self {
        let mut best: Vec<Option<(f32, u32, [f32; 3])>> = vec![None; MAP_SIZE * MAP_SIZE];
        let mut projections = Vec::new();
        for view in &VIEWS {
            let projection = fit(view, positions);
            projections.push(projection);
            for (t, tri) in indices.chunks_exact(3).enumerate() {
                let corners = [tri[0], tri[1], tri[2]].map(|i| positions[i as usize]);
                rasterise(view, &projection, corners, t as u32, &mut best);
            }
        }
        let mut table = Self {
            pixels: Vec::new(),
            triangles: Vec::new(),
            barycentrics: Vec::new(),
            projections,
        };
        for (pixel, hit) in best.into_iter().enumerate() {
            if let Some((_, triangle, bary)) = hit {
                table.pixels.push(pixel as u32);
                table.triangles.push(triangle);
                table.barycentrics.push(bary);
            }
        }
        table
    }

    pub fn len(&self) -> usize {
        self.pixels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    /// The surface point of every foreground pixel for a posed frame: `positions` are
    /// the posed vertices of the reference mesh, `indices` its triangles.
    pub fn gather(&self, positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
        self.triangles
            .iter()
            .zip(&self.barycentrics)
            .map(|(&t, b)| {
                let i = 3 * t as usize;
                positions[indices[i] as usize] * b[0]
                    + positions[indices[i + 1] as usize] * b[1]
                    + positions[indices[i + 2] as usize] * b[2]
            })
            .collect()
    }

    /// The share of each triangle's area that some view sees: sample points on the
    /// triangle count as seen where a view's pixel shows a surface point within one pixel
    /// footprint of them (the map's resolution).
    pub fn coverage(&self, positions: &[Vec3], indices: &[u32]) -> Vec<f32> {
        let mut shown = vec![None; MAP_SIZE * MAP_SIZE];
        for (&pixel, p) in self.pixels.iter().zip(self.gather(positions, indices)) {
            shown[pixel as usize] = Some(p);
        }
        let seen = |p: Vec3| {
            VIEWS
                .iter()
                .zip(&self.projections)
                .any(|(view, projection)| {
                    let q = projection.project(view, p);
                    if q.x < 0.0 || q.y < 0.0 || q.x >= view.cols as f32 || q.y >= view.rows as f32
                    {
                        return false;
                    }
                    let pixel = (view.row + q.y as usize) * MAP_SIZE + view.col + q.x as usize;
                    shown[pixel].is_some_and(|s: Vec3| s.distance(p) <= 1.5 / projection.scale)
                })
        };
        const STEPS: usize = 4;
        indices
            .chunks_exact(3)
            .map(|tri| {
                let [a, b, c] = [tri[0], tri[1], tri[2]].map(|i| positions[i as usize]);
                let mut hits = 0;
                let mut total = 0;
                for i in 0..STEPS {
                    for j in 0..STEPS - i {
                        let (u, v) = (
                            (i as f32 + 1.0 / 3.0) / STEPS as f32,
                            (j as f32 + 1.0 / 3.0) / STEPS as f32,
                        );
                        total += 1;
                        hits += usize::from(seen(a + (b - a) * u + (c - a) * v));
                    }
                }
                hits as f32 / total as f32
            })
            .collect()
    }

    /// Which view a packed pixel belongs to.
    pub fn view_of(pixel: u32) -> usize {
        let (row, col) = (pixel as usize / MAP_SIZE, pixel as usize % MAP_SIZE);
        VIEWS
            .iter()
            .position(|v| {
                (v.row..v.row + v.rows).contains(&row) && (v.col..v.col + v.cols).contains(&col)
            })
            .expect("every pixel of the map is in a view")
    }
}

/// The largest scale at which the mesh fits the view's slot (less a margin), centred.
fn fit(view: &View, positions: &[Vec3]) -> Projection {
    let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
    for p in positions {
        let q = Vec2::new(p.dot(view.right), p.dot(view.down));
        lo = lo.min(q);
        hi = hi.max(q);
    }
    let extent = (hi - lo).max(Vec2::splat(1e-6));
    let usable = Vec2::new(view.cols as f32, view.rows as f32) * (1.0 - 2.0 * MARGIN);
    let scale = (usable / extent).min_element();
    let centre = (lo + hi) * 0.5;
    let slot_centre = Vec2::new(view.cols as f32, view.rows as f32) * 0.5;
    Projection {
        scale,
        offset: slot_centre - centre * scale,
    }
}

/// Draws one triangle into the view's slot, keeping the nearest surface per pixel.
fn rasterise(
    view: &View,
    projection: &Projection,
    corners: [Vec3; 3],
    triangle: u32,
    best: &mut [Option<(f32, u32, [f32; 3])>],
) {
    let [a, b, c] = corners.map(|p| projection.project(view, p));
    let depth = corners.map(|p| p.dot(view.toward()));
    let area = (b - a).perp_dot(c - a);
    if area.abs() < 1e-12 {
        return;
    }
    let lo = a.min(b).min(c).floor().max(Vec2::ZERO);
    let hi = a
        .max(b)
        .max(c)
        .ceil()
        .min(Vec2::new(view.cols as f32, view.rows as f32));
    for y in lo.y as usize..hi.y as usize {
        for x in lo.x as usize..hi.x as usize {
            let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let w0 = (b - p).perp_dot(c - p) / area;
            let w1 = (c - p).perp_dot(a - p) / area;
            let w2 = 1.0 - w0 - w1;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            let z = w0 * depth[0] + w1 * depth[1] + w2 * depth[2];
            let pixel = (view.row + y) * MAP_SIZE + view.col + x;
            if best[pixel].is_none_or(|(nearest, _, _)| z > nearest) {
                best[pixel] = Some((z, triangle, [w0, w1, w2]));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_views_tile_the_map_exactly() {
        let mut owner = vec![0u8; MAP_SIZE * MAP_SIZE];
        for v in &VIEWS {
            for r in v.row..v.row + v.rows {
                for c in v.col..v.col + v.cols {
                    owner[r * MAP_SIZE + c] += 1;
                }
            }
            assert!((v.right.dot(v.down)).abs() < 1e-6 && (v.toward().length() - 1.0).abs() < 1e-6);
        }
        assert!(
            owner.iter().all(|&n| n == 1),
            "every pixel in exactly one view"
        );
    }

    #[test]
    fn front_sees_plus_z_and_back_sees_minus_z() {
        assert_eq!(VIEWS[1].toward(), Vec3::Z);
        assert_eq!(VIEWS[0].toward(), Vec3::NEG_Z);
        assert_eq!(VIEWS[2].toward(), Vec3::NEG_X, "the character's right side");
        assert_eq!(VIEWS[3].toward(), Vec3::X);
        assert_eq!(VIEWS[4].toward(), Vec3::Y);
        assert_eq!(VIEWS[5].toward(), Vec3::NEG_Y);
    }

    #[test]
    fn a_cube_fills_each_view_with_its_facing_side() {
        let mesh = crate::mesh::Mesh::cuboid(Vec3::splat(-0.5), Vec3::splat(0.5), Vec3::ONE);
        let table = SurfaceTable::build(&mesh.positions, &mesh.indices);
        let points = table.gather(&mesh.positions, &mesh.indices);
        for (&pixel, p) in table.pixels.iter().zip(&points) {
            let view = &VIEWS[SurfaceTable::view_of(pixel)];
            // Every pixel shows the face of the cube that points at its view.
            assert!(
                (p.dot(view.toward()) - 0.5).abs() < 1e-5,
                "{} pixel {pixel}: {p}",
                view.name
            );
        }
    }
}
