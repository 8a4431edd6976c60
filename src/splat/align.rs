//! World alignment (docs/architecture.md, Appearance): the least-squares similarity —
//! rotation, uniform scale, translation — that maps one point set onto another (Horn's
//! closed form with unit quaternions: the rotation is the top eigenvector of a symmetric
//! 4×4 matrix built from the cross-covariance, found by Jacobi rotations; no reflection
//! can come out).

use glam::{DMat3, DQuat, DVec3, Quat, Vec3};

/// `p ↦ scale · rotation · p + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    pub rotation: Quat,
    pub scale: f32,
    pub translation: Vec3,
}

impl Similarity {
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.scale * (self.rotation * p) + self.translation
    }
}

/// The similarity minimising Σ |s R from_i + t - to_i|²; `None` for fewer than three
/// points or a degenerate (collinear) `from`.
pub fn fit(from: &[Vec3], to: &[Vec3]) -> Option<Similarity> {
    assert_eq!(from.len(), to.len(), "point sets of different sizes");
    if from.len() < 3 {
        return None;
    }
    let n = from.len() as f64;
    let mean = |ps: &[Vec3]| ps.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / n;
    let (mx, my) = (mean(from), mean(to));
    // Cross-covariance M = Σ (x - x̄)(y - ȳ)ᵀ and the spread of `from`.
    let mut m = DMat3::ZERO;
    let mut spread = 0.0;
    for (x, y) in from.iter().zip(to) {
        let (dx, dy) = (x.as_dvec3() - mx, y.as_dvec3() - my);
        m += DMat3::from_cols(dx * dy.x, dx * dy.y, dx * dy.z);
        spread += dx.length_squared();
    }
    if spread < 1e-12 {
        return None;
    }
    // m.col(j)[i] = Σ dx_i dy_j = S_ij.
    let s = |i: usize, j: usize| m.col(j)[i];
    let k = [
        [
            s(0, 0) + s(1, 1) + s(2, 2),
            s(1, 2) - s(2, 1),
            s(2, 0) - s(0, 2),
            s(0, 1) - s(1, 0),
        ],
        [
            s(1, 2) - s(2, 1),
            s(0, 0) - s(1, 1) - s(2, 2),
            s(0, 1) + s(1, 0),
            s(2, 0) + s(0, 2),
        ],
        [
            s(2, 0) - s(0, 2),
            s(0, 1) + s(1, 0),
            -s(0, 0) + s(1, 1) - s(2, 2),
            s(1, 2) + s(2, 1),
        ],
        [
            s(0, 1) - s(1, 0),
            s(2, 0) + s(0, 2),
            s(1, 2) + s(2, 1),
            -s(0, 0) - s(1, 1) + s(2, 2),
        ],
    ];
    let (values, vectors) = symmetric_eigen4(k);
    let top = (0..4).max_by(|&a, &b| values[a].total_cmp(&values[b]))?;
    let q = vectors[top];
    let rotation = DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize();
    let rotated_dot: f64 = from
        .iter()
        .zip(to)
        .map(|(x, y)| (y.as_dvec3() - my).dot(rotation * (x.as_dvec3() - mx)))
        .sum();
    let scale = rotated_dot / spread;
    let translation = my - scale * (rotation * mx);
    Some(Similarity {
        rotation: rotation.as_quat(),
        scale: scale as f32,
        translation: translation.as_vec3(),
    })
}

/// Eigenvalues and eigenvectors (as rows) of a symmetric 4×4 matrix by cyclic Jacobi
/// rotations.
fn symmetric_eigen4(mut a: [[f64; 4]; 4]) -> ([f64; 4], [[f64; 4]; 4]) {
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for _ in 0..64 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i][j] * a[i][j])
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if a[p][q].abs() < 1e-300 {
                    continue;
                }
                // The rotation that zeroes a[p][q] (Numerical Recipes' jacobi).
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = if theta == 0.0 {
                    1.0
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                let rotate = |row: &mut [f64; 4]| {
                    let (x, y) = (row[p], row[q]);
                    row[p] = c * x - s * y;
                    row[q] = s * x + c * y;
                };
                // A ← Jᵀ A J: rotate the columns p, q of every row, then the rows p, q.
                a.iter_mut().for_each(rotate);
                let (rp, rq) = (a[p], a[q]);
                for k in 0..4 {
                    a[p][k] = c * rp[k] - s * rq[k];
                    a[q][k] = s * rp[k] + c * rq[k];
                }
                v.iter_mut().for_each(rotate);
            }
        }
    }
    let values = [a[0][0], a[1][1], a[2][2], a[3][3]];
    // Columns of v are the eigenvectors; return them as rows.
    let mut vectors = [[0.0; 4]; 4];
    for (i, vector) in vectors.iter_mut().enumerate() {
        for (k, value) in vector.iter_mut().enumerate() {
            *value = v[k][i];
        }
    }
    (values, vectors)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fixed irregular cloud (not symmetric, so the rotation is unique).
    fn cloud() -> Vec<Vec3> {
        (0..40)
            .map(|i| {
                let f = i as f32;
                Vec3::new(
                    (f * 0.37).sin() * 0.8,
                    f * 0.05 - 1.0,
                    (f * 0.91).cos() * 0.3 + 0.1 * f.sqrt(),
                )
            })
            .collect()
    }

    #[test]
    fn known_similarities_are_recovered_including_large_rotations() {
        let from = cloud();
        let cases = [
            (Quat::IDENTITY, 1.0, Vec3::ZERO),
            (Quat::from_rotation_y(0.3), 2.5, Vec3::new(1.0, -2.0, 0.5)),
            (
                Quat::from_axis_angle(Vec3::new(1.0, 2.0, -0.5).normalize(), 2.9),
                0.35,
                Vec3::new(-4.0, 0.0, 7.0),
            ),
            (
                Quat::from_rotation_x(std::f32::consts::PI),
                1.7,
                Vec3::new(0.0, 3.0, 0.0),
            ),
            (
                Quat::from_rotation_z(-std::f32::consts::FRAC_PI_2),
                1.0,
                Vec3::new(0.2, 0.2, 0.2),
            ),
        ];
        for (rotation, scale, translation) in cases {
            let truth = Similarity {
                rotation,
                scale,
                translation,
            };
            let to: Vec<Vec3> = from.iter().map(|&p| truth.apply(p)).collect();
            let got = fit(&from, &to).unwrap();
            assert!(
                (got.scale - scale).abs() < 1e-4,
                "scale {} vs {scale}",
                got.scale
            );
            assert!(
                got.rotation.dot(rotation).abs() > 1.0 - 1e-6,
                "rotation {:?} vs {rotation:?}",
                got.rotation
            );
            assert!(
                got.translation.distance(translation) < 1e-4,
                "{} vs {translation}",
                got.translation
            );
            for (p, q) in from.iter().zip(&to) {
                assert!(got.apply(*p).distance(*q) < 1e-4);
            }
        }
    }

    #[test]
    fn the_fit_is_least_squares_under_noise_and_refuses_degenerate_input() {
        let from = cloud();
        let truth = Similarity {
            rotation: Quat::from_rotation_y(1.2),
            scale: 1.3,
            translation: Vec3::new(0.5, 0.0, -1.0),
        };
        // Zero-mean, fixed perturbations: the fit stays close to the truth and fits the
        // noisy points at least as well as the truth does.
        let to: Vec<Vec3> = from
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                truth.apply(p)
                    + 0.01
                        * Vec3::new(
                            (i as f32 * 1.7).sin(),
                            (i as f32 * 2.3).cos(),
                            (i as f32 * 0.9).sin(),
                        )
            })
            .collect();
        let got = fit(&from, &to).unwrap();
        let cost = |s: &Similarity| {
            from.iter()
                .zip(&to)
                .map(|(p, q)| s.apply(*p).distance_squared(*q))
                .sum::<f32>()
        };
        assert!(cost(&got) <= cost(&truth) + 1e-6);
        assert!((got.scale - 1.3).abs() < 0.01 && got.rotation.dot(truth.rotation).abs() > 0.9999);
        let line: Vec<Vec3> = (0..5).map(|i| Vec3::X * i as f32).collect();
        assert!(fit(&line[..2], &line[..2]).is_none(), "two points");
        let same = vec![Vec3::ONE; 5];
        assert!(fit(&same, &line).is_none(), "no spread");
    }
}
