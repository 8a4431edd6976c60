//! Which rigid parts of a character hang (a cape parented to the chest): inferred from the
//! rest pose for characters without a description, as plain data that the description
//! turns into loose parts with spring chains and colliders.

use glam::{Mat4, Vec3};

use super::Character;

/// Below its parent joint by more than this share of the character's height, a rigid part
/// hangs (a cape does; a helmet or a shoulder pad does not).
const HANGS: f32 = 0.25;

/// Across over along its widest direction, in standard deviations, under which a part is
/// a sheet (a cape: 0.2) rather than a ring around its axis (a skirt: about 1).
const FLAT: f32 = 0.5;

/// A rigid mesh that hangs: its mesh (and node) name and whether it is flat.
#[derive(Clone, Debug, PartialEq)]
pub struct Hanging {
    pub mesh: String,
    pub flat: bool,
}

/// The meshes that are not skinned but hang from a skin joint they are parented to
/// (KayKit's capes are such meshes, following their joint rigidly).
pub fn hanging_parts(character: &Character) -> Vec<Hanging> {
    let rig = &character.rig;
    let rest = rig.world(&rig.rest_pose(), Mat4::IDENTITY);
    let rest_mesh = character.rest_mesh();
    let height = rest_mesh.height();
    let skinned = &character.skinned;
    let is_joint = |n: usize| rig.bones.iter().any(|b| b.node == n);
    let mut names: Vec<&str> = skinned.parts.iter().map(|p| p.mesh.as_str()).collect();
    names.dedup();
    let mut parts = Vec::new();
    for name in names {
        let vertices = skinned.select(Some(name), &[]);
        let bone_node = |v: usize| rig.bones[skinned.joints[v][0] as usize].node;
        // Rigid: every vertex wholly on the bone of the mesh's own node.
        let Some(node) = vertices.first().map(|&v| bone_node(v)) else {
            continue;
        };
        let rigid = rig.nodes[node].name == name
            && vertices
                .iter()
                .all(|&v| skinned.weights[v][0] == 1.0 && bone_node(v) == node);
        let Some(parent) = rig.nodes[node].parent.filter(|&p| rigid && is_joint(p)) else {
            continue;
        };
        let points: Vec<Vec3> = vertices.iter().map(|&v| rest_mesh.positions[v]).collect();
        let bottom = points.iter().map(|p| p.y).fold(f32::MAX, f32::min);
        if rest[parent].w_axis.y - bottom < HANGS * height {
            continue;
        }
        let (_, _, along, across) = horizontal_spread(&points);
        parts.push(Hanging {
            mesh: name.to_string(),
            flat: across < FLAT * along,
        });
    }
    parts
}

/// The horizontal centre of `points` and their widest horizontal direction (unit, in xz),
/// with the standard deviations along it and across it.
pub fn horizontal_spread(points: &[Vec3]) -> (Vec3, Vec3, f32, f32) {
    let n = points.len().max(1) as f32;
    let centre = points
        .iter()
        .map(|p| Vec3::new(p.x, 0.0, p.z))
        .sum::<Vec3>()
        / n;
    let (mut xx, mut xz, mut zz) = (0.0f32, 0.0f32, 0.0f32);
    for p in points {
        let (x, z) = (p.x - centre.x, p.z - centre.z);
        xx += x * x / n;
        xz += x * z / n;
        zz += z * z / n;
    }
    // The larger eigenvalue of [[xx, xz], [xz, zz]] and its eigenvector.
    let half_trace = (xx + zz) / 2.0;
    let root = (((xx - zz) / 2.0).powi(2) + xz * xz).sqrt();
    let (major, minor) = (half_trace + root, (half_trace - root).max(0.0));
    let axis = if xz.abs() > 1e-12 {
        Vec3::new(xz, 0.0, major - xx).normalize()
    } else if xx >= zz {
        Vec3::X
    } else {
        Vec3::Z
    };
    (centre, axis, major.sqrt(), minor.sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn horizontal_spread_finds_the_widest_direction() {
        // Points on a line at 45° between +x and +z, 1 m either side of (2, *, 3), with
        // heights that must not count: the spread along is sqrt(mean(t²)), across 0.
        let t = [-1.0f32, -0.5, 0.0, 0.5, 1.0];
        let points: Vec<Vec3> = t
            .iter()
            .enumerate()
            .map(|(i, &t)| Vec3::new(2.0 + t / 2f32.sqrt(), i as f32, 3.0 + t / 2f32.sqrt()))
            .collect();
        let (centre, axis, along, across) = horizontal_spread(&points);
        assert!(
            centre.abs_diff_eq(Vec3::new(2.0, 0.0, 3.0), 1e-5),
            "{centre}"
        );
        let diagonal = Vec3::new(1.0, 0.0, 1.0).normalize();
        assert!(axis.dot(diagonal).abs() > 1.0 - 1e-5, "{axis}");
        let expected = (t.iter().map(|t| t * t).sum::<f32>() / 5.0).sqrt();
        assert!(
            (along - expected).abs() < 1e-5 && across < 1e-3,
            "{along} {across}"
        );
        // Along an axis: the axis itself.
        let flat = [Vec3::new(-1.0, 0.0, 0.0), Vec3::new(1.0, 5.0, 0.0)];
        assert_eq!(horizontal_spread(&flat).1, Vec3::X);
    }
}
