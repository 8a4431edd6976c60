//! Gaussian splats in the de-facto 3DGS PLY layout (docs/architecture.md, Files): binary
//! little-endian vertices with x y z, nx ny nz, f_dc_0..2 (SH degree 0), opacity (logit),
//! scale_0..2 (log), rot_0..3 (w x y z). Reading also takes ASCII and big-endian files,
//! float or double properties in any order, and ignores extra ones (higher SH degrees:
//! f_rest_*). A file in SuperSplat's compressed layout (`packed_position` vertices) is
//! handed to [`super::compressed_ply`].

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};

use super::ply_layout::{Element, Format, Property, number, skip_binary, type_size};
pub use super::ply_layout::{MIN_SCALE, SH_C0, Splat};

#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct PlyError {
    pub path: PathBuf,
    pub problem: String,
}

/// The properties written, in order.
const FIELDS: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

fn fields(s: &Splat) -> [f32; 17] {
    let logit =
        (s.opacity.clamp(1e-6, 1.0 - 1e-6) / (1.0 - s.opacity.clamp(1e-6, 1.0 - 1e-6))).ln();
    let q = s.rotation;
    [
        s.position.x,
        s.position.y,
        s.position.z,
        0.0,
        0.0,
        0.0,
        s.f_dc.x,
        s.f_dc.y,
        s.f_dc.z,
        logit,
        // A degenerate splat (two map pixels on one point give a zero footprint) is
        // written as a vanishing one, so the file stays finite and readable.
        s.scale.x.max(MIN_SCALE).ln(),
        s.scale.y.max(MIN_SCALE).ln(),
        s.scale.z.max(MIN_SCALE).ln(),
        q.w,
        q.x,
        q.y,
        q.z,
    ]
}

/// The file's bytes for `splats`.
pub fn encode(splats: &[Splat]) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n",
        splats.len()
    )
    .into_bytes();
    for name in FIELDS {
        out.extend(format!("property float {name}\n").bytes());
    }
    out.extend(b"end_header\n");
    for s in splats {
        for v in fields(s) {
            out.extend(v.to_le_bytes());
        }
    }
    out
}

pub fn write(path: &Path, splats: &[Splat]) -> Result<(), crate::files::WriteError> {
    crate::files::write_atomic(path, &encode(splats))
}

pub fn read(path: &Path) -> Result<Vec<Splat>, PlyError> {
    read_with(path, decode)
}

/// The splats of the file at `path` as `decode` reads its bytes, errors naming the file.
pub(crate) fn read_with(
    path: &Path,
    decode: fn(&[u8]) -> Result<Vec<Splat>, String>,
) -> Result<Vec<Splat>, PlyError> {
    let bytes = std::fs::read(path).map_err(|e| PlyError {
        path: path.to_path_buf(),
        problem: e.to_string(),
    })?;
    decode(&bytes).map_err(|problem| PlyError {
        path: path.to_path_buf(),
        problem,
    })
}

/// Where the header ends and the body starts (after `end_header` and its LF or CRLF).
fn header_end(bytes: &[u8]) -> Option<(usize, usize)> {
    let mut from = 0;
    while let Some(at) = find(&bytes[from..], b"end_header") {
        let at = from + at;
        let rest = &bytes[at + b"end_header".len()..];
        let line_start = at == 0 || bytes[at - 1] == b'\n';
        if line_start && rest.starts_with(b"\n") {
            return Some((at, at + b"end_header\n".len()));
        }
        if line_start && rest.starts_with(b"\r\n") {
            return Some((at, at + b"end_header\r\n".len()));
        }
        from = at + 1;
    }
    None
}

/// Splats from a PLY file's bytes; the error says what is wrong.
pub fn decode(bytes: &[u8]) -> Result<Vec<Splat>, String> {
    let (end, body_start) = header_end(bytes).ok_or("not a PLY file (no end_header line)")?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "the PLY header is not text")?;
    let mut lines = header.lines();
    if lines.next().map(str::trim_end) != Some("ply") {
        return Err("not a PLY file (the first line is not 'ply')".into());
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", f, _] => {
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Little,
                    "binary_big_endian" => Format::Big,
                    other => return Err(format!("unknown PLY format '{other}'")),
                })
            }
            ["element", name, n] => elements.push(Element {
                name: name.to_string(),
                count: n
                    .parse::<usize>()
                    .map_err(|_| format!("bad {name} count '{n}'"))?,
                properties: Vec::new(),
            }),
            ["property", "list", count_ty, item_ty, _] => {
                let element = elements
                    .last_mut()
                    .ok_or("a property comes before any element")?;
                if element.name == "vertex" {
                    return Err("list properties on vertices are not supported".into());
                }
                for ty in [count_ty, item_ty] {
                    type_size(ty).ok_or(format!("unknown property type '{ty}'"))?;
                }
                element
                    .properties
                    .push(Property::List(count_ty.to_string(), item_ty.to_string()));
            }
            ["property", ty, name] => {
                let element = elements
                    .last_mut()
                    .ok_or("a property comes before any element")?;
                type_size(ty).ok_or(format!("unknown property type '{ty}'"))?;
                element
                    .properties
                    .push(Property::Scalar(ty.to_string(), name.to_string()));
            }
            _ => {}
        }
    }
    let format = format.ok_or("the PLY header has no format line")?;
    let at = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or("the PLY file has no vertex element")?;
    let vertex = &elements[at];
    let count = vertex.count;
    if count == 0 {
        return Err("the PLY file has 0 vertices".into());
    }
    let body = &bytes[body_start..];
    let packed = |p: &Property| matches!(p, Property::Scalar(_, n) if n == "packed_position");
    if vertex.properties.iter().any(packed) {
        // SuperSplat's compressed layout: quantised vertices in 256-splat chunks.
        return super::compressed_ply::decode(&elements, body, format);
    }
    let properties: Vec<(String, String)> = vertex
        .properties
        .iter()
        .filter_map(|p| match p {
            Property::Scalar(ty, name) => Some((ty.clone(), name.clone())),
            Property::List(..) => None,
        })
        .collect();
    let column = |name: &str| {
        properties
            .iter()
            .position(|(_, n)| n == name)
            .ok_or(format!(
                "the vertices have no '{name}' property (not a 3DGS splat file)"
            ))
    };
    // Every written field but the (unused) normals.
    let names: Vec<&str> = FIELDS
        .into_iter()
        .filter(|n| !["nx", "ny", "nz"].contains(n))
        .collect();
    let wanted: Vec<usize> = names.iter().map(|n| column(n)).collect::<Result<_, _>>()?;
    let rows = match format {
        Format::Ascii => {
            let text = std::str::from_utf8(body).map_err(|_| "the ASCII body is not text")?;
            let mut words = text.split_whitespace();
            for element in &elements[..at] {
                skip_ascii(&mut words, element)?;
            }
            read_ascii(&mut words, body.len(), &properties, count)?
        }
        Format::Little | Format::Big => {
            let mut offset = 0;
            for element in &elements[..at] {
                offset = skip_binary(body, offset, format, element)?;
            }
            read_rows(&body[offset..], format, &properties, count)?
        }
    };
    rows.chunks_exact(properties.len())
        .enumerate()
        .map(|(i, row)| {
            let v: Vec<f32> = wanted.iter().map(|&c| row[c]).collect();
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                return Err(format!("vertex {i}: '{}' is {}", names[k], v[k]));
            }
            let rotation = Quat::from_xyzw(v[11], v[12], v[13], v[10]);
            let norm = rotation.length_squared();
            if norm.is_nan() || norm <= 1e-12 || norm.is_infinite() {
                return Err(format!("vertex {i}: the rotation quaternion is zero"));
            }
            let scale = Vec3::new(v[7].exp(), v[8].exp(), v[9].exp());
            if !scale.is_finite() {
                return Err(format!("vertex {i}: a scale overflows ({scale})"));
            }
            Ok(Splat {
                position: Vec3::new(v[0], v[1], v[2]),
                f_dc: Vec3::new(v[3], v[4], v[5]),
                opacity: 1.0 / (1.0 + (-v[6]).exp()),
                scale,
                rotation: rotation.normalize(),
            })
        })
        .collect()
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    haystack.windows(needle.len()).position(|w| w == needle)
}

/// Skips an ASCII element (one line per item; a list is its count then its items).
fn skip_ascii<'a>(
    words: &mut impl Iterator<Item = &'a str>,
    element: &Element,
) -> Result<(), String> {
    if element.properties.is_empty() {
        return Ok(());
    }
    let ended = || format!("the file ends inside element '{}'", element.name);
    for _ in 0..element.count {
        for property in &element.properties {
            let word = words.next().ok_or_else(ended)?;
            if let Property::List(..) = property {
                let n: usize = word
                    .parse()
                    .map_err(|_| format!("element '{}': bad list length '{word}'", element.name))?;
                for _ in 0..n {
                    words.next().ok_or_else(ended)?;
                }
            }
        }
    }
    Ok(())
}

/// The vertices' properties from ASCII words, row-major.
fn read_ascii<'a>(
    words: &mut impl Iterator<Item = &'a str>,
    bytes: usize,
    properties: &[(String, String)],
    count: usize,
) -> Result<Vec<f32>, String> {
    // Each number takes at least one character and a separator.
    let values = count
        .checked_mul(properties.len())
        .filter(|&n| n <= bytes.div_ceil(2))
        .ok_or(format!(
            "the file is truncated: it cannot hold {count} vertices"
        ))?;
    let mut out = Vec::with_capacity(values);
    for i in 0..count {
        for _ in properties {
            let word = words
                .next()
                .ok_or(format!("the file ends inside vertex {i} of {count}"))?;
            out.push(
                word.parse::<f32>()
                    .map_err(|_| format!("vertex {i}: '{word}' is not a number"))?,
            );
        }
    }
    Ok(out)
}

/// Every binary vertex's properties as f32, row-major.
fn read_rows(
    body: &[u8],
    format: Format,
    properties: &[(String, String)],
    count: usize,
) -> Result<Vec<f32>, String> {
    let sizes: Vec<usize> = properties
        .iter()
        .map(|(ty, _)| type_size(ty).expect("checked"))
        .collect();
    let stride: usize = sizes.iter().sum();
    let needed = stride
        .checked_mul(count)
        .ok_or(format!("vertex count {count} is too large"))?;
    if body.len() < needed {
        return Err(format!(
            "the file is truncated: {count} vertices need {needed} bytes, {} are there",
            body.len()
        ));
    }
    let mut out = Vec::with_capacity(count * properties.len());
    for row in body.chunks_exact(stride).take(count) {
        let mut at = 0;
        for ((ty, _), &size) in properties.iter().zip(&sizes) {
            out.push(number(ty, &row[at..at + size], format));
            at += size;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn splats() -> Vec<Splat> {
        (0..5)
            .map(|i| {
                let f = i as f32;
                Splat {
                    position: Vec3::new(f, -f, 0.5 * f),
                    f_dc: Vec3::new(0.1 * f, -0.2, 0.3),
                    opacity: 0.1 + 0.15 * f,
                    scale: Vec3::new(0.01, 0.02 + 0.01 * f, 0.005),
                    rotation: Quat::from_rotation_y(0.3 * f),
                }
            })
            .collect()
    }

    fn close(a: &Splat, b: &Splat) -> bool {
        a.position.distance(b.position) < 1e-5
            && a.f_dc.distance(b.f_dc) < 1e-6
            && (a.opacity - b.opacity).abs() < 1e-5
            && (a.scale - b.scale).abs().max_element() < 1e-6
            && a.rotation.dot(b.rotation).abs() > 1.0 - 1e-6
    }

    #[test]
    fn splats_survive_a_round_trip_through_a_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.ply");
        write(&path, &splats()).unwrap();
        let back = read(&path).unwrap();
        assert_eq!(back.len(), 5);
        assert!(splats().iter().zip(&back).all(|(a, b)| close(a, b)));
    }

    #[test]
    fn a_zero_footprint_is_written_as_a_vanishing_splat() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.ply");
        let mut flat = splats();
        flat[1].scale = Vec3::new(0.01, 0.0, 0.0);
        write(&path, &flat).unwrap();
        let back = read(&path).unwrap();
        assert!(
            (back[1].scale.y - MIN_SCALE).abs() < 1e-12,
            "{}",
            back[1].scale
        );
        assert!((back[1].scale.x - 0.01).abs() < 1e-6);
    }

    #[test]
    fn other_writers_layouts_are_read() {
        // ASCII, another property order, doubles, and higher-degree SH (ignored).
        let s = splats()[2];
        let f = fields(&s);
        let header = "ply\nformat ascii 1.0\ncomment another tool\nelement vertex 1\nproperty double rot_0\nproperty double rot_1\nproperty double rot_2\nproperty double rot_3\nproperty float f_rest_0\nproperty float x\nproperty float y\nproperty float z\nproperty float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\nproperty float opacity\nproperty float scale_0\nproperty float scale_1\nproperty float scale_2\nend_header\n";
        let body = format!(
            "{} {} {} {} 0.7 {} {} {} {} {} {} {} {} {} {}\n",
            f[13],
            f[14],
            f[15],
            f[16],
            f[0],
            f[1],
            f[2],
            f[6],
            f[7],
            f[8],
            f[9],
            f[10],
            f[11],
            f[12]
        );
        let got = decode(format!("{header}{body}").as_bytes()).unwrap();
        assert!(close(&got[0], &s), "{:?} vs {s:?}", got[0]);
        // Big-endian binary.
        let mut big = b"ply\nformat binary_big_endian 1.0\nelement vertex 1\n".to_vec();
        for name in FIELDS {
            big.extend(format!("property float {name}\n").bytes());
        }
        big.extend(b"end_header\n");
        for v in f {
            big.extend(v.to_be_bytes());
        }
        assert!(close(&decode(&big).unwrap()[0], &s));
    }

    #[test]
    fn malformed_files_get_clear_errors() {
        let good = encode(&splats());
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"hello".to_vec(), "no end_header"),
            (b"plx\nend_header\n".to_vec(), "first line"),
            (good[..good.len() - 10].to_vec(), "truncated"),
            (
                String::from_utf8_lossy(&good)
                    .replace("property float opacity", "property float alpha")
                    .into_bytes(),
                "no 'opacity' property",
            ),
            (
                b"ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n".to_vec(),
                "unknown PLY format",
            ),
            (
                b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1 2\n"
                    .to_vec(),
                "no 'y' property",
            ),
            (
                b"ply\nformat ascii 1.0\nelement vertex many\nend_header\n".to_vec(),
                "bad vertex count",
            ),
            (
                String::from_utf8_lossy(&good)
                    .replace("element vertex 5", "element vertex 18446744073709551615")
                    .into_bytes(),
                "too large",
            ),
        ];
        for (bytes, expected) in cases {
            let err = decode(&bytes).unwrap_err();
            assert!(
                err.contains(expected),
                "'{err}' should mention '{expected}'"
            );
        }
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("none.ply");
        assert!(read(&missing).unwrap_err().to_string().contains("none.ply"));
    }
}
