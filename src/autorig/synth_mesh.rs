//! The surface of a synthetic character: the tapered capsules (limbs) it grows around
//! and the open sheets hung on its spring chains, meshed (a smooth union by surface nets;
//! sheets as strips between chains) with ground-truth skin weights.

use glam::Vec3;

use super::skeleton::Skeleton;
use crate::mesh::Mesh;

/// An open sheet hung on spring chains (no volume: it is not part of the grown surface):
/// a ring or strip between neighbouring chains, or a card of `width` along one chain.
/// Its triangles face away from joint `around` (horizontally when `vertical`).
pub(super) struct Sheet {
    pub(super) chains: Vec<Vec<usize>>,
    pub(super) closed: bool,
    pub(super) width: f32,
    pub(super) around: usize,
    pub(super) vertical: bool,
}

/// A tapered capsule the surface grows around, owned by the joint that moves it.
#[derive(Clone, Copy)]
pub(super) struct Limb {
    pub(super) a: Vec3,
    pub(super) b: Vec3,
    pub(super) ra: f32,
    pub(super) rb: f32,
    pub(super) joint: usize,
}

impl Limb {
    /// Signed distance and the position along the limb (0 at a, 1 at b).
    pub(super) fn distance(&self, p: Vec3) -> (f32, f32) {
        let ab = self.b - self.a;
        let t = ((p - self.a).dot(ab) / ab.length_squared().max(1e-12)).clamp(0.0, 1.0);
        let r = self.ra + (self.rb - self.ra) * t;
        (p.distance(self.a + t * ab) - r, t)
    }
}

/// Smooth union of the limbs' distances (polynomial smooth minimum, radius k).
pub(super) fn smooth_min(a: f32, b: f32, k: f32) -> f32 {
    let h = (0.5 + 0.5 * (b - a) / k).clamp(0.0, 1.0);
    b + (a - b) * h - k * h * (1.0 - h)
}

/// Meshes the zero level of `field` sampled on a grid (surface nets: one vertex per cell
/// crossing the surface at the mean of its edge crossings, one quad per crossing edge).
pub(super) fn surface_nets(lo: Vec3, cell: f32, dims: [usize; 3], field: &[f32]) -> Mesh {
    let [nx, ny, nz] = dims;
    let at = |x: usize, y: usize, z: usize| field[x + nx * (y + ny * z)];
    let corner = |x: usize, y: usize, z: usize| lo + Vec3::new(x as f32, y as f32, z as f32) * cell;
    let mut vertex_of = vec![u32::MAX; nx * ny * nz];
    let mut mesh = Mesh::default();
    for z in 0..nz - 1 {
        for y in 0..ny - 1 {
            for x in 0..nx - 1 {
                let mut sum = Vec3::ZERO;
                let mut crossings = 0;
                for (a, b) in CUBE_EDGES {
                    let pa = [x + a[0], y + a[1], z + a[2]];
                    let pb = [x + b[0], y + b[1], z + b[2]];
                    let (fa, fb) = (at(pa[0], pa[1], pa[2]), at(pb[0], pb[1], pb[2]));
                    if (fa < 0.0) != (fb < 0.0) {
                        let t = fa / (fa - fb);
                        sum += corner(pa[0], pa[1], pa[2]).lerp(corner(pb[0], pb[1], pb[2]), t);
                        crossings += 1;
                    }
                }
                if crossings > 0 {
                    vertex_of[x + nx * (y + ny * z)] = mesh.positions.len() as u32;
                    mesh.positions.push(sum / crossings as f32);
                }
            }
        }
    }
    let v = |x: usize, y: usize, z: usize| vertex_of[x + nx * (y + ny * z)];
    for z in 1..nz - 1 {
        for y in 1..ny - 1 {
            for x in 1..nx - 1 {
                let inside = at(x, y, z) < 0.0;
                // Edges from this grid point along +x, +y, +z, and the four cells around each.
                let quads = [
                    (
                        at(x + 1, y, z),
                        [
                            v(x, y - 1, z - 1),
                            v(x, y, z - 1),
                            v(x, y, z),
                            v(x, y - 1, z),
                        ],
                    ),
                    (
                        at(x, y + 1, z),
                        [
                            v(x - 1, y, z - 1),
                            v(x - 1, y, z),
                            v(x, y, z),
                            v(x, y, z - 1),
                        ],
                    ),
                    (
                        at(x, y, z + 1),
                        [
                            v(x - 1, y - 1, z),
                            v(x, y - 1, z),
                            v(x, y, z),
                            v(x - 1, y, z),
                        ],
                    ),
                ];
                for (other, [a, b, c, d]) in quads {
                    if inside == (other < 0.0) || [a, b, c, d].contains(&u32::MAX) {
                        continue;
                    }
                    let quad = if inside { [a, b, c, d] } else { [d, c, b, a] };
                    mesh.indices
                        .extend([quad[0], quad[1], quad[2], quad[0], quad[2], quad[3]]);
                }
            }
        }
    }
    mesh.compute_normals();
    mesh.colors = vec![Vec3::splat(0.7); mesh.positions.len()];
    mesh
}

pub(super) const CUBE_EDGES: [([usize; 3], [usize; 3]); 12] = [
    ([0, 0, 0], [1, 0, 0]),
    ([0, 1, 0], [1, 1, 0]),
    ([0, 0, 1], [1, 0, 1]),
    ([0, 1, 1], [1, 1, 1]),
    ([0, 0, 0], [0, 1, 0]),
    ([1, 0, 0], [1, 1, 0]),
    ([0, 0, 1], [0, 1, 1]),
    ([1, 0, 1], [1, 1, 1]),
    ([0, 0, 0], [0, 0, 1]),
    ([1, 0, 0], [1, 0, 1]),
    ([0, 1, 0], [0, 1, 1]),
    ([1, 1, 0], [1, 1, 1]),
];

/// Ground-truth weights of a surface point: the limb nearest the surface owns it,
/// [`painted`] with the owner's parent (where the limb starts at the owner) or the joint
/// the limb runs into.
pub(super) fn skin_of(p: Vec3, limbs: &[Limb], skeleton: &Skeleton) -> Vec<(usize, f32)> {
    let (limb, t) = limbs
        .iter()
        .map(|l| (l, l.distance(p)))
        .min_by(|a, b| a.1.0.total_cmp(&b.1.0))
        .map(|(l, (_, t))| (l, t))
        .expect("a character has limbs");
    let owner = limb.joint;
    let child = (0..skeleton.len()).find(|&c| {
        skeleton.parents[c] == Some(owner) && skeleton.joints[c].distance(limb.b) < 1e-4
    });
    let parent = skeleton.parents[owner].filter(|_| skeleton.joints[owner].distance(limb.a) < 1e-4);
    painted(owner, t, parent, child)
}

/// The weights of a point at `t` along a bone of `owner` (0 at its start, 1 at its end):
/// all to `owner`, except over the first and last fifth, where it blends linearly (to
/// half at the end) with `previous` (the joint before the bone's start) or `next` (the
/// joint at its end), as artists paint.
pub(super) fn painted(
    owner: usize,
    t: f32,
    previous: Option<usize>,
    next: Option<usize>,
) -> Vec<(usize, f32)> {
    let blend = 0.2;
    match (previous, next) {
        (Some(p), _) if t < blend => {
            let w = 0.5 * (1.0 - t / blend);
            vec![(owner, 1.0 - w), (p, w)]
        }
        (_, Some(c)) if t > 1.0 - blend => {
            let w = 0.5 * (t - (1.0 - blend)) / blend;
            vec![(owner, 1.0 - w), (c, w)]
        }
        _ => vec![(owner, 1.0)],
    }
}

/// A point of a sheet and its weights.
pub(super) type Weighted = (Vec3, Vec<(usize, f32)>);

/// Rows of vertices along a sheet's chains, and columns between two neighbouring chains.
pub(super) const SHEET_ROWS: usize = 9;
pub(super) const SHEET_SPAN: usize = 3;

/// The point at fraction `t` of a chain's length (its joints, then half a bone past the
/// last, as [`Builder::chain`] grows it) and its weights: the joint whose bone it lies on,
/// [`painted`] as [`skin_of`] does.
pub(super) fn along_chain(skeleton: &Skeleton, chain: &[usize], t: f32) -> Weighted {
    let mut line: Vec<Vec3> = chain.iter().map(|&j| skeleton.joints[j]).collect();
    let n = line.len();
    let last = line[n - 1];
    let before = if n > 1 {
        line[n - 2]
    } else {
        skeleton.parents[chain[0]].map_or(last + Vec3::Y, |p| skeleton.joints[p])
    };
    line.push(last + 0.5 * (last - before));
    let lengths: Vec<f32> = line.windows(2).map(|w| w[0].distance(w[1])).collect();
    let mut target = t.clamp(0.0, 1.0) * lengths.iter().sum::<f32>();
    let mut k = 0;
    while k + 1 < lengths.len() && target > lengths[k] {
        target -= lengths[k];
        k += 1;
    }
    let f = (target / lengths[k].max(1e-12)).clamp(0.0, 1.0);
    let at = line[k].lerp(line[k + 1], f);
    let owner = chain[k];
    let previous = if k == 0 {
        skeleton.parents[owner]
    } else {
        Some(chain[k - 1])
    };
    (at, painted(owner, f, previous, chain.get(k + 1).copied()))
}

/// Sums weights by joint.
pub(super) fn mix(parts: &[(f32, &[(usize, f32)])]) -> Vec<(usize, f32)> {
    let mut out: Vec<(usize, f32)> = Vec::new();
    for &(scale, weights) in parts {
        for &(j, w) in weights {
            match out.iter_mut().find(|(k, _)| *k == j) {
                Some(slot) => slot.1 += scale * w,
                None => out.push((j, scale * w)),
            }
        }
    }
    out.retain(|&(_, w)| w > 0.0);
    out
}

/// A sheet's mesh on the posed skeleton and each vertex's weights: a grid of
/// [`SHEET_ROWS`] rows by [`SHEET_SPAN`] columns between neighbouring chains (a card: two
/// columns, `width` apart, across its one chain), one layer of triangles facing away
/// from the sheet's `around` joint.
pub(super) fn sheet_mesh(sheet: &Sheet, skeleton: &Skeleton) -> (Mesh, Vec<Vec<(usize, f32)>>) {
    let chains = &sheet.chains;
    let mut columns: Vec<Vec<Weighted>> = Vec::new();
    let rows = |c: usize| -> Vec<Weighted> {
        (0..SHEET_ROWS)
            .map(|r| along_chain(skeleton, &chains[c], r as f32 / (SHEET_ROWS - 1) as f32))
            .collect()
    };
    let center = skeleton.joints[sheet.around];
    if chains.len() == 1 {
        let line = rows(0);
        for side in [-0.5f32, 0.5] {
            let column = (0..SHEET_ROWS)
                .map(|r| {
                    let (at, w) = &line[r];
                    let tangent = line[(r + 1).min(SHEET_ROWS - 1)].0 - line[r.saturating_sub(1)].0;
                    let across = tangent.cross(*at - center).normalize_or(Vec3::X);
                    (*at + across * side * sheet.width, w.clone())
                })
                .collect();
            columns.push(column);
        }
    } else {
        let lines: Vec<_> = (0..chains.len()).map(rows).collect();
        let spans = if sheet.closed {
            chains.len()
        } else {
            chains.len() - 1
        };
        for c in 0..spans {
            let (a, b) = (&lines[c], &lines[(c + 1) % chains.len()]);
            for q in 0..SHEET_SPAN {
                let u = q as f32 / SHEET_SPAN as f32;
                columns.push(
                    (0..SHEET_ROWS)
                        .map(|r| {
                            let at = a[r].0.lerp(b[r].0, u);
                            (at, mix(&[(1.0 - u, &a[r].1), (u, &b[r].1)]))
                        })
                        .collect(),
                );
            }
        }
        if !sheet.closed {
            columns.push(lines[chains.len() - 1].clone());
        }
    }
    let mut mesh = Mesh::default();
    let mut skin = Vec::new();
    for column in &columns {
        for (at, w) in column {
            mesh.positions.push(*at);
            skin.push(w.clone());
        }
    }
    let index = |c: usize, r: usize| (c % columns.len() * SHEET_ROWS + r) as u32;
    let quads = if sheet.closed {
        columns.len()
    } else {
        columns.len() - 1
    };
    for c in 0..quads {
        for r in 0..SHEET_ROWS - 1 {
            let quad = [
                index(c, r),
                index(c + 1, r),
                index(c + 1, r + 1),
                index(c, r + 1),
            ];
            for tri in [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]] {
                let [a, b, d] = tri.map(|i| mesh.positions[i as usize]);
                let mut away = (a + b + d) / 3.0 - center;
                if sheet.vertical {
                    away.y = 0.0;
                }
                let tri = if (b - a).cross(d - a).dot(away) < 0.0 {
                    [tri[0], tri[2], tri[1]]
                } else {
                    tri
                };
                mesh.indices.extend(tri);
            }
        }
    }
    mesh.colors = vec![Vec3::splat(0.7); mesh.positions.len()];
    (mesh, skin)
}
