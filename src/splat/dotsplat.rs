//! The antimatter15 `.splat` format (read and write): no header, 32 bytes per splat, all
//! little-endian — position 3 × f32, linear scale 3 × f32 (exp of the log scale), colour
//! 4 × u8 RGBA (rgb = 0.5 + SH_C0 · f_dc, a = the opacity after the sigmoid, each × 255,
//! clamped and truncated), rotation 4 × u8 w x y z (each q/|q| · 128 + 128, clamped,
//! truncated; read back as (b − 128)/128). The writer orders splats by size × opacity
//! (product of the scales times the opacity), largest first, as the format's viewer
//! expects. Layout followed: antimatter15/splat `convert.py` (writer) and `main.js`
//! (reader); playcanvas/splat-transform `src/lib/readers/read-splat.ts` agrees.

use std::path::Path;

use glam::{Quat, Vec3};

use super::ply::{MIN_SCALE, PlyError, SH_C0, Splat};

/// Bytes per splat.
pub const RECORD: usize = 32;

/// A value in 0..=1 (or -1..=1 mapped by the caller) as the format's byte: × 255, clamped
/// to 0..=255 and truncated, as `convert.py`'s `astype(np.uint8)` does.
fn byte(v: f32) -> u8 {
    v.clamp(0.0, 255.0) as u8
}

/// The record of one splat.
pub fn record(s: &Splat) -> [u8; RECORD] {
    let mut out = [0u8; RECORD];
    let scale = s.scale.max(Vec3::splat(MIN_SCALE));
    for (i, v) in s
        .position
        .to_array()
        .into_iter()
        .chain(scale.to_array())
        .enumerate()
    {
        out[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
    }
    let color = s.color() * 255.0;
    out[24] = byte(color.x);
    out[25] = byte(color.y);
    out[26] = byte(color.z);
    out[27] = byte(s.opacity * 255.0);
    let q = s.rotation.normalize();
    for (i, v) in [q.w, q.x, q.y, q.z].into_iter().enumerate() {
        out[28 + i] = byte(v * 128.0 + 128.0);
    }
    out
}

/// The file's bytes for `splats`, largest size × opacity first.
pub fn encode(splats: &[Splat]) -> Vec<u8> {
    let weight = |s: &Splat| -(s.scale.x * s.scale.y * s.scale.z * s.opacity);
    let mut order: Vec<&Splat> = splats.iter().collect();
    order.sort_by(|a, b| weight(a).total_cmp(&weight(b)));
    order.into_iter().flat_map(record).collect()
}

pub fn write(path: &Path, splats: &[Splat]) -> Result<(), crate::files::WriteError> {
    crate::files::write_atomic(path, &encode(splats))
}

pub fn read(path: &Path) -> Result<Vec<Splat>, PlyError> {
    super::ply::read_with(path, decode)
}

/// Splats from a `.splat` file's bytes; the error says what is wrong.
pub fn decode(bytes: &[u8]) -> Result<Vec<Splat>, String> {
    if bytes.is_empty() {
        return Err("the .splat file is empty (no splats)".into());
    }
    if !bytes.len().is_multiple_of(RECORD) {
        return Err(format!(
            "the .splat file is truncated: {} bytes is not a whole number of {RECORD}-byte splats",
            bytes.len()
        ));
    }
    bytes
        .chunks_exact(RECORD)
        .enumerate()
        .map(|(i, r)| {
            let f = |k: usize| f32::from_le_bytes(r[4 * k..4 * k + 4].try_into().expect("4"));
            let position = Vec3::new(f(0), f(1), f(2));
            let scale = Vec3::new(f(3), f(4), f(5));
            if !position.is_finite() {
                return Err(format!(
                    "splat {i}: the position is not finite ({position})"
                ));
            }
            if !scale.is_finite() || scale.min_element() < 0.0 {
                return Err(format!(
                    "splat {i}: a scale is negative or not finite ({scale})"
                ));
            }
            let c = |k: usize| r[24 + k] as f32 / 255.0;
            let q = |k: usize| (r[28 + k] as f32 - 128.0) / 128.0;
            let rotation = Quat::from_xyzw(q(1), q(2), q(3), q(0));
            if rotation.length_squared() == 0.0 {
                return Err(format!("splat {i}: the rotation quaternion is zero"));
            }
            Ok(Splat {
                position,
                f_dc: (Vec3::new(c(0), c(1), c(2)) - Vec3::splat(0.5)) / SH_C0,
                opacity: c(3),
                scale,
                rotation: rotation.normalize(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn splats() -> Vec<Splat> {
        (0..40)
            .map(|i| {
                let f = i as f32;
                Splat {
                    position: Vec3::new(f * 0.1, -f, 0.5 * f),
                    f_dc: Vec3::new(0.05 * f - 1.0, -0.2, 0.3),
                    opacity: 0.02 + 0.024 * f,
                    scale: Vec3::new(0.01, 0.02 + 0.001 * (f * 7.0 % 13.0), 0.005),
                    rotation: Quat::from_euler(glam::EulerRot::YXZ, 0.3 * f, 0.2 * f, -0.1 * f),
                }
            })
            .collect()
    }

    #[test]
    fn one_record_by_hand() {
        // Colour 0.5 + SH_C0·f_dc: f_dc = 0 → 0.5·255 = 127.5 → 127; f_dc = 1/SH_C0 → 1.5
        // → clamped 255; f_dc = −2/SH_C0 → −1.5 → 0. Opacity 0.25 → 63.75 → 63. A quarter
        // turn about X: (w, x) = (√½, √½) → √½·128 + 128 = 218.5 → 218, y = z = 0 → 128.
        let s = Splat {
            position: Vec3::new(1.0, -2.0, 0.5),
            f_dc: Vec3::new(0.0, 1.0 / SH_C0, -2.0 / SH_C0),
            opacity: 0.25,
            scale: Vec3::new(0.5, 2.0, 0.0),
            rotation: Quat::from_rotation_x(std::f32::consts::FRAC_PI_2),
        };
        let r = record(&s);
        assert_eq!(&r[0..4], &1.0f32.to_le_bytes());
        assert_eq!(&r[4..8], &(-2.0f32).to_le_bytes());
        assert_eq!(&r[12..16], &0.5f32.to_le_bytes());
        assert_eq!(
            &r[20..24],
            &MIN_SCALE.to_le_bytes(),
            "a zero scale is written tiny"
        );
        assert_eq!(r[24..28], [127, 255, 0, 63]);
        assert_eq!(r[28..32], [218, 218, 128, 128]);
        // Read back: (218 − 128)/128 = 0.703 for w and x: the same quarter turn.
        let back = decode(&r).unwrap()[0];
        assert!(
            back.rotation.dot(s.rotation) > 1.0 - 1e-6,
            "{}",
            back.rotation
        );
        assert!((back.opacity - 63.0 / 255.0).abs() < 1e-7);
        assert!((back.color().x - 127.0 / 255.0).abs() < 1e-6);
    }

    /// Positions and scales are f32 as written. Colour and opacity are truncated to 1/255
    /// (f_dc off by < 1/(255·SH_C0) ≈ 0.0139); each rotation component by < 1/128, so
    /// |Δq| < 2/128 and |q·q'| > cos(1/64) ≈ 1 − 1.3e-4 (allowed: 2e-4).
    #[test]
    fn splats_survive_a_round_trip_largest_first() {
        let want = splats();
        let got = decode(&encode(&want)).unwrap();
        assert_eq!(got.len(), want.len());
        let weight = |s: &Splat| s.scale.x * s.scale.y * s.scale.z * s.opacity;
        let mut weights = Vec::new();
        for g in &got {
            let w = want
                .iter()
                .find(|w| w.position == g.position)
                .expect("every splat is there");
            weights.push(weight(w));
            assert_eq!(w.scale, g.scale);
            let dc = (w.f_dc - g.f_dc).abs().max_element();
            assert!(dc < 1.0 / (255.0 * SH_C0) + 1e-5, "{dc}");
            assert!((w.opacity - g.opacity).abs() < 1.0 / 255.0);
            assert!(w.rotation.dot(g.rotation).abs() > 1.0 - 2e-4);
        }
        assert!(
            weights.windows(2).all(|w| w[0] >= w[1]),
            "sorted by size × opacity, largest first: {weights:?}"
        );
        // The first is the largest: 40 splats, weights known.
        let largest = want
            .iter()
            .max_by(|a, b| weight(a).total_cmp(&weight(b)))
            .unwrap();
        assert_eq!(got[0].position, largest.position);
    }

    #[test]
    fn malformed_files_get_one_line_errors() {
        let good = encode(&splats()[..3]);
        let mut nan = good.clone();
        nan[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        let mut negative = good.clone();
        negative[RECORD + 12..RECORD + 16].copy_from_slice(&(-1.0f32).to_le_bytes());
        let mut zero = good.clone();
        zero[2 * RECORD + 28..3 * RECORD].fill(128);
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (Vec::new(), "empty"),
            (
                good[..good.len() - 7].to_vec(),
                "89 bytes is not a whole number",
            ),
            (nan, "splat 0: the position is not finite"),
            (negative, "splat 1: a scale is negative"),
            (zero, "splat 2: the rotation quaternion is zero"),
        ];
        for (bytes, expected) in cases {
            let err = decode(&bytes).unwrap_err();
            assert!(!err.contains('\n') && err.contains(expected), "{err}");
        }
    }
}
