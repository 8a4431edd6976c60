//! SuperSplat's compressed PLY (PlayCanvas SuperSplat / splat-transform), read only: a
//! `chunk` element (one per 256 splats: float bounds of position, log scale and,
//! optionally, colour), a `vertex` element of four packed uint words per splat and an
//! optional `sh` element of uchar `f_rest_*` (higher SH degrees, ignored here).
//!
//! Layout followed: playcanvas/splat-transform, `src/lib/readers/decompress-ply.ts` (the
//! reader) and `src/compressed-chunk.ts` (the writer), read 2025; the decoder below is
//! written from that description:
//! - `packed_position`, `packed_scale`: 11-10-11 bits (x in bits 21..31, y 11..20, z
//!   0..10), each a unorm lerped between the chunk's min and max (scale in log space).
//! - `packed_rotation`: bits 30..31 the index of the largest component of the quaternion
//!   (rot_0..3 order, i.e. w x y z; made non-negative by the writer), then the other
//!   three in index order, 10 bits each from bit 20 down; each is (unorm − 0.5) · √2
//!   and the largest is √(1 − a² − b² − c²).
//! - `packed_color`: 8-8-8-8 r g b a from the top byte down; rgb lerped between the
//!   chunk's min and max colour when the chunk has them (else taken as is) and stored as
//!   0.5 + SH_C0 · f_dc; alpha is the opacity after the sigmoid.

use glam::{Quat, Vec3};

use super::ply_layout::{Element, Format, Property, SH_C0, Splat, number, skip_binary, type_size};

/// Splats per chunk.
pub const CHUNK: usize = 256;

/// The chunk's float properties, in the order the decoder reads them.
const BOUNDS: [&str; 12] = [
    "min_x",
    "min_y",
    "min_z",
    "max_x",
    "max_y",
    "max_z",
    "min_scale_x",
    "min_scale_y",
    "min_scale_z",
    "max_scale_x",
    "max_scale_y",
    "max_scale_z",
];
/// The chunk's optional colour bounds.
const COLORS: [&str; 6] = ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"];
/// The vertex's packed words.
const PACKED: [&str; 4] = [
    "packed_position",
    "packed_rotation",
    "packed_scale",
    "packed_color",
];

/// A `bits`-bit unsigned field of `word` starting at bit `shift`, mapped to 0..=1.
fn unorm(word: u32, shift: u32, bits: u32) -> f32 {
    let max = (1u32 << bits) - 1;
    ((word >> shift) & max) as f32 / max as f32
}

/// An 11-10-11 word as three unorms (x high, z low).
pub fn unpack_111011(word: u32) -> Vec3 {
    Vec3::new(unorm(word, 21, 11), unorm(word, 11, 10), unorm(word, 0, 11))
}

/// An 8-8-8-8 word as four unorms (r in the top byte, a in the low one).
pub fn unpack_8888(word: u32) -> [f32; 4] {
    [
        unorm(word, 24, 8),
        unorm(word, 16, 8),
        unorm(word, 8, 8),
        unorm(word, 0, 8),
    ]
}

/// A "largest index + smallest three" word as a unit quaternion.
pub fn unpack_rotation(word: u32) -> Quat {
    let largest = (word >> 30) as usize;
    let small = [20, 10, 0].map(|shift| (unorm(word, shift, 10) - 0.5) * std::f32::consts::SQRT_2);
    let rest = 1.0 - small.iter().map(|v| v * v).sum::<f32>();
    // Components in rot_0..3 order: w x y z.
    let mut wxyz = [0.0; 4];
    let mut next = small.into_iter();
    for (i, c) in wxyz.iter_mut().enumerate() {
        *c = if i == largest {
            rest.max(0.0).sqrt()
        } else {
            next.next().expect("three small components")
        };
    }
    Quat::from_xyzw(wxyz[1], wxyz[2], wxyz[3], wxyz[0]).normalize()
}

/// `lo` to `hi` by `t` per component.
fn mix(lo: Vec3, hi: Vec3, t: Vec3) -> Vec3 {
    lo * (Vec3::ONE - t) + hi * t
}

/// One binary element's rows, with its properties' byte offsets.
struct Table<'a> {
    name: &'a str,
    rows: &'a [u8],
    stride: usize,
    columns: Vec<(&'a str, &'a str, usize)>,
    format: Format,
}

impl<'a> Table<'a> {
    fn new(element: &'a Element, body: &'a [u8], format: Format) -> Result<Self, String> {
        let mut columns = Vec::new();
        let mut stride = 0;
        for property in &element.properties {
            let Property::Scalar(ty, name) = property else {
                return Err(format!(
                    "element '{}' has a list property (not a compressed splat file)",
                    element.name
                ));
            };
            columns.push((ty.as_str(), name.as_str(), stride));
            stride += type_size(ty).expect("checked by the header");
        }
        Ok(Self {
            name: &element.name,
            rows: body,
            stride,
            columns,
            format,
        })
    }

    fn column(&self, name: &str) -> Result<(&'a str, usize), String> {
        self.columns
            .iter()
            .find(|(_, n, _)| *n == name)
            .map(|&(ty, _, offset)| (ty, offset))
            .ok_or(format!(
                "the compressed PLY's '{}' element has no '{name}' property",
                self.name
            ))
    }

    fn raw(&self, row: usize, (ty, offset): (&str, usize)) -> &[u8] {
        let at = row * self.stride + offset;
        &self.rows[at..at + type_size(ty).expect("checked by the header")]
    }

    fn float(&self, row: usize, column: (&str, usize)) -> f32 {
        number(column.0, self.raw(row, column), self.format)
    }

    fn word(&self, row: usize, column: (&str, usize)) -> u32 {
        let raw: [u8; 4] = self.raw(row, column).try_into().expect("4-byte column");
        match self.format {
            Format::Big => u32::from_be_bytes(raw),
            _ => u32::from_le_bytes(raw),
        }
    }
}

/// Splats from a compressed PLY: the header's `elements` and the body after it.
pub(super) fn decode(
    elements: &[Element],
    body: &[u8],
    format: Format,
) -> Result<Vec<Splat>, String> {
    if format == Format::Ascii {
        return Err("a compressed PLY (packed_position) must be binary, not ASCII".into());
    }
    let find = |name: &str| elements.iter().position(|e| e.name == name);
    let chunk_at = find("chunk")
        .ok_or("a compressed PLY (packed_position) needs a 'chunk' element; there is none")?;
    let vertex_at = find("vertex").expect("the caller found it");
    // Every element's start; a short file is refused here, whichever element it cuts.
    let mut starts = Vec::with_capacity(elements.len());
    let mut offset = 0;
    for element in elements {
        starts.push(offset);
        offset = skip_binary(body, offset, format, element)
            .map_err(|e| format!("the file is truncated: {e}"))?;
    }
    let chunks = Table::new(&elements[chunk_at], &body[starts[chunk_at]..], format)?;
    let vertices = Table::new(&elements[vertex_at], &body[starts[vertex_at]..], format)?;
    let count = elements[vertex_at].count;
    let needed = count.div_ceil(CHUNK);
    if elements[chunk_at].count < needed {
        return Err(format!(
            "{count} vertices need {needed} chunks of {CHUNK}, the 'chunk' element has {}",
            elements[chunk_at].count
        ));
    }
    let bounds: Vec<_> = BOUNDS
        .iter()
        .map(|n| chunks.column(n))
        .collect::<Result<_, _>>()?;
    let colors: Option<Vec<_>> = if chunks.columns.iter().any(|(_, n, _)| *n == "min_r") {
        Some(
            COLORS
                .iter()
                .map(|n| chunks.column(n))
                .collect::<Result<_, _>>()?,
        )
    } else {
        None
    };
    let packed: Vec<_> = PACKED
        .iter()
        .map(|n| {
            let (ty, offset) = vertices.column(n)?;
            if !["uint", "uint32", "int", "int32"].contains(&ty) {
                return Err(format!(
                    "'{n}' is a {ty}; the compressed layout packs it in a 32-bit uint"
                ));
            }
            Ok((ty, offset))
        })
        .collect::<Result<_, String>>()?;
    let mut out = Vec::with_capacity(count);
    for i in 0..count {
        let c = i / CHUNK;
        let b: Vec<f32> = bounds.iter().map(|&col| chunks.float(c, col)).collect();
        if let Some(k) = b.iter().position(|v| !v.is_finite()) {
            return Err(format!("chunk {c}: '{}' is {}", BOUNDS[k], b[k]));
        }
        let [p, r, s, k] = [0, 1, 2, 3].map(|j| vertices.word(i, packed[j]));
        let lo = Vec3::from_slice(&b[0..3]);
        let hi = Vec3::from_slice(&b[3..6]);
        let position = mix(lo, hi, unpack_111011(p));
        let log_lo = Vec3::from_slice(&b[6..9]);
        let log_hi = Vec3::from_slice(&b[9..12]);
        let scale = mix(log_lo, log_hi, unpack_111011(s)).exp();
        if !scale.is_finite() {
            return Err(format!("vertex {i}: a scale overflows ({scale})"));
        }
        let [red, green, blue, alpha] = unpack_8888(k);
        let mut color = Vec3::new(red, green, blue);
        if let Some(columns) = &colors {
            let v: Vec<f32> = columns.iter().map(|&col| chunks.float(c, col)).collect();
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                return Err(format!("chunk {c}: '{}' is {}", COLORS[k], v[k]));
            }
            color = mix(
                Vec3::from_slice(&v[0..3]),
                Vec3::from_slice(&v[3..6]),
                color,
            );
        }
        out.push(Splat {
            position,
            f_dc: (color - Vec3::splat(0.5)) / SH_C0,
            opacity: alpha,
            scale,
            rotation: unpack_rotation(r),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    //! An encoder written from the writer's description (splat-transform's
    //! `compressed-chunk.ts`, see the module header), independent of the decoder's
    //! helpers: compress known splats, decode, compare within the quantisation.
    use super::*;
    use crate::splat::ply::decode as decode_ply;

    /// Rounds `v` in 0..=1 to a `bits`-bit unsigned integer.
    fn quantise(v: f32, bits: u32) -> u32 {
        let max = ((1u32 << bits) - 1) as f32;
        (v * max + 0.5).floor().clamp(0.0, max) as u32
    }

    /// `v` between `lo` and `hi` as 0..=1 (0 for a flat range).
    fn fraction(v: f32, lo: f32, hi: f32) -> f32 {
        if hi - lo < 1e-5 {
            0.0
        } else {
            ((v - lo) / (hi - lo)).clamp(0.0, 1.0)
        }
    }

    fn pack_111011(t: Vec3) -> u32 {
        quantise(t.x, 11) << 21 | quantise(t.y, 10) << 11 | quantise(t.z, 11)
    }

    fn pack_rotation(q: Quat) -> u32 {
        let q = q.normalize();
        let mut wxyz = [q.w, q.x, q.y, q.z];
        // The first of the largest magnitudes, as the writer's reduce picks it.
        let largest = (1..4).fold(0, |m, i| if wxyz[i].abs() > wxyz[m].abs() { i } else { m });
        if wxyz[largest] < 0.0 {
            wxyz = wxyz.map(|v| -v);
        }
        let mut word = largest as u32;
        for (i, v) in wxyz.iter().enumerate() {
            if i != largest {
                word = word << 10 | quantise(v * std::f32::consts::FRAC_1_SQRT_2 + 0.5, 10);
            }
        }
        word
    }

    /// A compressed PLY of `splats`, with per-chunk colour bounds when `chunk_colors`,
    /// and an `sh` element of 9 uchar coefficients when `sh`.
    fn compress(splats: &[Splat], chunk_colors: bool, sh: bool) -> Vec<u8> {
        let chunks = splats.len().div_ceil(CHUNK);
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\ncomment written by a test\nelement chunk {chunks}\n"
        );
        let names: Vec<&str> = BOUNDS
            .iter()
            .chain(if chunk_colors { &COLORS[..] } else { &[] })
            .copied()
            .collect();
        for n in &names {
            header += &format!("property float {n}\n");
        }
        header += &format!("element vertex {}\n", splats.len());
        for n in PACKED {
            header += &format!("property uint {n}\n");
        }
        if sh {
            header += &format!("element sh {}\n", splats.len());
            for k in 0..9 {
                header += &format!("property uchar f_rest_{k}\n");
            }
        }
        header += "end_header\n";
        let mut chunk_bytes = Vec::new();
        let mut vertex_bytes = Vec::new();
        for group in splats.chunks(CHUNK) {
            let range = |f: &dyn Fn(&Splat) -> Vec3| {
                group.iter().fold(
                    (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                    |(lo, hi), s| (lo.min(f(s)), hi.max(f(s))),
                )
            };
            let (plo, phi) = range(&|s| s.position);
            let (slo, shi) = range(&|s| s.scale.map(f32::ln));
            let (clo, chi) = range(&|s| s.color());
            let mut values = vec![plo, phi, slo, shi];
            if chunk_colors {
                values.extend([clo, chi]);
            }
            for v in values.iter().flat_map(|v| v.to_array()) {
                chunk_bytes.extend(v.to_le_bytes());
            }
            for s in group {
                let t = |v: Vec3, lo: Vec3, hi: Vec3| {
                    Vec3::new(
                        fraction(v.x, lo.x, hi.x),
                        fraction(v.y, lo.y, hi.y),
                        fraction(v.z, lo.z, hi.z),
                    )
                };
                let color = if chunk_colors {
                    t(s.color(), clo, chi)
                } else {
                    s.color()
                };
                let words = [
                    pack_111011(t(s.position, plo, phi)),
                    pack_rotation(s.rotation),
                    pack_111011(t(s.scale.map(f32::ln), slo, shi)),
                    quantise(color.x, 8) << 24
                        | quantise(color.y, 8) << 16
                        | quantise(color.z, 8) << 8
                        | quantise(s.opacity, 8),
                ];
                for w in words {
                    vertex_bytes.extend(w.to_le_bytes());
                }
            }
        }
        let mut out = header.into_bytes();
        out.extend(chunk_bytes);
        out.extend(vertex_bytes);
        if sh {
            out.extend((0..9 * splats.len()).map(|i| (i % 251) as u8));
        }
        out
    }

    /// 600 splats (three chunks, the last partial) spread over a few metres.
    fn splats() -> Vec<Splat> {
        Splat::cloud(600, Vec3::new(-2.0, 0.0, -0.5), Vec3::new(4.0, 2.0, 1.0))
    }

    /// The quantisation's worst error for each field of a chunk: half a step of the
    /// chunk's range (11 bits: range / 2047 / 2; 10 bits: / 1023 / 2) plus f32 rounding.
    #[test]
    fn compressed_splats_decode_within_the_quantisation() {
        let want = splats();
        for (colors, sh) in [(true, false), (false, true)] {
            let got = decode_ply(&compress(&want, colors, sh)).unwrap();
            assert_eq!(got.len(), want.len());
            for (chunk, (w, g)) in want.chunks(CHUNK).zip(got.chunks(CHUNK)).enumerate() {
                let range = |f: &dyn Fn(&Splat) -> Vec3| {
                    let (lo, hi) = w.iter().fold(
                        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
                        |(lo, hi), s| (lo.min(f(s)), hi.max(f(s))),
                    );
                    hi - lo
                };
                let step = Vec3::new(2047.0, 1023.0, 2047.0);
                let position_tol = range(&|s| s.position) / step / 2.0 + 1e-6;
                let log_scale_tol = range(&|s| s.scale.map(f32::ln)) / step / 2.0 + 1e-5;
                // Colour: 8 bits over the chunk's range, or over 0..1 without bounds.
                let color_range = if colors {
                    range(&|s| s.color())
                } else {
                    Vec3::ONE
                };
                let color_tol = color_range / 255.0 / 2.0 + 1e-6;
                for (a, b) in w.iter().zip(g) {
                    let ctx = format!("chunk {chunk}: {a:?} vs {b:?}");
                    assert!(
                        ((a.position - b.position).abs() - position_tol).max_element() <= 0.0,
                        "{ctx}"
                    );
                    let dlog = (a.scale.map(f32::ln) - b.scale.map(f32::ln)).abs();
                    assert!((dlog - log_scale_tol).max_element() <= 0.0, "{ctx}");
                    assert!(
                        ((a.color() - b.color()).abs() - color_tol).max_element() <= 0.0,
                        "{ctx}"
                    );
                    assert!((a.opacity - b.opacity).abs() <= 0.5 / 255.0 + 1e-6, "{ctx}");
                    // Rotation: three components of at most 1/√2 in 10 bits, each off
                    // by ≤ √2/1023/2 ≈ 7e-4, the fourth recomputed from them: |Δq| <
                    // 3e-3, so |q·q'| > 1 − 4.5e-6 (allow 1e-5).
                    assert!(a.rotation.dot(b.rotation).abs() > 1.0 - 1e-5, "{ctx}");
                }
            }
        }
    }

    #[test]
    fn one_packed_word_of_each_kind_by_hand() {
        // Position / scale 11-10-11: x = 1024 (bits 21..31), y = 1023, z = 0.
        let word = 1024 << 21 | 1023 << 11;
        let t = unpack_111011(word);
        assert!((t.x - 1024.0 / 2047.0).abs() < 1e-7 && t.y == 1.0 && t.z == 0.0);
        // Colour 0x80_40_FF_00: r 128/255, g 64/255, b 1, a 0.
        let [r, g, b, a] = unpack_8888(0x8040_FF00);
        assert!((r - 128.0 / 255.0).abs() < 1e-7 && (g - 64.0 / 255.0).abs() < 1e-7);
        assert!(b == 1.0 && a == 0.0);
        // Rotation: largest = 0 (w), x = 1023, y = z = 0: x = (1 − 0.5)·√2 = √½,
        // y = z = (0 − 0.5)·√2 = −√½. Their squares sum to 1.5, so w = √max(0, −0.5) = 0
        // and the quaternion is normalised: (w x y z) = (0, 1, −1, −1)/√3.
        let q = unpack_rotation(1023 << 20);
        let want = Quat::from_xyzw(1.0, -1.0, -1.0, 0.0).normalize();
        assert!(q.dot(want) > 1.0 - 1e-6, "{q}");
        // Largest = 3 (z), the others w x y at 512/1023 → (512/1023 − 0.5)·√2 = 6.9e-4,
        // so z = √(1 − 3 · (6.9e-4)²) ≈ 1: a half turn about Z.
        let q = unpack_rotation(3 << 30 | 512 << 20 | 512 << 10 | 512);
        let small = (512.0 / 1023.0 - 0.5) * std::f32::consts::SQRT_2;
        assert!((small - 6.9124e-4).abs() < 1e-7);
        let want = Quat::from_xyzw(small, small, 1.0, small).normalize();
        assert!(q.dot(want) > 1.0 - 1e-7, "{q}");
        assert!(
            (q * Vec3::X + Vec3::X).length() < 5e-3,
            "≈ a half turn about Z"
        );
        // The test encoder on a word known by hand: a quarter turn about Y, (w, y) =
        // (√½, √½): largest = 0 (the first of the tie), x = z = 0 → ⌊0.5·1023 + 0.5⌋ =
        // 512, y = √½·√½ + 0.5 = 1 → 1023.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let quarter = Quat::from_xyzw(0.0, h, 0.0, h);
        assert_eq!(pack_rotation(quarter), 512 << 20 | 1023 << 10 | 512);
    }

    #[test]
    fn malformed_compressed_files_get_one_line_errors() {
        let good = compress(&splats()[..300], true, true);
        let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (good[..good.len() - 5].to_vec(), "truncated"),
            (
                good[..text(&good).find("end_header").unwrap() + 11 + 100].to_vec(),
                "the file is truncated: the file ends inside element 'chunk'",
            ),
            (
                text(&good)
                    .replace("element chunk 2", "element chunk 1")
                    .into_bytes(),
                "300 vertices need 2 chunks of 256, the 'chunk' element has 1",
            ),
            (
                text(&good)
                    .replace("element chunk 2", "element bounds 2")
                    .into_bytes(),
                "needs a 'chunk' element",
            ),
            (
                text(&good)
                    .replace("property float min_scale_y", "property float min_sy")
                    .into_bytes(),
                "no 'min_scale_y' property",
            ),
            (
                text(&good)
                    .replace("property uint packed_color", "property float packed_color")
                    .into_bytes(),
                "'packed_color' is a float",
            ),
            (
                b"ply\nformat ascii 1.0\nelement chunk 1\nproperty float min_x\nelement vertex 1\nproperty uint packed_position\nend_header\n0\n0\n".to_vec(),
                "must be binary",
            ),
        ];
        for (bytes, expected) in cases {
            let err = decode_ply(&bytes).unwrap_err();
            assert!(!err.contains('\n'), "one line: {err}");
            assert!(
                err.contains(expected),
                "'{err}' should mention '{expected}'"
            );
        }
        // A NaN bound is named.
        let mut nan = good.clone();
        let body = text(&good).find("end_header\n").unwrap() + 11;
        nan[body..body + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        let err = decode_ply(&nan).unwrap_err();
        assert!(err.contains("chunk 0: 'min_x' is NaN"), "{err}");
    }
}
