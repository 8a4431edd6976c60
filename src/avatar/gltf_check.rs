//! Opening a glTF/GLB file and checking it before anything is read: a missing buffer or
//! image file is named, and every accessor's declared count, stride and byte range is
//! checked against the bytes its buffer holds, as is the component type and shape of each
//! accessor unica reads — so a malformed file gets a named error, never a huge
//! allocation, a panic or silently substituted data.

use std::path::Path;

use gltf::accessor::{Accessor, DataType, Dimensions};
use gltf::mesh::Semantic;

use super::load_error::{CharacterError, fail};

/// The most elements one accessor may declare (16,777,216).
pub const MAX_ELEMENTS: usize = 1 << 24;

/// The most bytes one accessor may expand to (256 MiB; a sparse accessor without a
/// bufferView is all zeros but its declared size).
pub const MAX_BYTES: usize = 1 << 28;

/// The document, its buffers and its decoded images, each checked.
pub type Imported = (
    gltf::Document,
    Vec<gltf::buffer::Data>,
    Vec<gltf::image::Data>,
);

/// Reads a `.gltf` or `.glb` file and its external buffers and images, then [`check`]s it.
pub fn import(path: &Path) -> Result<Imported, CharacterError> {
    let bytes = std::fs::read(path).map_err(|e| fail(path, e.to_string()))?;
    if bytes.is_empty() {
        return Err(fail(path, "the file is empty"));
    }
    let glb = bytes.starts_with(b"glTF");
    let named_glb = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("glb") || e.eq_ignore_ascii_case("vrm"));
    if named_glb && !glb {
        return Err(fail(path, "not a GLB file (it does not start with 'glTF')"));
    }
    let gltf = gltf::Gltf::from_slice(&bytes).map_err(|e| {
        let kind = if glb {
            "not a valid GLB file"
        } else {
            "not valid glTF JSON"
        };
        fail(path, format!("{kind}: {e}"))
    })?;
    let base = path.parent().unwrap_or(Path::new("."));
    let uris = gltf
        .document
        .buffers()
        .filter_map(|b| match b.source() {
            gltf::buffer::Source::Uri(uri) => Some(("buffer", b.index(), uri)),
            gltf::buffer::Source::Bin => None,
        })
        .chain(gltf.document.images().filter_map(|i| match i.source() {
            gltf::image::Source::Uri { uri, .. } => Some(("image", i.index(), uri)),
            gltf::image::Source::View { .. } => None,
        }));
    for (kind, index, uri) in uris {
        if let Some(why) = refused_uri(uri) {
            return Err(fail(
                path,
                format!("{kind} {index}'s URI '{}' {why}", short(uri)),
            ));
        }
        let plain = !uri.starts_with("data:") && !uri.contains('%');
        let file = base.join(uri);
        if plain && !file.is_file() {
            let name = path.file_name().unwrap_or_default().to_string_lossy();
            return Err(fail(
                &file,
                format!("no such file ({kind} {index} of {name})"),
            ));
        }
    }
    let document = gltf.document;
    let buffers = gltf::import_buffers(&document, Some(base), gltf.blob)
        .map_err(|e| fail(path, format!("buffers: {e}")))?;
    check(path, &document, &buffers)?;
    let images = gltf::import_images(&document, Some(base), &buffers)
        .map_err(|e| fail(path, format!("images: {e}")))?;
    Ok((document, buffers, images))
}

/// Why a buffer or image URI is refused, if it is: a file may point only at files beside
/// it (a relative path) or carry its data inline (`data:`). Another scheme would fetch
/// from elsewhere (`http:`, `file:`), and an absolute path reads any file on the machine.
fn refused_uri(uri: &str) -> Option<&'static str> {
    if uri.starts_with("data:") {
        return None;
    }
    let scheme = uri.split_once(':').is_some_and(|(head, _)| {
        head.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
            && head
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
    });
    if scheme {
        return Some("is not a relative file path or a data: URI");
    }
    if uri.starts_with('/') || uri.starts_with('\\') {
        return Some("is an absolute path (only paths relative to the file are read)");
    }
    None
}

/// `uri` cut to 60 characters for an error line.
fn short(uri: &str) -> String {
    if uri.chars().count() <= 60 {
        uri.to_string()
    } else {
        format!("{}…", uri.chars().take(60).collect::<String>())
    }
}

/// Runs `read` (everything that touches the `gltf` crate for `path`) and turns a panic
/// inside it into a named error. The `gltf` crate (1.4) panics on some malformed files
/// (indices out of range inside its own validation, invalid enum values); those panics
/// are kept silent on this thread, so the caller prints one line.
pub fn guarded<T>(
    path: &Path,
    read: impl FnOnce() -> Result<T, CharacterError>,
) -> Result<T, CharacterError> {
    use std::cell::Cell;
    use std::panic::{AssertUnwindSafe, catch_unwind};
    thread_local! {
        static QUIET: Cell<bool> = const { Cell::new(false) };
    }
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(Cell::get) {
                previous(info);
            }
        }));
    });
    let was = QUIET.with(|q| q.replace(true));
    let result = catch_unwind(AssertUnwindSafe(read));
    QUIET.with(|q| q.set(was));
    result.unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        Err(fail(
            path,
            format!("malformed glTF: the glTF reader failed ({message})"),
        ))
    })
}

/// Checks every accessor's extent and the type of every accessor unica reads.
pub fn check(
    path: &Path,
    doc: &gltf::Document,
    buffers: &[gltf::buffer::Data],
) -> Result<(), CharacterError> {
    use DataType::{F32, I8, I16, U8, U16, U32};
    use Dimensions::{Mat4, Scalar, Vec2, Vec3, Vec4};
    for accessor in doc.accessors() {
        check_extent(path, &accessor, buffers)?;
    }
    for mesh in doc.meshes() {
        for primitive in mesh.primitives() {
            if let Some(a) = primitive.indices() {
                expect(path, &a, "indices", &[U8, U16, U32], &[Scalar])?;
            }
            for (semantic, a) in primitive.attributes() {
                let (types, dims): (&[DataType], &[Dimensions]) = match semantic {
                    Semantic::Positions | Semantic::Normals => (&[F32], &[Vec3]),
                    Semantic::Joints(_) => (&[U8, U16], &[Vec4]),
                    Semantic::Weights(_) => (&[U8, U16, F32], &[Vec4]),
                    Semantic::TexCoords(_) => (&[U8, U16, F32], &[Vec2]),
                    Semantic::Colors(_) => (&[U8, U16, F32], &[Vec3, Vec4]),
                    _ => continue,
                };
                expect(path, &a, &semantic.to_string(), types, dims)?;
            }
        }
    }
    for skin in doc.skins() {
        if let Some(a) = skin.inverse_bind_matrices() {
            expect(path, &a, "inverse bind matrices", &[F32], &[Mat4])?;
        }
    }
    for animation in doc.animations() {
        for channel in animation.channels() {
            let sampler = channel.sampler();
            expect(path, &sampler.input(), "key times", &[F32], &[Scalar])?;
            let (types, dims): (&[DataType], &[Dimensions]) = match channel.target().property() {
                gltf::animation::Property::Translation | gltf::animation::Property::Scale => {
                    (&[F32], &[Vec3])
                }
                gltf::animation::Property::Rotation => (&[I8, U8, I16, U16, F32], &[Vec4]),
                gltf::animation::Property::MorphTargetWeights => {
                    (&[I8, U8, I16, U16, F32], &[Scalar])
                }
            };
            expect(path, &sampler.output(), "key values", types, dims)?;
        }
    }
    Ok(())
}

fn label(a: &Accessor) -> String {
    match a.name() {
        Some(name) => format!("accessor {} ('{name}')", a.index()),
        None => format!("accessor {}", a.index()),
    }
}

/// The accessor, used as `what`, has one of `types` and one of `dims`.
fn expect(
    path: &Path,
    a: &Accessor,
    what: &str,
    types: &[DataType],
    dims: &[Dimensions],
) -> Result<(), CharacterError> {
    if types.contains(&a.data_type()) && dims.contains(&a.dimensions()) {
        return Ok(());
    }
    Err(fail(
        path,
        format!(
            "{} ({what}) is {:?} {:?}, expected one of {types:?} {dims:?}",
            label(a),
            a.data_type(),
            a.dimensions()
        ),
    ))
}

/// The declared count is bounded and every element (and sparse index and value) lies
/// inside its buffer view, and the view inside its buffer.
fn check_extent(
    path: &Path,
    a: &Accessor,
    buffers: &[gltf::buffer::Data],
) -> Result<(), CharacterError> {
    let name = label(a);
    let count = a.count();
    if count == 0 || count > MAX_ELEMENTS {
        return Err(fail(
            path,
            format!("{name} declares {count} elements (1 to {MAX_ELEMENTS} are read)"),
        ));
    }
    if count.saturating_mul(a.size()) > MAX_BYTES {
        return Err(fail(
            path,
            format!(
                "{name}: {count} elements of {} bytes are more than 256 MiB",
                a.size()
            ),
        ));
    }
    match a.view() {
        Some(view) => fits(path, &name, &view, a.offset(), count, a.size(), buffers)?,
        None if a.sparse().is_none() => {
            return Err(fail(
                path,
                format!("{name} has no bufferView and is not sparse"),
            ));
        }
        None => {}
    }
    if let Some(sparse) = a.sparse() {
        let n = sparse.count();
        if n == 0 || n > count {
            return Err(fail(
                path,
                format!("{name} has {n} sparse values, expected 1 to its count {count}"),
            ));
        }
        let indices = sparse.indices();
        let what = format!("{name} sparse indices");
        let size = indices.index_type().size();
        fits(
            path,
            &what,
            &indices.view(),
            indices.offset(),
            n,
            size,
            buffers,
        )?;
        let values = sparse.values();
        let what = format!("{name} sparse values");
        fits(
            path,
            &what,
            &values.view(),
            values.offset(),
            n,
            a.size(),
            buffers,
        )?;
    }
    Ok(())
}

/// `count` elements of `size` bytes from `offset` in `view` (at its stride) fit in the
/// view, and the view fits in its buffer.
fn fits(
    path: &Path,
    what: &str,
    view: &gltf::buffer::View,
    offset: usize,
    count: usize,
    size: usize,
    buffers: &[gltf::buffer::Data],
) -> Result<(), CharacterError> {
    let buffer = view.buffer().index();
    let have = buffers.get(buffer).map_or(0, |b| b.len());
    let view_end = view.offset().checked_add(view.length());
    if view_end.is_none_or(|end| end > have) {
        return Err(fail(
            path,
            format!(
                "buffer view {} (bytes {}..+{}) overruns buffer {buffer} of {have} bytes",
                view.index(),
                view.offset(),
                view.length()
            ),
        ));
    }
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return Err(fail(
            path,
            format!("{what}: stride {stride} is less than the element size {size}"),
        ));
    }
    let need = stride
        .checked_mul(count - 1)
        .and_then(|n| n.checked_add(size))
        .and_then(|n| n.checked_add(offset));
    match need {
        Some(need) if need <= view.length() => Ok(()),
        _ => Err(fail(
            path,
            format!(
                "{what}: {count} elements of {size} bytes from byte {offset} overrun buffer view {} of {} bytes",
                view.index(),
                view.length()
            ),
        )),
    }
}
