//! The teacher's reference for position maps: the character's rest pose (spring chains
//! included) drawn into the six-view surface table, its normalisation scale and the
//! waist pixels whose mean is the root, plus the coverage report.

use glam::Vec3;

use super::character::{CharacterError, fail};
use super::teacher::Teacher;
use crate::posmap::table::VIEWS;
use crate::posmap::{GroupNorm, SurfaceTable};

pub struct Reference {
    pub table: SurfaceTable,
    pub norm: GroupNorm,
    /// Indices (into the table's foreground pixels) of the waist pixels.
    pub waist: Vec<u32>,
}

/// What the six views see of the reference.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CoverageReport {
    pub foreground_pixels: usize,
    pub foreground_share: f32,
    /// Foreground pixels per view, in view order.
    pub view_pixels: Vec<(String, usize)>,
    /// Share of the surface area seen by at least one view.
    pub surface_seen: f32,
    /// Per mesh/material part: (name, area share seen, the part's share of all area).
    pub parts: Vec<(String, f32, f32)>,
    /// The regions a viewer looks at most (issue #17): what the map gives them.
    pub regions: Vec<RegionCoverage>,
}

/// What the position map gives one region of the body.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RegionCoverage {
    /// `face`: the head bone's triangles facing forward (normal within 60° of +Z);
    /// `hands`: the triangles of the wrists and everything below them (fingers).
    pub name: String,
    /// Foreground pixels of the map showing the region.
    pub pixels: usize,
    /// The region's share of the whole surface area.
    pub area_share: f32,
    /// Share of the region's area seen by at least one view.
    pub seen: f32,
    /// Pixels the region would get if the map's pixels were spread over the surface by
    /// area (`foreground_pixels × area_share`): below 1 × this, the layout starves it.
    pub fair_pixels: f32,
}

impl Reference {
    pub fn new(teacher: &Teacher) -> Result<Self, CharacterError> {
        let character = &teacher.character;
        let mesh = character.rest_mesh();
        let (lo, hi) = mesh.bounds().expect("a character has vertices");
        let table = SurfaceTable::build(&mesh.positions, &mesh.indices);
        let waist_bones: Vec<usize> = (0..character.rig.bones.len())
            .filter(|&b| teacher.waist_nodes().contains(&character.rig.bones[b].node))
            .collect();
        let on_waist = |v: u32| waist_bones.contains(&character.skinned.dominant_bone(v as usize));
        let waist: Vec<u32> = (0..table.len() as u32)
            .filter(|&i| {
                let t = 3 * table.triangles[i as usize] as usize;
                mesh.indices[t..t + 3].iter().all(|&v| on_waist(v))
            })
            .collect();
        if waist.is_empty() {
            return Err(fail(
                &character.path,
                "no pixel of the position map shows the waist bones' surface",
            ));
        }
        Ok(Self {
            norm: GroupNorm::for_extent((hi - lo).max_element()),
            table,
            waist,
        })
    }

    pub fn report(&self, teacher: &Teacher) -> CoverageReport {
        let character = &teacher.character;
        let mesh = character.rest_mesh();
        let seen = self.table.coverage(&mesh.positions, &mesh.indices);
        let areas: Vec<f32> = mesh
            .indices
            .chunks_exact(3)
            .map(|t| {
                let [a, b, c] = [t[0], t[1], t[2]].map(|i| mesh.positions[i as usize]);
                (b - a).cross(c - a).length() * 0.5
            })
            .collect();
        let total: f32 = areas.iter().sum();
        // (area, area seen) of the triangles `inside` picks.
        let area_seen = |inside: &dyn Fn(usize) -> bool| {
            (0..areas.len())
                .filter(|&t| inside(t))
                .fold((0.0f32, 0.0f32), |(a, v), t| {
                    (a + areas[t], v + areas[t] * seen[t])
                })
        };
        let skinned = &character.skinned;
        let parts = (0..skinned.parts.len())
            .map(|p| {
                let (area, visible) =
                    area_seen(&|t| skinned.part[mesh.indices[3 * t] as usize] as usize == p);
                let part = &skinned.parts[p];
                (
                    format!("{}/{}", part.mesh, part.material),
                    visible / area.max(1e-12),
                    area / total,
                )
            })
            .collect();
        let mut view_pixels: Vec<(String, usize)> =
            VIEWS.iter().map(|v| (v.name.to_string(), 0)).collect();
        for &pixel in &self.table.pixels {
            view_pixels[SurfaceTable::view_of(pixel)].1 += 1;
        }
        let n = crate::posmap::MAP_SIZE * crate::posmap::MAP_SIZE;
        let regions = body_regions(teacher, &mesh)
            .into_iter()
            .map(|(name, inside)| {
                let (area, visible) = area_seen(&|t| inside[t]);
                let pixels = self
                    .table
                    .triangles
                    .iter()
                    .filter(|&&t| inside[t as usize])
                    .count();
                RegionCoverage {
                    name: name.to_string(),
                    pixels,
                    area_share: area / total,
                    seen: visible / area.max(1e-12),
                    fair_pixels: self.table.len() as f32 * area / total,
                }
            })
            .collect();
        CoverageReport {
            regions,
            foreground_pixels: self.table.len(),
            foreground_share: self.table.len() as f32 / n as f32,
            view_pixels,
            surface_seen: areas.iter().zip(&seen).map(|(a, s)| a * s).sum::<f32>() / total,
            parts,
        }
    }

    /// The foreground points of a posed mesh (world space).
    pub fn gather(&self, positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
        self.table.gather(positions, indices)
    }
}

/// Per triangle of the rest mesh: in the face, in the hands (see [`RegionCoverage`]); a
/// rig without a head or wrist bone (found by the humanoid names) has an empty region.
fn body_regions(teacher: &Teacher, mesh: &crate::mesh::Mesh) -> Vec<(&'static str, Vec<bool>)> {
    use crate::avatar::humanoid::find_all;
    let character = &teacher.character;
    let rig = &character.rig;
    let found = find_all(rig, character.vrm.as_ref(), &["Head", "Wrist.L", "Wrist.R"]);
    // A node is in the hands when a wrist is it or one of its ancestors.
    let under = |node: usize, tops: &[usize]| tops.iter().any(|&top| rig.is_under(node, top));
    let wrists: Vec<usize> = found[1..].iter().flatten().copied().collect();
    let node_of = |v: u32| rig.bones[character.skinned.dominant_bone(v as usize)].node;
    let triangles: Vec<[u32; 3]> = mesh
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    let face = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let facing = (b - a).cross(c - a).normalize_or_zero().z > 0.5;
            facing && found[0].is_some_and(|head| t.iter().all(|&v| node_of(v) == head))
        })
        .collect();
    let hands = triangles
        .iter()
        .map(|t| !wrists.is_empty() && t.iter().all(|&v| under(node_of(v), &wrists)))
        .collect();
    vec![("face", face), ("hands", hands)]
}
