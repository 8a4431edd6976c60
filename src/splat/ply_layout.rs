//! One Gaussian splat as splat files hold it, and the PLY container both PLY layouts
//! share (the 3DGS one in `ply`, SuperSplat's compressed one in `compressed_ply`): the
//! header's elements and properties, value types, and skipping binary elements.

use glam::{Quat, Vec3};

/// One Gaussian with the file's activations undone: opacity in (0, 1), linear scales.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splat {
    pub position: Vec3,
    /// SH degree-0 coefficients (colour = 0.5 + SH_C0 · f_dc).
    pub f_dc: Vec3,
    pub opacity: f32,
    pub scale: Vec3,
    pub rotation: Quat,
}

impl Splat {
    /// A deterministic cloud of `n` splats in the box from `min` over `size`: mixed
    /// sizes, elongations, rotations, colours and opacities, some overlapping (for tests
    /// and benchmarks).
    pub fn cloud(n: usize, min: Vec3, size: Vec3) -> Vec<Splat> {
        (0..n)
            .map(|i| {
                let f = i as f32;
                let h = |k: f32| ((f * k).sin() * 43758.547).fract().abs();
                Splat {
                    position: min + Vec3::new(h(1.1), h(2.3), h(3.7)) * size,
                    f_dc: (Vec3::new(h(4.1), h(5.3), h(6.7)) - Vec3::splat(0.5)) / SH_C0,
                    opacity: 0.2 + 0.79 * h(7.9),
                    scale: Vec3::new(0.01, 0.01, 0.005)
                        + Vec3::new(0.12 * h(8.3), 0.05 * h(9.1), 0.03 * h(10.7)),
                    rotation: Quat::from_euler(
                        glam::EulerRot::XYZ,
                        h(11.3) * 6.0,
                        h(12.1) * 6.0,
                        h(13.9) * 6.0,
                    ),
                }
            })
            .collect()
    }
}

/// The smallest scale written (1 nm): zero footprints are written as this.
pub const MIN_SCALE: f32 = 1e-9;

/// The SH degree-0 constant, 1 / (2√π).
pub const SH_C0: f32 = 0.282_094_8;

impl Splat {
    /// Linear RGB colour from the degree-0 coefficients.
    pub fn color(&self) -> Vec3 {
        Vec3::splat(0.5) + SH_C0 * self.f_dc
    }
}

#[derive(Clone, Copy, PartialEq)]
pub(super) enum Format {
    Ascii,
    Little,
    Big,
}

/// A property's byte size by PLY type name.
pub(super) fn type_size(name: &str) -> Option<usize> {
    Some(match name {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// One property of a PLY element: a scalar, or a list (its count's type and its items').
pub(super) enum Property {
    Scalar(String, String),
    List(String, String),
}

/// An element of the header: name, count and properties, in file order.
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: usize,
    pub(super) properties: Vec<Property>,
}

/// Skips a binary element from `offset`; returns the offset after it.
pub(super) fn skip_binary(
    body: &[u8],
    mut offset: usize,
    format: Format,
    element: &Element,
) -> Result<usize, String> {
    let ended = || format!("the file ends inside element '{}'", element.name);
    let fixed: Option<usize> = element
        .properties
        .iter()
        .map(|p| match p {
            Property::Scalar(ty, _) => type_size(ty),
            Property::List(..) => None,
        })
        .sum();
    if let Some(stride) = fixed {
        let end = stride
            .checked_mul(element.count)
            .and_then(|n| n.checked_add(offset))
            .filter(|&end| end <= body.len())
            .ok_or_else(ended)?;
        return Ok(end);
    }
    for _ in 0..element.count {
        for property in &element.properties {
            let (size, items) = match property {
                Property::Scalar(ty, _) => (type_size(ty).expect("checked"), 0),
                Property::List(count_ty, item_ty) => {
                    let size = type_size(count_ty).expect("checked");
                    let raw = body.get(offset..offset + size).ok_or_else(ended)?;
                    let n = number(count_ty, raw, format);
                    if n.is_nan() || n < 0.0 {
                        return Err(format!("element '{}': bad list length {n}", element.name));
                    }
                    (
                        size,
                        (n as usize).saturating_mul(type_size(item_ty).expect("checked")),
                    )
                }
            };
            offset = offset
                .checked_add(size)
                .and_then(|o| o.checked_add(items))
                .filter(|&o| o <= body.len())
                .ok_or_else(ended)?;
        }
    }
    Ok(offset)
}

/// One value of PLY type `ty` in `format`, as f32.
pub(super) fn number(ty: &str, raw: &[u8], format: Format) -> f32 {
    let mut raw = raw.to_vec();
    if format == Format::Big {
        raw.reverse();
    }
    value(ty, &raw)
}

/// One little-endian value of PLY type `ty` as f32.
fn value(ty: &str, raw: &[u8]) -> f32 {
    match ty {
        "float" | "float32" => f32::from_le_bytes(raw.try_into().expect("4 bytes")),
        "double" | "float64" => f64::from_le_bytes(raw.try_into().expect("8 bytes")) as f32,
        "char" | "int8" => raw[0] as i8 as f32,
        "uchar" | "uint8" => raw[0] as f32,
        "short" | "int16" => i16::from_le_bytes(raw.try_into().expect("2 bytes")) as f32,
        "ushort" | "uint16" => u16::from_le_bytes(raw.try_into().expect("2 bytes")) as f32,
        "int" | "int32" => i32::from_le_bytes(raw.try_into().expect("4 bytes")) as f32,
        _ => u32::from_le_bytes(raw.try_into().expect("4 bytes")) as f32,
    }
}
