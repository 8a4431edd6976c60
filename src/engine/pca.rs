//! PCA cleaning of a drawn frame (docs/architecture.md, The live loop): the frame,
//! centred on its own root, is replaced by its closest point in the bundle's PCA
//! subspace; never fed back.

use glam::Vec3;

/// `points` normalised with their root at 0.5 + `shift`: projected with `mean` [3N] and
/// orthonormal `basis` rows [K, 3N] after removing `shift`, which is then put back.
pub fn project_points(points: &[Vec3], shift: Vec3, mean: &[f32], basis: &[f32]) -> Vec<Vec3> {
    let d = 3 * points.len();
    assert_eq!(mean.len(), d, "PCA mean for {} points", points.len());
    let centred: Vec<f32> = points
        .iter()
        .flat_map(|&p| (p - shift).to_array())
        .zip(mean)
        .map(|(v, m)| v - m)
        .collect();
    let mut out = mean.to_vec();
    for row in basis.chunks_exact(d) {
        let c: f32 = row.iter().zip(&centred).map(|(a, b)| a * b).sum();
        for (o, r) in out.iter_mut().zip(row) {
            *o += c * r;
        }
    }
    out.chunks_exact(3)
        .map(|v| Vec3::new(v[0], v[1], v[2]) + shift)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_keeps_the_subspace_and_removes_the_rest() {
        // Two points (D = 6); the subspace is spanned by e0 and (e1 + e2)/√2 around a
        // mean m. A point m + 2 e0 + 3 e5 + (e1 - e2) projects to m + 2 e0.
        let mean = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6];
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let basis = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, h, h, 0.0, 0.0, 0.0];
        let x = [0.1 + 2.0, 0.2 + 1.0, 0.3 - 1.0, 0.4, 0.5, 0.6 + 3.0];
        let shift = Vec3::new(0.05, -0.02, 0.01);
        let points = [
            Vec3::new(x[0], x[1], x[2]) + shift,
            Vec3::new(x[3], x[4], x[5]) + shift,
        ];
        let got = project_points(&points, shift, &mean, &basis);
        let want = [
            Vec3::new(2.1, 0.2, 0.3) + shift,
            Vec3::new(0.4, 0.5, 0.6) + shift,
        ];
        for (g, w) in got.iter().zip(want) {
            assert!(g.distance(w) < 1e-6, "{g} vs {w}");
        }
    }
}
