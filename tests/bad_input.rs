//! Regression tests for issue #18: every malformed input found by hand (glTF accessors,
//! non-finite meshes, datasets, bundles, PLY files, key scripts, write errors) gets a
//! named error — from the library, and from the binary as one line with a non-zero exit.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::{Value, json};
use unica::avatar::character::load_character;

fn unica(args: &[&str]) -> Output {
    common::unica_command(args)
        .output()
        .expect("the unica binary runs")
}

/// A failure: non-zero exit, no panic or abort, one `unica: error:` line holding every
/// needle.
fn assert_one_line_error(out: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "should fail cleanly: {err}");
    let line = common::error_line(out);
    for needle in needles {
        assert!(line.contains(needle), "expected '{needle}' in: {line}");
    }
}

// ---------- glTF ----------

/// A skinned triangle: positions, u16 indices, joints, weights, one inverse bind matrix.
fn triangle_bin(positions: [[f32; 3]; 3], weight: f32) -> Vec<u8> {
    let mut bin = Vec::new();
    for p in positions.iter().flatten() {
        bin.extend(p.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0] {
        bin.extend(i.to_le_bytes()); // 3 indices and padding
    }
    for _ in 0..3 {
        for j in [0u16; 4] {
            bin.extend(j.to_le_bytes());
        }
    }
    for _ in 0..3 {
        for w in [weight, 0.0, 0.0, 0.0] {
            bin.extend(w.to_le_bytes());
        }
    }
    let identity = glam::Mat4::IDENTITY.to_cols_array();
    for v in identity {
        bin.extend(v.to_le_bytes());
    }
    bin
}

fn triangle_json(bin_len: usize) -> Value {
    let view = |offset: usize, length: usize| json!({"buffer": 0, "byteOffset": offset, "byteLength": length});
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "skin": 0, "name": "body"}, {"name": "hip"}],
        "skins": [{"joints": [1], "inverseBindMatrices": 4}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3},
            "indices": 1
        }]}],
        "buffers": [{"uri": "t.bin", "byteLength": bin_len}],
        "bufferViews": [view(0, 36), view(36, 6), view(44, 24), view(68, 48), view(116, 64)],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5123, "count": 3, "type": "VEC4"},
            {"bufferView": 3, "componentType": 5126, "count": 3, "type": "VEC4"},
            {"bufferView": 4, "componentType": 5126, "count": 1, "type": "MAT4"}
        ]
    })
}

const GOOD: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// Writes `t.gltf` + `t.bin` into `dir` after `edit` changes the JSON.
fn write_gltf(dir: &Path, bin: &[u8], edit: impl FnOnce(&mut Value)) -> PathBuf {
    let mut doc = triangle_json(bin.len());
    edit(&mut doc);
    std::fs::write(dir.join("t.bin"), bin).unwrap();
    let path = dir.join("t.gltf");
    std::fs::write(&path, serde_json::to_vec(&doc).unwrap()).unwrap();
    path
}

/// The load error of the glTF after `edit`, which must name the file.
fn gltf_error(bin: &[u8], edit: impl FnOnce(&mut Value)) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = write_gltf(dir.path(), bin, edit);
    let err = load_character(&path).expect_err("must fail").to_string();
    assert!(err.contains("t.gltf") || err.contains("t.bin"), "{err}");
    err
}

#[test]
fn the_test_triangle_itself_loads() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_gltf(dir.path(), &triangle_bin(GOOD, 1.0), |_| {});
    let c = load_character(&path).unwrap();
    assert_eq!(c.skinned.bind.indices, [0, 1, 2]);
}

#[test]
fn a_sparse_accessor_of_2_pow_44_elements_is_refused_before_allocating() {
    let err = gltf_error(&triangle_bin(GOOD, 1.0), |doc| {
        doc["accessors"][0] = json!({
            "componentType": 5126, "count": 1u64 << 44, "type": "VEC3",
            "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0],
            "sparse": {"count": 1,
                       "indices": {"bufferView": 1, "componentType": 5123},
                       "values": {"bufferView": 0}}
        });
    });
    assert!(
        err.contains("accessor 0 declares 17592186044416 elements"),
        "{err}"
    );
}

#[test]
fn a_huge_accessor_count_is_named_not_reported_as_a_missing_position() {
    let err = gltf_error(&triangle_bin(GOOD, 1.0), |doc| {
        doc["accessors"][0]["count"] = json!(1_000_000_000_000u64);
    });
    assert!(
        err.contains("accessor 0 declares 1000000000000 elements"),
        "{err}"
    );
    assert!(!err.contains("no POSITION"), "{err}");
}

#[test]
fn an_accessor_whose_count_does_not_fit_is_an_error_naming_it() {
    // (accessor, the count it is made to declare, what the error must say): the indices
    // overrunning their buffer view, the inverse bind matrices overrunning theirs, and an
    // index count that is not a multiple of 3.
    let cases: [(usize, u64, &[&str]); 3] = [
        (1, 300, &["accessor 1", "overrun buffer view 1"]),
        (4, 2, &["accessor 4", "overrun"]),
        (1, 2, &["2 indices, not a multiple of 3"]),
    ];
    for (accessor, count, says) in cases {
        let err = gltf_error(&triangle_bin(GOOD, 1.0), |doc| {
            doc["accessors"][accessor]["count"] = json!(count);
        });
        assert!(
            says.iter().all(|s| err.contains(s)),
            "accessor {accessor} declaring {count}: {err}"
        );
    }
}

#[test]
fn non_finite_vertices_and_weights_are_named() {
    for bad in [f32::NAN, f32::INFINITY] {
        let mut positions = GOOD;
        positions[1][2] = bad;
        let err = gltf_error(&triangle_bin(positions, 1.0), |_| {});
        assert!(err.contains("vertex 1 has a non-finite position"), "{err}");
    }
    let err = gltf_error(&triangle_bin([[f32::NAN; 3]; 3], 1.0), |_| {});
    assert!(err.contains("vertex 0 has a non-finite position"), "{err}");
    let err = gltf_error(&triangle_bin(GOOD, f32::NAN), |_| {});
    assert!(err.contains("weights") && err.contains("NaN"), "{err}");
}

#[test]
fn empty_and_garbage_glb_files_and_a_missing_bin_say_so() {
    let dir = tempfile::tempdir().unwrap();
    let glb = dir.path().join("x.glb");
    std::fs::write(&glb, b"").unwrap();
    let err = load_character(&glb).err().unwrap().to_string();
    assert!(err.contains("x.glb: the file is empty"), "{err}");
    std::fs::write(&glb, b"\x01\x02garbage\x00\x7f").unwrap();
    let err = load_character(&glb).err().unwrap().to_string();
    assert!(err.contains("x.glb: not a GLB file"), "{err}");
    std::fs::write(&glb, b"glTF\x02\x00\x00\x00\xff\x00\x00\x00").unwrap();
    let err = load_character(&glb).err().unwrap().to_string();
    assert!(err.contains("x.glb: not a valid GLB file"), "{err}");

    let path = write_gltf(dir.path(), &triangle_bin(GOOD, 1.0), |_| {});
    std::fs::remove_file(dir.path().join("t.bin")).unwrap();
    let err = load_character(&path).err().unwrap().to_string();
    assert!(
        err.contains("t.bin: no such file (buffer 0 of t.gltf)"),
        "{err}"
    );
}

#[test]
fn buffer_and_image_uris_are_relative_paths_or_data_and_nothing_else() {
    let bin = triangle_bin(GOOD, 1.0);
    let cases = [
        (
            "http://example.com/t.bin",
            "is not a relative file path or a data: URI",
        ),
        (
            "file:///etc/passwd",
            "is not a relative file path or a data: URI",
        ),
        ("ftp:t.bin", "is not a relative file path or a data: URI"),
        ("/etc/passwd", "is an absolute path"),
        ("\\\\server\\share\\t.bin", "is an absolute path"),
    ];
    for (uri, why) in cases {
        let err = gltf_error(&bin, |doc| doc["buffers"][0]["uri"] = json!(uri));
        assert!(
            err.contains("t.gltf") && err.contains(&format!("buffer 0's URI '{uri}' {why}")),
            "{uri}: {err}"
        );
        let err = gltf_error(&bin, |doc| doc["images"] = json!([{"uri": uri}]));
        assert!(
            err.contains(&format!("image 0's URI '{uri}' {why}")),
            "{uri}: {err}"
        );
    }
    // A relative path beside the file, and inline data, load.
    let dir = tempfile::tempdir().unwrap();
    let inline = format!(
        "data:application/octet-stream;base64,{}",
        base64_encode(&bin)
    );
    let path = write_gltf(dir.path(), &bin, |doc| {
        doc["buffers"][0]["uri"] = json!(inline)
    });
    load_character(&path).unwrap();
}

/// Standard base64 (for a `data:` URI).
fn base64_encode(bytes: &[u8]) -> String {
    const ALPHABET: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[test]
fn bake_reports_a_bad_character_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    // All vertices NaN: this panicked in the spring placement (a clamp).
    let bake = |character: &Path, out: &str| {
        let out = dir.path().join(out);
        let (character, out) = (character.to_str().unwrap(), out.to_str().unwrap());
        unica(&["bake", character, "--out", out, "--quick"])
    };
    let path = write_gltf(dir.path(), &triangle_bin([[f32::NAN; 3]; 3], 1.0), |_| {});
    assert_one_line_error(&bake(&path, "out"), &["t.gltf", "non-finite position"]);
    // An index overrun: this panicked in tensors.rs.
    let path = write_gltf(dir.path(), &triangle_bin(GOOD, 1.0), |doc| {
        doc["accessors"][1]["count"] = json!(30);
    });
    assert_one_line_error(&bake(&path, "out2"), &["t.gltf", "overrun"]);
}

// ---------- key scripts ----------

#[test]
fn huge_key_scripts_are_refused_by_render_and_the_app() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r");
    for keys in ["99999999999999W", "3000000000W"] {
        let render = unica(&[
            "render",
            "--teacher",
            "missing.gltf",
            "--keys",
            keys,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_one_line_error(&render, &["--keys", "more than 1,000,000 frames"]);
        let app = unica(&["--keys", keys, "--exit-after", "1"]);
        assert_one_line_error(&app, &["--keys", "more than 1,000,000 frames"]);
    }
}

// ---------- datasets ----------

/// A copy of the quick dataset fixture.
fn dataset_copy() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/dataset_quick");
    std::fs::create_dir(dir.path().join("clips")).unwrap();
    for entry in ["manifest.json", "reference.safetensors"] {
        std::fs::copy(src.join(entry), dir.path().join(entry)).unwrap();
    }
    for entry in std::fs::read_dir(src.join("clips")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(
            entry.path(),
            dir.path().join("clips").join(entry.file_name()),
        )
        .unwrap();
    }
    dir
}

/// Overwrites element `index` of tensor `name` in a safetensors file with `bytes`.
fn patch_tensor(path: &Path, name: &str, index: usize, bytes: [u8; 4]) {
    let mut data = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(data[..8].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&data[8..8 + n]).unwrap();
    let start = header[name]["data_offsets"][0].as_u64().unwrap() as usize;
    let at = 8 + n + start + 4 * index;
    data[at..at + 4].copy_from_slice(&bytes);
    std::fs::write(path, data).unwrap();
}

#[test]
fn validate_names_reference_indices_out_of_range() {
    for (tensor, needle) in [
        ("joints", "'joints' holds 9999, outside 0..107"),
        ("triangles", "'triangles' holds 9999999, outside 0..13884"),
        (
            "pixel_triangles",
            "'pixel_triangles' holds 9999999, outside 0..6872",
        ),
        ("waist", "'waist' holds 9999999, outside 0..4414"),
    ] {
        let dir = dataset_copy();
        let value: i32 = if tensor == "joints" { 9999 } else { 9_999_999 };
        patch_tensor(
            &dir.path().join("reference.safetensors"),
            tensor,
            0,
            value.to_le_bytes(),
        );
        let err = unica::dataset::validate(dir.path())
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("reference.safetensors") && err.contains(needle),
            "{err}"
        );
        if tensor == "waist" {
            let out = unica(&["validate", dir.path().to_str().unwrap()]);
            assert_one_line_error(&out, &["reference.safetensors", needle]);
        }
    }
}

#[test]
fn validate_refuses_a_manifest_without_clips_and_a_nan_reference() {
    let dir = dataset_copy();
    let manifest = dir.path().join("manifest.json");
    let mut json: Value = serde_json::from_slice(&std::fs::read(&manifest).unwrap()).unwrap();
    json["clips"] = json!([]);
    std::fs::write(&manifest, serde_json::to_vec(&json).unwrap()).unwrap();
    let err = unica::dataset::validate(dir.path())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("manifest.json: the manifest lists no clips"),
        "{err}"
    );

    let dir = dataset_copy();
    let reference = dir.path().join("reference.safetensors");
    patch_tensor(&reference, "bind_positions", 5, f32::NAN.to_le_bytes());
    let err = unica::dataset::validate(dir.path())
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("'bind_positions' holds a non-finite value"),
        "{err}"
    );
}

// ---------- bundles ----------

/// The manifest error after `edit`.
fn manifest_error(edit: impl FnOnce(&mut Value)) -> String {
    let dir = tempfile::tempdir().unwrap();
    let mut json: Value = serde_json::from_slice(
        &std::fs::read(common::shipped_bundle("witch").join("manifest.json")).unwrap(),
    )
    .unwrap();
    edit(&mut json);
    let path = dir.path().join("manifest.json");
    std::fs::write(&path, serde_json::to_vec(&json).unwrap()).unwrap();
    let err = unica::engine::bundle::read_manifest(&path)
        .expect_err("must fail")
        .to_string();
    assert!(err.contains("manifest.json"), "{err}");
    err
}

#[test]
fn bundle_manifests_with_impossible_values_are_refused() {
    type Edit = fn(&mut Value);
    let cases: Vec<(Edit, &str)> = vec![
        (
            |j| j["diffusion"]["steps"] = json!(1_000_000_000_000_000u64),
            "diffusion.steps 1000000000000000",
        ),
        (|j| j["diffusion"]["steps"] = json!(1), "diffusion.steps 1:"),
        (
            |j| j["diffusion"]["beta_start"] = json!(-0.001),
            "diffusion betas -0.001",
        ),
        (
            |j| j["latent_scale"] = json!(0.0),
            "latent_scale 0 is not a positive number",
        ),
        (
            |j| j["normalisation"]["scale"] = json!(0.0),
            "normalisation.scale 0",
        ),
        (
            |j| j["version"] = json!("1"),
            "bundle version \"1\" is not a whole number",
        ),
        (
            |j| j["root_motion"] = json!("sideways"),
            "unknown variant `sideways`",
        ),
        (|j| j["heading"] = json!("north"), "unknown variant `north`"),
        (
            |j| j["stand_speed"] = json!(-0.1),
            "stand_speed -0.1 is not a positive number",
        ),
    ];
    for (edit, needle) in cases {
        let err = manifest_error(edit);
        assert!(err.contains(needle), "expected '{needle}' in {err}");
    }
}

/// A copy of the shipped Witch bundle in `dir/bundle`.
fn witch_bundle_copy(dir: &Path) -> PathBuf {
    let bundle = dir.join("bundle");
    std::fs::create_dir(&bundle).unwrap();
    for file in ["manifest.json", "weights.safetensors"] {
        std::fs::copy(
            common::shipped_bundle("witch").join(file),
            bundle.join(file),
        )
        .unwrap();
    }
    bundle
}

/// Rewrites `bundle`'s manifest.json after `edit`.
fn edit_manifest(bundle: &Path, edit: impl FnOnce(&mut Value)) {
    let manifest = bundle.join("manifest.json");
    let mut json: Value =
        serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    edit(&mut json);
    std::fs::write(&manifest, serde_json::to_vec(&json).unwrap()).unwrap();
}

/// `unica render --bundle BUNDLE --keys 1I --out OUT`.
fn render_bundle(bundle: &Path, out: &Path) -> Output {
    unica(&[
        "render",
        "--bundle",
        bundle.to_str().unwrap(),
        "--keys",
        "1I",
        "--out",
        out.to_str().unwrap(),
    ])
}

#[test]
fn render_refuses_a_bundle_with_a_nan_weight_or_a_huge_step_count() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = witch_bundle_copy(dir.path());
    patch_tensor(
        &bundle.join("weights.safetensors"),
        "pca.mean",
        7,
        f32::NAN.to_le_bytes(),
    );
    let out = dir.path().join("out");
    assert_one_line_error(
        &render_bundle(&bundle, &out),
        &[
            "weights.safetensors",
            "tensor 'pca.mean' holds NaN at index 7",
        ],
    );
    edit_manifest(&bundle, |j| {
        j["diffusion"]["steps"] = json!(1_000_000_000_000_000u64)
    });
    assert_one_line_error(
        &render_bundle(&bundle, &out),
        &["manifest.json", "diffusion.steps"],
    );
    let app = unica(&["--bundle", bundle.to_str().unwrap(), "--exit-after", "1"]);
    assert_one_line_error(&app, &["manifest.json", "diffusion.steps"]);
}

#[test]
fn render_refuses_a_refiner_whose_pixel_residuals_are_not_the_maps() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = witch_bundle_copy(dir.path());
    edit_manifest(&bundle, |j| j["refiner"]["pixel_residuals"] = json!(17));
    assert_one_line_error(
        &render_bundle(&bundle, &dir.path().join("out")),
        &[
            "weights.safetensors",
            "the refiner's pixel_residuals (17) are not the map's 4414 foreground pixels",
        ],
    );
}

// ---------- PLY ----------

use unica::splat::ply::{Splat, decode, encode};

fn splat() -> Splat {
    Splat {
        position: glam::Vec3::new(0.1, 0.2, 0.3),
        f_dc: glam::Vec3::ZERO,
        opacity: 0.5,
        scale: glam::Vec3::splat(0.01),
        rotation: glam::Quat::IDENTITY,
    }
}

/// A one-splat binary file with float `field` (of the 17 written) set to `value`.
fn with_field(field: usize, value: f32) -> Vec<u8> {
    let mut bytes = encode(&[splat()]);
    let body = bytes.len() - 17 * 4;
    bytes[body + 4 * field..body + 4 * field + 4].copy_from_slice(&value.to_le_bytes());
    bytes
}

#[test]
fn ply_files_with_nothing_to_draw_are_refused() {
    let err = decode(&encode(&[])).unwrap_err();
    assert!(err.contains("0 vertices"), "{err}");
    let cases = [
        (0, f32::NAN, "vertex 0: 'x' is NaN"),
        (2, f32::INFINITY, "vertex 0: 'z' is inf"),
        (9, f32::NAN, "vertex 0: 'opacity' is NaN"),
        (10, f32::NAN, "vertex 0: 'scale_0' is NaN"),
        (11, 200.0, "vertex 0: a scale overflows"),
    ];
    for (field, value, needle) in cases {
        let err = decode(&with_field(field, value)).unwrap_err();
        assert!(err.contains(needle), "expected '{needle}' in {err}");
    }
    let mut zero = encode(&[splat()]);
    let body = zero.len() - 4 * 4;
    zero[body..].fill(0);
    let err = decode(&zero).unwrap_err();
    assert!(err.contains("rotation quaternion is zero"), "{err}");
}

#[test]
fn ply_elements_in_any_order_and_crlf_headers_are_read() {
    let good = encode(&[splat()]);
    let text = String::from_utf8_lossy(&good).into_owned();
    let header_len = text.find("end_header\n").unwrap() + "end_header\n".len();
    let (header, body) = good.split_at(header_len);
    let header = String::from_utf8(header.to_vec()).unwrap();
    // Binary: a face element (one triangle) before the vertices.
    let moved = header.replace(
        "element vertex 1\n",
        "element face 1\nproperty list uchar int vertex_indices\nelement vertex 1\n",
    );
    let mut bytes = moved.into_bytes();
    bytes.push(3);
    for i in [0i32, 0, 0] {
        bytes.extend(i.to_le_bytes());
    }
    bytes.extend(body);
    let got = decode(&bytes).unwrap();
    assert!(
        got[0].position.distance(splat().position) < 1e-6,
        "{:?}",
        got[0]
    );
    // CRLF line ends.
    let crlf = header.replace('\n', "\r\n");
    let got = decode(&[crlf.as_bytes(), body].concat()).unwrap();
    assert!(got[0].position.distance(splat().position) < 1e-6);
    // ASCII with a face first.
    let names: Vec<&str> = header
        .lines()
        .filter_map(|l| l.strip_prefix("property float "))
        .collect();
    let values: Vec<String> = body
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()).to_string())
        .collect();
    let mut ascii = "ply\r\nformat ascii 1.0\r\nelement face 2\r\nproperty list uchar int vertex_indices\r\nelement vertex 1\r\n".to_string();
    for name in &names {
        ascii += &format!("property float {name}\r\n");
    }
    ascii += &format!(
        "end_header\r\n3 0 0 0\r\n4 0 0 0 0\r\n{}\r\n",
        values.join(" ")
    );
    let got = decode(ascii.as_bytes()).unwrap();
    assert!(got[0].position.distance(splat().position) < 1e-6);
}

#[test]
fn view_refuses_an_empty_ply_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("empty.ply");
    std::fs::write(&path, encode(&[])).unwrap();
    let out = unica(&["view", path.to_str().unwrap(), "--exit-after", "1"]);
    assert_one_line_error(&out, &["empty.ply", "0 vertices"]);
}

#[test]
fn absurd_splats_are_dropped_with_a_line_that_says_how_many_and_why() {
    // Log-scales of 80 (5e34 m) and a splat 1e6 m away, beside a sane one.
    let huge = Splat {
        scale: glam::Vec3::splat(80f32.exp()),
        ..splat()
    };
    let far = Splat {
        position: glam::Vec3::new(1e6, 0.0, 0.0),
        ..splat()
    };
    let kept = unica::splat::files::Kept::sane(vec![huge, splat(), far, huge]);
    assert_eq!((kept.splats.len(), kept.too_large, kept.too_far), (1, 2, 1));
    assert_eq!(
        kept.note().unwrap(),
        "dropped 3 of 4 splats: 2 larger than 1000 m, 1 farther than 100 km from the origin"
    );
    assert_eq!(unica::splat::files::Kept::sane(vec![splat()]).note(), None);
    // Through the file reader: every splat absurd is an error naming the file, and `view`
    // refuses it in one line before a window opens.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("huge.ply");
    std::fs::write(&path, encode(&[huge, huge])).unwrap();
    let err = unica::splat::files::read(&path, Default::default()).unwrap_err();
    assert!(err.to_string().contains("huge.ply"), "{err}");
    let out = unica(&["view", path.to_str().unwrap(), "--exit-after", "1"]);
    assert_one_line_error(
        &out,
        &[
            "huge.ply",
            "every one of its 2 splats is absurd: 2 larger than 1000 m",
        ],
    );
    // A file with some sane splats reads them, and says what it dropped.
    let mixed = dir.path().join("mixed.ply");
    std::fs::write(&mixed, encode(&[huge, splat(), far])).unwrap();
    let kept = unica::splat::files::read(&mixed, Default::default()).unwrap();
    assert_eq!(kept.splats.len(), 1);
    assert!(kept.note().unwrap().starts_with("dropped 2 of 3 splats"));
}

#[test]
fn view_refuses_malformed_compressed_plys_and_truncated_splat_files_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let view = |name: &str, bytes: &[u8]| {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        unica(&["view", path.to_str().unwrap(), "--exit-after", "1"])
    };
    // The file itself is well formed: 300 zero splats in 2 chunks decode.
    let good = common::compressed_ply(2, 300);
    assert_eq!(decode(&good).unwrap().len(), 300);
    assert_one_line_error(
        &view("few_chunks.ply", &common::compressed_ply(1, 300)),
        &[
            "few_chunks.ply",
            "300 vertices need 2 chunks of 256, the 'chunk' element has 1",
        ],
    );
    assert_one_line_error(
        &view("no_chunk.ply", &common::compressed_ply(0, 10)),
        &["no_chunk.ply", "needs a 'chunk' element"],
    );
    assert_one_line_error(
        &view("cut.ply", &good[..good.len() - 3]),
        &["cut.ply", "truncated", "'vertex'"],
    );
    // .splat: 32 bytes per splat; 2.5 splats, and none.
    assert_one_line_error(
        &view("cut.splat", &[0u8; 80]),
        &["cut.splat", "truncated: 80 bytes"],
    );
    assert_one_line_error(&view("empty.splat", &[]), &["empty.splat", "empty"]);
    // An up axis that is neither y nor z.
    let out = unica(&["view", "any.ply", "--up", "x"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("'x' is not an up axis"),
        "{err}"
    );
}

// ---------- write errors ----------

#[test]
fn a_write_error_names_its_cause_once() {
    let e = unica::files::WriteError {
        path: PathBuf::from("/full/frame.png"),
        source: std::io::Error::other("No space left on device"),
    };
    let chained = format!("{:#}", anyhow::Error::from(e));
    assert_eq!(chained.matches("No space left").count(), 1, "{chained}");
    assert!(
        chained.contains("could not write /full/frame.png"),
        "{chained}"
    );
}

// ---------- start-up noise ----------

#[test]
fn no_xdg_runtime_dir_complaint_without_a_wayland_session() {
    let out = Command::new(env!("CARGO_BIN_EXE_unica"))
        .arg("adapters")
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("DISPLAY")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

// ---------- avatar descriptions (found by tests/fuzz.rs) ----------

#[test]
fn descriptions_with_huge_chain_counts_or_speeds_are_refused() {
    use unica::avatar::description::Description;
    let path = Path::new("x.avatar.json");
    let base = || {
        json!({"clips": {"idle": "Idle", "walk": "Walk", "run": "Run"},
               "waist_bones": ["hip"], "feet": ["hip"], "forward": "+z"})
    };
    let part = |chains: u64, segments: u64| {
        let mut d = base();
        d["loose_parts"] = json!([{"name": "skirt", "kind": "ring", "parent_bone": "hip",
                                   "chains": chains, "segments": segments}]);
        d.to_string()
    };
    assert!(Description::parse(&part(3, 2), path).is_ok());
    // 2^31 chains aborted on a 51 GB allocation.
    let err = Description::parse(&part(2_147_483_647, 2), path)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("x.avatar.json: loose part 'skirt': 2147483647 chains"),
        "{err}"
    );
    let err = Description::parse(&part(3, 0), path)
        .unwrap_err()
        .to_string();
    assert!(err.contains("3 chains of 0 segments"), "{err}");
    // A run speed of 1e308 made the clip time infinite: a panic in clip sampling.
    let mut fast = base();
    fast["run_speed"] = json!(1e308);
    let err = Description::parse(&fast.to_string(), path)
        .unwrap_err()
        .to_string();
    assert!(err.contains("run_speed Some(inf) is not a speed"), "{err}");
}

// ---------- unica make ----------

#[test]
fn make_refuses_a_missing_character_a_foreign_folder_and_a_missing_trainer() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("made");
    let out_s = out.to_str().unwrap();
    let missing = dir.path().join("nobody.glb");
    let run = |args: &[&str], python: &str| {
        Command::new(env!("CARGO_BIN_EXE_unica"))
            .args(args)
            .env("UNICA_PYTHON", python)
            .output()
            .expect("the unica binary runs")
    };
    let out1 = run(
        &["make", missing.to_str().unwrap(), "--out", out_s, "--quick"],
        "python3",
    );
    assert_one_line_error(&out1, &["nobody.glb: no such character file"]);

    // A folder made from another character is not overwritten.
    std::fs::create_dir_all(&out).unwrap();
    let state = json!({"asked": {"character": "/elsewhere/other.glb", "quick": true,
                                 "avatar": null}, "done": ["bake"]});
    std::fs::write(out.join("make.json"), state.to_string()).unwrap();
    let witch = common::witch();
    let out2 = run(
        &["make", witch.to_str().unwrap(), "--out", out_s, "--quick"],
        "python3",
    );
    assert_one_line_error(
        &out2,
        &["make.json: this folder holds a make of /elsewhere/other.glb"],
    );
    assert_eq!(
        std::fs::read_to_string(out.join("make.json")).unwrap(),
        state.to_string(),
        "the other make's state is kept"
    );

    // No trainer: one line before any stage runs.
    std::fs::remove_file(out.join("make.json")).unwrap();
    let out3 = run(
        &["make", witch.to_str().unwrap(), "--out", out_s, "--quick"],
        "false",
    );
    assert_one_line_error(
        &out3,
        &["false cannot run the trainer", "pip install -e ./train"],
    );
    assert!(!out.join("data").exists(), "nothing was baked");
}
