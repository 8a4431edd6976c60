//! A mutation fuzzer on stable Rust for every parser of untrusted input: glTF (JSON and
//! GLB), VRM 1.0's extensions, OBJ, binary, ASCII and compressed PLY, antimatter15's
//! .splat, safetensors, bundle and dataset manifests, the dataset's render manifest,
//! avatar descriptions and key scripts. Every JSON target also starts from seeds built to
//! exhaust ([`exhausting`]). Real seed files are mutated by a small deterministic
//! mutator (bit flips, interesting bytes and numbers, cuts, splices); every execution
//! must return (Ok or a named error) without a panic, without an abort and with bounded
//! memory: a counting allocator refuses any allocation over 1 GiB (the process then
//! aborts and the test fails, leaving the input in target/fuzz/<target>.current) and
//! checks the peak of live memory.
//!
//! The test suite runs a short budget (`FUZZ_SECONDS` per target, ≤ 60 s in all). The
//! long run (docs/status.md has its figures): `UNICA_FUZZ_EXECS=1000000 cargo test
//! --release --test fuzz -- --nocapture` (executions per target; no time limit then).

use std::alloc::{GlobalAlloc, Layout, System};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use unica::avatar::character::{Character, load_character};

mod common;

// ---------- bounded memory ----------

/// Live bytes, their peak, and the cap on one allocation and on the peak.
static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
const GIB: usize = 1 << 30;

struct Counting;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > GIB {
            return std::ptr::null_mut(); // the caller aborts: the run fails loudly
        }
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        unsafe { System.dealloc(p, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

// ---------- the mutator ----------

/// xorshift64*: deterministic, seeded per target.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const NUMBERS: &[&str] = &[
    "0",
    "1",
    "-1",
    "2",
    "3",
    "255",
    "65536",
    "2147483647",
    "4294967295",
    "4294967296",
    "17592186044416",
    "1000000000000",
    "1000000000000000",
    "18446744073709551615",
    "18446744073709551616",
    "1e15",
    "1e308",
    "-1e308",
    "NaN",
    "nan",
    "inf",
    "-0",
    "0.5",
    "\"1\"",
    "null",
    "[]",
    "{}",
];

const WORDS: &[u32] = &[
    0,
    1,
    0xff,
    0xffff,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x7fc0_0000, // NaN
    0x7f80_0000, // inf
    0xff80_0000, // -inf
];

/// One to four stacked mutations of `input`, sometimes spliced with `other`.
fn mutate(rng: &mut Rng, input: &[u8], other: &[u8]) -> Vec<u8> {
    let mut data = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = data.len();
        match rng.below(10) {
            0 if len > 0 => {
                let i = rng.below(len);
                data[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                data[i] = rng.next() as u8;
            }
            2 if len > 0 => {
                // Cut a range.
                let a = rng.below(len);
                let b = (a + 1 + rng.below(16)).min(len);
                data.drain(a..b);
            }
            3 if len > 0 => {
                // Duplicate a range.
                let a = rng.below(len);
                let b = (a + 1 + rng.below(64)).min(len);
                let copy = data[a..b].to_vec();
                let at = rng.below(len);
                data.splice(at..at, copy);
            }
            4 | 5 => {
                // Replace a run of digits (or insert) with an interesting number.
                let number = NUMBERS[rng.below(NUMBERS.len())].as_bytes();
                let digits: Vec<usize> = (0..len).filter(|&i| data[i].is_ascii_digit()).collect();
                if digits.is_empty() {
                    let at = rng.below(len + 1);
                    data.splice(at..at, number.iter().copied());
                } else {
                    let start = digits[rng.below(digits.len())];
                    let end = (start..len)
                        .find(|&i| !(data[i].is_ascii_digit() || data[i] == b'.'))
                        .unwrap_or(len);
                    data.splice(start..end, number.iter().copied());
                }
            }
            6 if len >= 4 => {
                // An interesting 32-bit word (counts, lengths, floats) at any offset.
                let at = rng.below(len - 3);
                let word = WORDS[rng.below(WORDS.len())].to_le_bytes();
                data[at..at + 4].copy_from_slice(&word);
            }
            7 if len > 0 => data.truncate(rng.below(len)),
            8 if !other.is_empty() => {
                // Splice in part of another seed.
                let a = rng.below(other.len());
                let b = (a + 1 + rng.below(256)).min(other.len());
                let at = rng.below(len + 1);
                data.splice(at..at, other[a..b].iter().copied());
            }
            _ => {
                let at = rng.below(len + 1);
                let bytes = b"\0\n\r\" ,:[]{}-.eE";
                data.insert(at, bytes[rng.below(bytes.len())]);
            }
        }
    }
    data
}

// ---------- the runner ----------

/// Per-target executions (the long run) or the short default.
fn budget() -> (usize, Option<Duration>) {
    match std::env::var("UNICA_FUZZ_EXECS") {
        Ok(n) => (n.parse().expect("UNICA_FUZZ_EXECS is a number"), None),
        Err(_) => (usize::MAX, Some(Duration::from_secs(FUZZ_SECONDS))),
    }
}

/// Seconds per target in the test suite (14 targets).
const FUZZ_SECONDS: u64 = 4;

fn work_dir(target: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("fuzz")
        .join(target);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Mutates `seeds` and runs `exec` on each input (the input is also in
/// `<work dir>/<file>` for the targets that read files); fails on any panic, an
/// execution over 30 s, or live memory over 1 GiB.
fn fuzz(target: &str, file: &str, seeds: &[Vec<u8>], exec: impl Fn(&Path, &[u8]) -> bool) {
    fuzz_in(&work_dir(target), target, file, seeds, exec)
}

/// [`fuzz`] with the input written in `dir` (where a reader expects it beside other files).
fn fuzz_in(
    dir: &Path,
    target: &str,
    file: &str,
    seeds: &[Vec<u8>],
    exec: impl Fn(&Path, &[u8]) -> bool,
) {
    for seed in seeds {
        assert!(!seed.is_empty());
    }
    let path = dir.join(file);
    let (execs, time) = budget();
    let started = Instant::now();
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15 ^ target.bytes().fold(7, |h, b| h * 31 + b as u64));
    let (mut done, mut accepted, mut panics, mut slowest) = (0, 0, Vec::new(), Duration::ZERO);
    while done < execs && time.is_none_or(|t| started.elapsed() < t) {
        let seed = &seeds[rng.below(seeds.len())];
        let other = &seeds[rng.below(seeds.len())];
        // The seeds themselves first, then mutants.
        let input = if done < seeds.len() {
            seeds[done].clone()
        } else {
            mutate(&mut rng, seed, other)
        };
        std::fs::write(&path, &input).unwrap();
        let clock = Instant::now();
        match catch_unwind(AssertUnwindSafe(|| exec(&path, &input))) {
            Ok(ok) => accepted += usize::from(ok),
            Err(_) => {
                let saved = dir.join(format!("panic-{}", panics.len()));
                std::fs::write(&saved, &input).unwrap();
                panics.push(saved);
            }
        }
        slowest = slowest.max(clock.elapsed());
        done += 1;
    }
    // The whole test process's peak of live heap memory (targets run side by side).
    let peak = PEAK.load(Ordering::Relaxed);
    println!(
        "fuzz {target}: {done} executions in {:.1} s, {} panics, 0 aborts, {accepted} accepted, \
         process heap peak {} KiB, slowest {} ms",
        started.elapsed().as_secs_f64(),
        panics.len(),
        peak >> 10,
        slowest.as_millis()
    );
    assert!(
        panics.is_empty(),
        "{target}: inputs that panicked: {panics:?}"
    );
    assert!(peak > 0, "the counting allocator saw nothing");
    assert!(peak < GIB, "{target}: {peak} bytes live at the peak");
    assert!(
        slowest < Duration::from_secs(30),
        "{target}: an input took {slowest:?}"
    );
    assert!(done >= seeds.len(), "{target}: not even the seeds ran");
}

// ---------- seeds ----------

/// `seed` (a JSON document) and seeds built to exhaust a JSON reader: arrays and objects
/// nested 100,000 deep, and the seed with one of its numbers made huge (4294967295 or
/// 1e308: counts, sizes and indices that would allocate without end if believed), for
/// up to 12 of its numbers spread through it.
fn exhausting(seed: &[u8]) -> Vec<Vec<u8>> {
    const DEEP: usize = 100_000;
    let arrays = format!("{}{}", "[".repeat(DEEP), "]".repeat(DEEP));
    let objects = format!("{}1{}", "{\"a\":".repeat(DEEP), "}".repeat(DEEP));
    let mut out = vec![seed.to_vec(), arrays.into_bytes(), objects.into_bytes()];
    let value: Value = serde_json::from_slice(seed).expect("a JSON seed");
    let numbers = with_number(&value, usize::MAX, &Value::Null).1;
    let step = numbers.div_ceil(12).max(1);
    for (k, at) in (0..numbers).step_by(step).enumerate() {
        let huge = if k % 2 == 0 {
            json!(4294967295u64)
        } else {
            json!(1e308)
        };
        out.push(serde_json::to_vec(&with_number(&value, at, &huge).0).unwrap());
    }
    out
}

/// `v` with its number `at` (counting in document order) replaced by `huge`, and how many
/// numbers it holds.
fn with_number(v: &Value, at: usize, huge: &Value) -> (Value, usize) {
    let mut seen = 0;
    fn walk(v: &Value, at: usize, huge: &Value, seen: &mut usize) -> Value {
        match v {
            Value::Number(_) => {
                *seen += 1;
                if *seen - 1 == at {
                    huge.clone()
                } else {
                    v.clone()
                }
            }
            Value::Array(items) => items.iter().map(|x| walk(x, at, huge, seen)).collect(),
            Value::Object(map) => Value::Object(
                map.iter()
                    .map(|(k, x)| (k.clone(), walk(x, at, huge, seen)))
                    .collect(),
            ),
            _ => v.clone(),
        }
    }
    let out = walk(v, at, huge, &mut seen);
    (out, seen)
}

/// A skinned, animated triangle whose positions have a sparse override: the bytes of its
/// binary buffer.
fn triangle_bin() -> Vec<u8> {
    let mut bin = Vec::new();
    let f = |bin: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|x| bin.extend(x.to_le_bytes()));
    f(&mut bin, &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]); // 0: positions
    [0u16, 1, 2, 0]
        .iter()
        .for_each(|i| bin.extend(i.to_le_bytes())); // 36: indices
    (0..12).for_each(|_| bin.extend(0u16.to_le_bytes())); // 44: joints
    (0..3).for_each(|_| f(&mut bin, &[1.0, 0.0, 0.0, 0.0])); // 68: weights
    f(&mut bin, &glam::Mat4::IDENTITY.to_cols_array()); // 116: inverse bind
    f(&mut bin, &[0.0, 1.0]); // 180: key times
    f(&mut bin, &[0.0, 0.0, 0.0, 0.0, 0.1, 0.0]); // 188: key translations
    [1u16, 0].iter().for_each(|i| bin.extend(i.to_le_bytes())); // 212: sparse index
    f(&mut bin, &[1.5, 0.0, 0.0]); // 216: sparse value
    bin
}

fn triangle_json(buffer: serde_json::Value) -> serde_json::Value {
    let view = |o: usize, l: usize| json!({"buffer": 0, "byteOffset": o, "byteLength": l});
    json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "skin": 0, "name": "body"}, {"name": "hip", "translation": [0.0, 1.0, 0.0]}],
        "skins": [{"joints": [1], "inverseBindMatrices": 4}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "JOINTS_0": 2, "WEIGHTS_0": 3},
            "indices": 1, "material": 0
        }]}],
        "materials": [{"name": "skin", "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.5, 0.4, 1.0]}}],
        "animations": [{"name": "Walk", "channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}],
                        "samplers": [{"input": 5, "output": 6, "interpolation": "LINEAR"}]}],
        "buffers": [buffer],
        "bufferViews": [view(0, 36), view(36, 6), view(44, 24), view(68, 48), view(116, 64),
                        view(180, 8), view(188, 24), view(212, 2), view(216, 12)],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [1.5, 1.0, 0.0],
             "sparse": {"count": 1, "indices": {"bufferView": 7, "componentType": 5123},
                        "values": {"bufferView": 8}}},
            {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5123, "count": 3, "type": "VEC4"},
            {"bufferView": 3, "componentType": 5126, "count": 3, "type": "VEC4"},
            {"bufferView": 4, "componentType": 5126, "count": 1, "type": "MAT4"},
            {"bufferView": 5, "componentType": 5126, "count": 2, "type": "SCALAR", "min": [0.0], "max": [1.0]},
            {"bufferView": 6, "componentType": 5126, "count": 2, "type": "VEC3"}
        ]
    })
}

/// The triangle as one .gltf file with its buffer in a data URI.
fn gltf_seed() -> Vec<u8> {
    use std::fmt::Write;
    let bin = triangle_bin();
    // Base64 by hand (no dependency for one seed).
    const ABC: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut b64 = String::new();
    for chunk in bin.chunks(3) {
        let n = chunk
            .iter()
            .enumerate()
            .fold(0u32, |n, (i, &b)| n | (b as u32) << (16 - 8 * i));
        for k in 0..4 {
            if k <= chunk.len() {
                b64.push(ABC[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                b64.push('=');
            }
        }
    }
    let mut uri = String::from("data:application/octet-stream;base64,");
    write!(uri, "{b64}").unwrap();
    let doc = triangle_json(json!({"uri": uri, "byteLength": bin.len()}));
    serde_json::to_vec_pretty(&doc).unwrap()
}

/// The triangle as a GLB: JSON chunk, BIN chunk.
fn glb_seed() -> Vec<u8> {
    let bin = triangle_bin();
    common::glb(&triangle_json(json!({"byteLength": bin.len()})), &bin)
}

fn character_ok(path: &Path) -> bool {
    load_character(path).is_ok()
}

#[test]
fn fuzz_gltf_json() {
    assert!(character_ok_seed("seed.gltf", &gltf_seed()));
    fuzz("gltf", "input.gltf", &exhausting(&gltf_seed()), |p, _| {
        character_ok(p)
    });
}

/// The triangle with VRM 1.0's humanoid bone map and spring bones (a sphere and a
/// capsule collider, one spring of one joint) in its root extensions.
fn vrm_seed() -> Vec<u8> {
    let mut doc: Value = serde_json::from_slice(&gltf_seed()).unwrap();
    doc["extensionsUsed"] = json!(["VRMC_vrm", "VRMC_springBone"]);
    doc["extensions"] = json!({
        "VRMC_vrm": {"specVersion": "1.0", "humanoid": {"humanBones": {"hips": {"node": 1}}}},
        "VRMC_springBone": {
            "specVersion": "1.0",
            "colliders": [
                {"node": 1, "shape": {"sphere": {"offset": [0.0, 0.1, 0.0], "radius": 0.05}}},
                {"node": 1, "shape": {"capsule": {"offset": [0.0, 0.0, 0.0], "radius": 0.03,
                                                  "tail": [0.0, 0.2, 0.0]}}}
            ],
            "colliderGroups": [{"colliders": [0, 1]}],
            "springs": [{"joints": [{"node": 1, "hitRadius": 0.02, "stiffness": 1.0,
                                     "gravityPower": 0.3, "gravityDir": [0.0, -1.0, 0.0],
                                     "dragForce": 0.4}],
                         "colliderGroups": [0]}]
        }
    });
    serde_json::to_vec_pretty(&doc).unwrap()
}

#[test]
fn fuzz_vrm_extensions() {
    assert!(character_ok_seed("seed_vrm.gltf", &vrm_seed()));
    fuzz("vrm", "input.gltf", &exhausting(&vrm_seed()), |p, _| {
        character_ok(p)
    });
}

#[test]
fn fuzz_glb() {
    assert!(character_ok_seed("seed.glb", &glb_seed()));
    fuzz("glb", "input.glb", &[glb_seed()], |p, _| character_ok(p));
}

/// The seed itself loads (so the fuzzer starts from valid files), with its sparse
/// override, skin and clip.
fn character_ok_seed(name: &str, bytes: &[u8]) -> bool {
    let dir = work_dir("seeds");
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    let c = load_character(&path).unwrap();
    assert_eq!(
        c.skinned.bind.positions[1].x, 1.5,
        "the sparse value applies"
    );
    assert_eq!(c.clips.len(), 1);
    true
}

#[test]
fn fuzz_obj() {
    let cube = b"# a cube\nmtllib none.mtl\no Cube\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\nvn 0 0 1\nvt 0.5 0.5\nusemtl Skin\nf 1/1/1 2/1/1 3/1/1 4/1/1\nf 5 6 7\nf 5 7 8\nf 1 5 8 4\ng hat\nf 2 6 7 3\n".to_vec();
    let tri = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf -1 -2 -3\n".to_vec();
    fuzz("obj", "input.obj", &[cube, tri], |p, _| character_ok(p));
}

fn splats() -> Vec<unica::splat::ply::Splat> {
    (0..4)
        .map(|i| unica::splat::ply::Splat {
            position: glam::Vec3::new(i as f32, 0.5, -0.25),
            f_dc: glam::Vec3::new(0.1, 0.2, 0.3),
            opacity: 0.2 + 0.1 * i as f32,
            scale: glam::Vec3::new(0.01, 0.02, 0.03),
            rotation: glam::Quat::from_rotation_y(i as f32),
        })
        .collect()
}

#[test]
fn fuzz_ply_binary() {
    let binary = unica::splat::ply::encode(&splats());
    let text = String::from_utf8_lossy(&binary).into_owned();
    let with_face = {
        let split = text.find("element vertex").unwrap();
        let mut bytes = binary[..split].to_vec();
        bytes.extend(b"element face 1\nproperty list uchar int vertex_indices\n");
        let header_end = text.find("end_header\n").unwrap() + "end_header\n".len();
        bytes.extend(&binary[split..header_end]);
        bytes.push(3);
        [0i32, 1, 2]
            .iter()
            .for_each(|i| bytes.extend(i.to_le_bytes()));
        bytes.extend(&binary[header_end..]);
        bytes
    };
    assert_eq!(unica::splat::ply::decode(&with_face).unwrap().len(), 4);
    fuzz("ply_binary", "input.ply", &[binary, with_face], |_, b| {
        unica::splat::ply::decode(b).is_ok()
    });
}

#[test]
fn fuzz_ply_ascii() {
    let mut ascii = String::from(
        "ply\nformat ascii 1.0\ncomment by hand\nelement face 1\nproperty list uchar int vertex_indices\nelement vertex 2\n",
    );
    for name in [
        "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
        "rot_0", "rot_1", "rot_2", "rot_3", "f_rest_0",
    ] {
        ascii += &format!("property float {name}\n");
    }
    ascii += "end_header\n3 0 1 1\n0 0 0 0.1 0.2 0.3 0.5 -4 -4 -4 1 0 0 0 0.7\n1 2 3 0 0 0 -0.5 -3 -5 -4 0.7 0.7 0 0 0\n";
    let crlf = ascii.replace('\n', "\r\n");
    assert_eq!(unica::splat::ply::decode(crlf.as_bytes()).unwrap().len(), 2);
    fuzz(
        "ply_ascii",
        "input.ply",
        &[ascii.into_bytes(), crlf.into_bytes()],
        |_, b| unica::splat::ply::decode(b).is_ok(),
    );
}

#[test]
fn fuzz_dot_splat() {
    let seed = unica::splat::dotsplat::encode(&splats());
    assert_eq!(unica::splat::dotsplat::decode(&seed).unwrap().len(), 4);
    fuzz("dot_splat", "input.splat", &[seed], |p, _| {
        unica::splat::files::read(p, Default::default()).is_ok()
    });
}

#[test]
fn fuzz_compressed_ply() {
    // SuperSplat's layout: 2 chunks of bounds, 300 packed vertices; one seed with a zero
    // body, one with its packed words drawn at random (fixed seed).
    let zeros = common::compressed_ply(2, 300);
    let mut drawn = zeros.clone();
    let body = drawn.len() - (48 * 2 + 16 * 300);
    let mut rng = Rng(0x5eed);
    for (i, b) in drawn[body..].iter_mut().enumerate() {
        // The chunk bounds as small floats (min below max), the vertices' words at random.
        *b = if i < 48 * 2 {
            [0u8, 0, 0, 0x3f][i % 4] + u8::from(i % 48 >= 24 && i % 4 == 3)
        } else {
            rng.next() as u8
        };
    }
    for seed in [&zeros, &drawn] {
        assert_eq!(unica::splat::ply::decode(seed).unwrap().len(), 300);
    }
    fuzz("compressed_ply", "input.ply", &[zeros, drawn], |p, _| {
        unica::splat::files::read(p, Default::default()).is_ok()
    });
}

#[test]
fn fuzz_safetensors() {
    use unica::tensors::{TensorData, TensorFile, write};
    let dir = work_dir("seeds");
    let path = dir.join("seed.safetensors");
    write(
        &path,
        &[
            (
                "a",
                TensorData::f32(&[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
            ),
            ("b", TensorData::i32(&[4], &[7, 8, 9, 10])),
            ("c", TensorData::f32(&[1, 1, 2], &[0.5, -0.5])),
        ],
    )
    .unwrap();
    let seed = std::fs::read(&path).unwrap();
    fuzz("safetensors", "input.safetensors", &[seed], |p, _| {
        let Ok(file) = TensorFile::open(p) else {
            return false;
        };
        let a = file.f32("a", &[None, None]).is_ok();
        let b = file.i32("b", &[None]).is_ok();
        let c = file.f32("c", &[Some(1), None, Some(2)]).is_ok();
        a && b && c && !file.contains("d")
    });
}

#[test]
fn fuzz_bundle_manifest() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let seed = std::fs::read(root.join("assets/witch/bundle/manifest.json")).unwrap();
    fuzz(
        "bundle_manifest",
        "manifest.json",
        &exhausting(&seed),
        |p, _| unica::engine::bundle::read_manifest(p).is_ok(),
    );
}

/// A tiny dataset (one bone, one clip of 5 frames) whose manifest and reference are
/// fuzzed: `Dataset::open`, then `validate`.
fn tiny_dataset(dir: &Path) -> Vec<u8> {
    use unica::tensors::{TensorData, write};
    std::fs::create_dir_all(dir.join("clips")).unwrap();
    write(
        &dir.join("reference.safetensors"),
        &[
            (
                "bind_positions",
                TensorData::f32(&[3, 3], &[0.0, 0.0, 0.0, 0.2, 0.0, 0.0, 0.0, 0.2, 0.0]),
            ),
            ("colors", TensorData::f32(&[3, 3], &[0.5; 9])),
            ("joints", TensorData::i32(&[3, 4], &[0; 12])),
            (
                "weights",
                TensorData::f32(&[3, 4], &[1.0, 0.0, 0.0, 0.0].repeat(3)),
            ),
            ("triangles", TensorData::i32(&[1, 3], &[0, 1, 2])),
            ("pixels", TensorData::i32(&[2], &[100, 200])),
            ("pixel_triangles", TensorData::i32(&[2], &[0, 0])),
            (
                "barycentrics",
                TensorData::f32(&[2, 3], &[0.2, 0.3, 0.5, 0.6, 0.2, 0.2]),
            ),
            ("waist", TensorData::i32(&[2], &[0, 1])),
        ],
    )
    .unwrap();
    let identity = [
        1.0f32, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
    ];
    // The mean of the two waist pixels: 0.3·p1 + 0.5·p2 and 0.2·p1 + 0.2·p2.
    let r = [0.05f32, 0.07, 0.0];
    write(
        &dir.join("clips/clip_000.safetensors"),
        &[
            ("skin", TensorData::f32(&[5, 1, 3, 4], &identity.repeat(5))),
            ("actions", TensorData::i32(&[5], &[0, 0, 1, 1, 1])),
            ("root", TensorData::f32(&[5, 3], &r.repeat(5))),
        ],
    )
    .unwrap();
    let manifest = json!({
        "format": "unica-dataset", "version": 1, "avatar": "tiny", "character": "tiny.gltf",
        "frame_rate": 30.0, "actions": ["Idle", "Forward", "Backward", "Left", "Right"],
        "map_size": 128, "foreground_pixels": 2, "vertices": 3, "bones": 1,
        "norm_scale": 0.7, "walk_speed": 1.0, "run_speed": 2.0,
        "clips": [{"file": "clips/clip_000.safetensors", "frames": 5, "first": "Idle",
                   "second": "Forward", "switch_frame": 2}],
        "coverage": {}
    });
    serde_json::to_vec_pretty(&manifest).unwrap()
}

#[test]
fn fuzz_dataset_manifest() {
    let dir = work_dir("dataset_manifest");
    let seed = tiny_dataset(&dir);
    std::fs::write(dir.join("manifest.json"), &seed).unwrap();
    let report = unica::dataset::validate(&dir).unwrap();
    assert_eq!((report.clips, report.frames, report.groups), (1, 5, 2));
    fuzz(
        "dataset_manifest",
        "manifest.json",
        &exhausting(&seed),
        |p, _| unica::dataset::validate(p.parent().unwrap()).is_ok(),
    );
}

/// The tiny dataset's render manifest (`renders/cameras.json`: 50 views of the standing
/// pose and 4 of each of its 5 frames, each naming its render), read by `validate`.
#[test]
fn fuzz_render_manifest() {
    let dir = work_dir("render_manifest");
    std::fs::write(dir.join("manifest.json"), tiny_dataset(&dir)).unwrap();
    let renders = dir.join("renders");
    std::fs::create_dir_all(&renders).unwrap();
    let camera = |file: String| {
        json!({"file": file, "camera": {"target": [0.0, 1.0, 0.0], "yaw": 0.5, "pitch": 0.1,
                                        "distance": 3.0}})
    };
    let mut cameras: Vec<Value> = (0..50)
        .map(|i| camera(format!("rest_{i:02}.png")))
        .collect();
    for f in 0..5 {
        for v in 0..4 {
            let mut c = camera(format!("clip_000_{f:03}_{v}.png"));
            c["clip_frame"] = json!([0, f]);
            cameras.push(c);
        }
    }
    for c in &cameras {
        std::fs::write(renders.join(c["file"].as_str().unwrap()), b"png").unwrap();
    }
    let seed = serde_json::to_vec_pretty(&json!({"every": 1, "cameras": cameras})).unwrap();
    std::fs::write(renders.join("cameras.json"), &seed).unwrap();
    assert_eq!(unica::dataset::validate(&dir).unwrap().renders, 70);
    let dataset = dir.clone();
    fuzz_in(
        &renders,
        "render_manifest",
        "cameras.json",
        &exhausting(&seed),
        |_, _| unica::dataset::validate(&dataset).is_ok(),
    );
}

/// The fuzzed description drives a teacher of the seed triangle (bone "hip").
#[test]
fn fuzz_avatar_description() {
    use unica::avatar::description::Description;
    let dir = work_dir("seeds");
    let path = dir.join("description.glb");
    std::fs::write(&path, glb_seed()).unwrap();
    let character: Character = load_character(&path).unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let witch = std::fs::read(root.join("assets/avatars/witch.avatar.json")).unwrap();
    let tiny = serde_json::to_vec_pretty(&json!({
        "clips": {"idle": "Walk", "walk": "Walk", "run": "Walk"},
        "waist_bones": ["hip"], "feet": ["hip"], "forward": "+z",
        "walk_speed": 1.0, "run_speed": 2.0,
        "loose_parts": [
            {"name": "skirt", "kind": "ring", "mesh": "body", "materials": ["skin"],
             "parent_bone": "hip", "chains": 3, "segments": 2, "arc_degrees": 150,
             "stiffness": 1.5, "drag": 0.35, "gravity": 0.3},
            {"name": "hat", "kind": "tip", "mesh": "body", "materials": ["skin"],
             "parent_bone": "hip", "chains": 1, "segments": 2,
             "stiffness": 6.0, "drag": 0.5, "gravity": 0.1}
        ],
        "colliders": [{"bone": "hip"}, {"bone": "hip", "to": "hip"}]
    }))
    .unwrap();
    let seed = Description::parse(std::str::from_utf8(&tiny).unwrap(), &path).unwrap();
    if let Err(e) = unica::avatar::teacher::Teacher::new(character.clone(), seed) {
        panic!("the seed description drives no teacher: {e}");
    }
    let seeds = [exhausting(&tiny), vec![witch]].concat();
    fuzz(
        "avatar_description",
        "input.avatar.json",
        &seeds,
        |p, bytes| {
            let Ok(text) = std::str::from_utf8(bytes) else {
                return false;
            };
            let Ok(description) = Description::parse(text, p) else {
                return false;
            };
            unica::avatar::teacher::Teacher::new(character.clone(), description)
                .map(|mut t| {
                    for action in unica::action::Action::ALL {
                        t.step(action);
                    }
                })
                .is_ok()
        },
    );
}

#[test]
fn fuzz_key_scripts() {
    use unica::action::KeyScript;
    let seeds =
        ["60W 60S 60A 20I", "1w", "  30I\t2d 5A ", "999999W 1S"].map(|s| s.as_bytes().to_vec());
    fuzz("key_scripts", "keys.txt", &seeds, |_, bytes| {
        let Ok(text) = std::str::from_utf8(bytes) else {
            return false;
        };
        match KeyScript::parse(text) {
            Ok(script) => {
                assert!(!script.is_empty() && script.len() <= 1_000_000);
                for frame in [
                    0,
                    script.len() / 2,
                    script.len() - 1,
                    script.len(),
                    usize::MAX,
                ] {
                    script.action_at(frame);
                }
                true
            }
            Err(e) => {
                assert!(!e.to_string().contains('\n'));
                false
            }
        }
    });
}
