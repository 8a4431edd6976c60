//! The WGSL splat rasterizer against the CPU reference renderer (src/splat/project.rs),
//! on lavapipe. Both use the same projection, keys and blending order in f32; they differ
//! by the GPU's exp/rounding, which can move a splat across the 1/255 alpha cut or the
//! 1e-4 transmittance stop at a few pixels (a step of up to ~1/255 per channel there).
//! Tolerance: mean absolute difference ≤ 1e-4 and at most 0.5 % of pixel channels off by
//! more than 1e-3; an ordering or coverage bug moves whole splats (differences ~0.1-1).

use glam::{Quat, Vec3};
use unica::gpu::{GpuContext, GpuOptions, readback};
use unica::render::OrbitCamera;
use unica::render::camera::FOV_Y;
use unica::splat::ply::Splat;
use unica::splat::project::{SplatCamera, project, render_reference};
use unica::splat::raster::{ROW_BLEND_MAX_SPLATS, RasterKernels, Rasterizer};

/// A deterministic cloud of `n` splats around the origin: mixed sizes, elongations,
/// rotations, colours and opacities, some overlapping, some off screen.
fn scene(n: usize) -> Vec<Splat> {
    Splat::cloud(n, Vec3::new(-1.2, -0.9, -1.0), Vec3::new(2.4, 1.8, 2.0))
}

fn camera(width: u32, height: u32) -> SplatCamera {
    let orbit = OrbitCamera {
        target: Vec3::ZERO,
        yaw: 0.4,
        pitch: 0.3,
        distance: 3.5,
    };
    orbit.splat_camera(width, height)
}

/// The rasterizer's variants: each kernel set, with the sort's grids sized on the GPU
/// (indirect dispatches) or over the capacity.
fn variants() -> Vec<(String, Rasterizer)> {
    let mut out = Vec::new();
    for (kernels, name) in [(RasterKernels::Gpu, "gpu"), (RasterKernels::Cpu, "cpu")] {
        let rasterizer = || Rasterizer::default().with_kernels(kernels);
        out.push((name.to_string(), rasterizer()));
        out.push((
            format!("{name}, grids over the capacity"),
            rasterizer().direct_grids(),
        ));
    }
    out
}

/// Renders on the GPU; returns the image and [entries kept, entries wanted]. With
/// `warm_up`, the same rasterizer first draws those splats (same count and size, so its
/// kept buffers are reused: nothing of that frame may leak into this one).
fn gpu_render(
    mut rasterizer: Rasterizer,
    splats: &[Splat],
    warm_up: Option<&[Splat]>,
    cam: &SplatCamera,
    background: Vec3,
) -> (Vec<[f32; 4]>, [u32; 2]) {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let mut raster = None;
    for scene in warm_up.into_iter().chain([splats]) {
        let buffer = Rasterizer::upload(&gpu, scene).unwrap();
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        raster = Some(
            rasterizer
                .record(&gpu, &mut encoder, &buffer, scene.len(), cam, background)
                .unwrap(),
        );
        gpu.queue.submit([encoder.finish()]);
    }
    let raster = raster.expect("one frame at least");
    let image = readback::buffer(&gpu, &raster.image, "image").unwrap();
    let info = readback::buffer(&gpu, &raster.info, "info").unwrap();
    let info: Vec<u32> = bytemuck::pod_collect_to_vec(&info);
    let pixels = (cam.width * cam.height) as usize;
    (
        bytemuck::pod_collect_to_vec::<u8, [f32; 4]>(&image)[..pixels].to_vec(),
        [info[0], info[1]],
    )
}

/// Every variant of the rasterizer against the reference.
fn compare(splats: &[Splat], warm_up: Option<&[Splat]>, cam: &SplatCamera) {
    let background = Vec3::new(0.1, 0.2, 0.3);
    let want = render_reference(splats, cam, background);
    for (name, rasterizer) in variants() {
        eprint!("{name}: ");
        compare_one(rasterizer, splats, warm_up, cam, background, &want);
    }
}

fn compare_one(
    rasterizer: Rasterizer,
    splats: &[Splat],
    warm_up: Option<&[Splat]>,
    cam: &SplatCamera,
    background: Vec3,
    want: &[[f32; 4]],
) {
    let (got, info) = gpu_render(rasterizer, splats, warm_up, cam, background);
    assert_eq!(info[0], info[1], "no sort entry dropped");
    assert!(info[0] > 0, "something is on screen");
    let diffs: Vec<f32> = got
        .iter()
        .zip(want)
        .flat_map(|(a, b)| (0..4).map(move |c| (a[c] - b[c]).abs()))
        .collect();
    let mean = diffs.iter().sum::<f32>() / diffs.len() as f32;
    let off = diffs.iter().filter(|&&d| d > 1e-3).count() as f32 / diffs.len() as f32;
    let worst = diffs.iter().fold(0.0f32, |m, &d| m.max(d));
    let covered = want.iter().filter(|p| p[3] > 0.5).count();
    eprintln!(
        "{}x{}: mean {mean:.2e}, {:.3}% > 1e-3, worst {worst:.3}, {covered} covered pixels, \
         {} sort entries",
        cam.width,
        cam.height,
        off * 100.0,
        info[0]
    );
    assert!(
        covered > (cam.width * cam.height / 20) as usize,
        "the scene covers a twentieth of the image"
    );
    assert!(
        mean <= 1e-4 && off <= 0.005,
        "mean {mean}, {off} off, worst {worst}"
    );
}

#[test]
fn the_rasterizer_matches_the_reference_on_a_small_scene() {
    compare(&scene(300), None, &camera(64, 48));
}

#[test]
fn the_rasterizer_matches_the_reference_off_the_tile_grid_and_with_deep_scans() {
    // 100 × 70 pixels (partial tiles) and 5,000 splats: 80,000 sort entries of
    // capacity, of which over 4,096 are kept, so the histogram scan (256 values a block
    // of 256 entries) needs two levels of block sums either way.
    compare(&scene(5000), None, &camera(100, 70));
}

#[test]
fn a_second_frame_reusing_the_buffers_shows_only_its_own_splats() {
    let first: Vec<Splat> = scene(300)
        .into_iter()
        .map(|s| Splat {
            position: s.position * 0.5 + Vec3::X * 0.4,
            ..s
        })
        .collect();
    compare(&scene(300), Some(&first), &camera(64, 48));
}

#[test]
fn the_gpu_upscale_matches_the_cpu_reference() {
    // A 128² map with a ragged foreground (a disc with holes) and varied values, ×8 to
    // 1024² as docs/architecture.md, Appearance, says. Same f32 arithmetic; the GPU may
    // fuse multiply-adds, so values agree within 1e-5 and the mask may differ only where
    // the interpolated mask is within rounding of the 0.25 threshold.
    use unica::splat::upscale;
    let (w, h) = (128usize, 128usize);
    let mask: Vec<f32> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 - 64.0, (i / w) as f32 - 64.0);
            let hole = (x * 0.37).sin() * (y * 0.23).cos() > 0.8;
            f32::from(x * x + y * y < 50.0 * 50.0 && !hole)
        })
        .collect();
    let map: Vec<f32> = (0..3 * w * h)
        .map(|i| ((i as f32 * 0.618).fract() * 0.5 + 0.25) * mask[i % (w * h)])
        .collect();
    let (want, want_mask) = upscale::upscale_reference(&map, &mask, w, h, 8);

    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let upload = |label, data: &[f32]| {
        gpu.storage_buffer_init(
            label,
            bytemuck::cast_slice(data),
            wgpu::BufferUsages::empty(),
        )
        .unwrap()
    };
    let (map_buffer, mask_buffer) = (upload("map", &map), upload("mask", &mask));
    let mut pipelines = unica::gpu::kernel::PipelineCache::default();
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let (out, out_mask) = upscale::record(
        &gpu,
        &mut pipelines,
        &mut encoder,
        &map_buffer,
        &mask_buffer,
        w,
        h,
        8,
    )
    .unwrap();
    gpu.queue.submit([encoder.finish()]);
    let got: Vec<f32> = bytemuck::pod_collect_to_vec(&readback::buffer(&gpu, &out, "map").unwrap());
    let got_mask: Vec<f32> =
        bytemuck::pod_collect_to_vec(&readback::buffer(&gpu, &out_mask, "mask").unwrap());
    let mask_differs = got_mask
        .iter()
        .zip(&want_mask)
        .filter(|(a, b)| a != b)
        .count();
    assert!(mask_differs <= 100, "{mask_differs} mask pixels differ");
    let kept = want_mask.iter().filter(|&&m| m == 1.0).count();
    assert!(kept > 300_000, "{kept} foreground pixels at 1024²");
    let plane = 1024 * 1024;
    let worst = (0..3 * plane)
        .filter(|i| got_mask[i % plane] == want_mask[i % plane])
        .map(|i| (got[i] - want[i]).abs())
        .fold(0.0f32, f32::max);
    assert!(worst <= 1e-5, "values differ by {worst}");
}

/// The trainer's base splats of a real map (the Witch bundle's mean PCA frame, fixture
/// `base_splats`) against src/splat/base.rs. Tolerances: positions, scales, normals and
/// features come from the same f32 arithmetic in another order (errors ~1e-7 of values
/// ≤ 1; 1e-5 absolute). Quaternion components come from square roots of 1 ± diagonal
/// sums, which turn a 1e-7 rounding near zero into ~3e-4, so rotations are compared as
/// the rotated axes (1e-4) instead.
#[test]
fn base_splats_match_the_trainer_on_a_real_map() {
    use unica::splat::base;
    use unica::tensors::TensorFile;
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/nn/base_splats.safetensors");
    let file = TensorFile::open(&path).unwrap();
    let get = |name: &str, rank: usize| file.f32(name, &vec![None; rank]).unwrap().0;
    let vec3s =
        |name: &str| -> Vec<Vec3> { get(name, 2).chunks_exact(3).map(Vec3::from_slice).collect() };
    let unit = vec3s("io.in.unit");
    let colors = vec3s("io.in.colors");
    let pixels: Vec<u32> = get("io.in.pixels", 1).iter().map(|&p| p as u32).collect();
    let neighbours = base::neighbours(&pixels, 128);
    let t = base::tangents(&unit, &neighbours);
    assert!((t.median - get("io.out.median", 1)[0]).abs() < 1e-7);
    let (splats, normals) = base::base_splats(&unit, &colors, &t);
    let worst = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let flat = |v: &[Vec3]| -> Vec<f32> { v.iter().flat_map(|p| p.to_array()).collect() };
    let scales: Vec<Vec3> = splats.iter().map(|s| s.scale).collect();
    assert!(worst(&flat(&scales), &get("io.out.scales", 2)) < 1e-5);
    assert!(worst(&flat(&normals), &get("io.out.normals", 2)) < 1e-5);
    let features = base::features(&unit, &splats, &normals, t.median);
    let error = worst(&features, &get("io.out.features", 2));
    println!("features: worst difference {error:.1e}");
    assert!(error < 1e-4);
    let rotations = get("io.out.rotations", 2);
    let mut worst_axis = 0.0f32;
    for (s, q) in splats.iter().zip(rotations.chunks_exact(4)) {
        let want = Quat::from_xyzw(q[0], q[1], q[2], q[3]).normalize();
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            worst_axis = worst_axis.max((s.rotation * axis).distance(want * axis));
        }
    }
    println!("rotated axes: worst difference {worst_axis:.1e}");
    assert!(worst_axis < 1e-4);
}

/// The shipped Witch's own splats at splat `level` after one frame.
fn witchs_splats(level: usize) -> Vec<Splat> {
    use unica::action::Action;
    use unica::engine::{Engine, EngineOptions};
    use unica::splat::raster::GpuSplat;
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/witch/bundle");
    let options = EngineOptions {
        splat_level: Some(level),
        ..EngineOptions::default()
    };
    let mut engine = Engine::new(&gpu, &dir, &options).unwrap();
    engine.frame(Action::Forward).unwrap();
    engine.finish();
    let (buffer, count) = engine.splats().expect("splats asked for");
    let bytes = readback::buffer(&gpu, buffer, "splats").unwrap();
    bytemuck::pod_collect_to_vec::<u8, GpuSplat>(&bytes)[..count]
        .iter()
        .map(GpuSplat::to_splat)
        .collect()
}

/// The sort entries of the fullest tile: a splat enters each tile its 3σ box touches.
fn fullest_tile(splats: &[Splat], cam: &SplatCamera) -> u32 {
    let (tiles_x, tiles_y) = cam.tiles();
    let mut entries = vec![0u32; (tiles_x * tiles_y) as usize];
    for p in splats.iter().filter_map(|s| project(s, cam)) {
        for y in p.tiles[1]..p.tiles[3] {
            for x in p.tiles[0]..p.tiles[2] {
                entries[(y * tiles_x + x) as usize] += 1;
            }
        }
    }
    entries.into_iter().max().unwrap_or(0)
}

/// The camera `unica eval --quick` frames the Witch with from 30° above: 128², the
/// figure 72 % of the image height (src/eval/lockstep.rs), so tiles are fullest.
fn eval_camera_from_above(splats: &[Splat]) -> SplatCamera {
    let (lo, hi) = splats.iter().fold((Vec3::MAX, Vec3::MIN), |(l, h), s| {
        (l.min(s.position), h.max(s.position))
    });
    let orbit = OrbitCamera {
        target: (lo + hi) * 0.5,
        yaw: 0.0,
        pitch: 30f32.to_radians(),
        distance: (hi.y - lo.y) / (0.72 * 2.0 * (FOV_Y * 0.5).tan()),
    };
    orbit.splat_camera(128, 128)
}

/// The Witch's own level-1024 splats (306k, most under a pixel at 128 × 128, so tiles
/// hold thousands of sort entries), drawn by every variant against the reference:
/// synthetic clouds missed a blend that differed here (docs/performance.md). First from
/// 3 m; then as the quick eval frames her from above, where one tile holds more entries
/// than lavapipe's 65,535 loop iterations an invocation (the shared-memory blend lost
/// pixels there before its walk was unrolled; the row blend is not used for so many).
#[test]
fn the_rasterizer_matches_the_reference_on_the_witchs_own_splats() {
    let splats = witchs_splats(1024);
    assert!(splats.len() > ROW_BLEND_MAX_SPLATS);
    let count = splats.len();
    let centre = splats.iter().fold(Vec3::ZERO, |a, s| a + s.position) / count as f32;
    let orbit = OrbitCamera {
        target: centre,
        yaw: 0.4,
        pitch: 0.1,
        distance: 3.0,
    };
    compare(&splats, None, &orbit.splat_camera(128, 128));
    let cam = eval_camera_from_above(&splats);
    let most = fullest_tile(&splats, &cam);
    eprintln!("from above: {most} sort entries in the fullest tile");
    assert!(most > 65_535, "the fullest tile holds {most} entries");
    compare(&splats, None, &cam);
}

/// The same at the CPU drivers' default level 256 (18k splats), which the row blend
/// draws: from above the fullest tile holds about 4,800 sort entries.
#[test]
fn the_row_blend_matches_the_reference_on_the_witchs_level_256_splats() {
    let splats = witchs_splats(256);
    assert!(splats.len() <= ROW_BLEND_MAX_SPLATS);
    let cam = eval_camera_from_above(&splats);
    let most = fullest_tile(&splats, &cam);
    eprintln!("from above: {most} sort entries in the fullest tile");
    assert!(most > 3_000, "the fullest tile holds {most} entries");
    compare(&splats, None, &cam);
}

/// The serialisation ranks of both kernels (`rank_serial.wgsl` for CPU drivers,
/// `rank_tiled.wgsl` for GPUs) against a stable sort on the host, on codes with many
/// ties (a point's rank counts the smaller codes and the equal codes of smaller index),
/// for the second curve of a codes buffer (its offset), with the pooled groups, at the
/// Witch's point count, a count that is not a multiple of 4, one point, and the serial
/// kernel's largest count (`RANK_SERIAL_MAX_POINTS`, just under lavapipe's loop limit);
/// the tiled kernel also past it. Exact: both are integer sorts.
#[test]
fn both_rank_kernels_sort_codes_stably_as_the_host_does() {
    use unica::gpu::kernel::PipelineCache;
    use unica::gpu::plan::Builder;
    use unica::gpu::precision::Precision;
    use unica::splat::frame::{RANK_SERIAL, RANK_SERIAL_MAX_POINTS, RANK_TILED, SplatParams};

    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let stride = 4u32;
    let cases = [
        (4_414, false),
        (4_414, true),
        (4_415, false),
        (1, false),
        (1, true),
        (RANK_SERIAL_MAX_POINTS, false),
        (RANK_SERIAL_MAX_POINTS + 1_001, true),
    ];
    for (n, tiled) in cases {
        // Four curves of n codes each, padded to a multiple of 4 with the largest u32 as
        // codes.wgsl pads them; the kernel reads curve 1. Codes below 2^30 (three 10-bit
        // digits); a third of them from 50 values, so ties are common.
        let padded = n.div_ceil(4) * 4;
        let mut state = 12_345u64 + n as u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 33) as u32
        };
        let mut codes = vec![u32::MAX; 4 * padded];
        for curve in 0..4 {
            for i in 0..n {
                let r = next();
                codes[curve * padded + i] = if r % 3 == 0 {
                    (r / 3 % 50) << 17
                } else {
                    r & ((1 << 30) - 1)
                };
            }
        }
        let ours = &codes[padded..padded + n];
        let mut want: Vec<u32> = (0..n as u32).collect();
        want.sort_by_key(|&i| ours[i as usize]);
        assert!(
            n == 1
                || want
                    .windows(2)
                    .any(|w| ours[w[0] as usize] == ours[w[1] as usize]),
            "the codes have ties"
        );

        let codes_buffer = gpu
            .storage_buffer_init(
                "codes",
                bytemuck::cast_slice(&codes),
                wgpu::BufferUsages::empty(),
            )
            .unwrap();
        let out = |label| {
            gpu.storage_buffer(label, 4 * n as u64, wgpu::BufferUsages::COPY_SRC)
                .unwrap()
        };
        let (sort_buffer, unsort_buffer, groups_buffer) =
            (out("sort"), out("unsort"), out("groups"));
        let mut pipelines = PipelineCache::default();
        let mut b = Builder::new(&gpu, &mut pipelines, Precision::F32);
        let mut p: SplatParams = bytemuck::Zeroable::zeroed();
        p.points = n as u32;
        p.curve = 1;
        p.stride = stride;
        p.features = 1;
        let bound = [&codes_buffer, &sort_buffer, &unsort_buffer, &groups_buffer];
        if tiled {
            let grid = b.grid(n);
            b.dispatch(&RANK_TILED, &p, &bound, grid);
        } else {
            let grid = b.workgroups(1);
            b.dispatch(&RANK_SERIAL, &p, &bound, grid);
        }
        b.submit();
        let read = |buffer: &wgpu::Buffer| -> Vec<u32> {
            let bytes = readback::buffer(&gpu, buffer, "ranks").unwrap();
            bytemuck::pod_collect_to_vec::<u8, u32>(&bytes)[..n].to_vec()
        };
        let kernel = if tiled { "rank_tiled" } else { "rank_serial" };
        let mut unsort = vec![0u32; n];
        for (r, &i) in want.iter().enumerate() {
            unsort[i as usize] = r as u32;
        }
        let groups: Vec<u32> = unsort.iter().map(|r| r / stride).collect();
        for (what, buffer, expected) in [
            ("sort", &sort_buffer, &want),
            ("unsort", &unsort_buffer, &unsort),
            ("groups", &groups_buffer, &groups),
        ] {
            let got = read(buffer);
            let wrong = got.iter().zip(expected).filter(|(a, b)| a != b).count();
            let first = got.iter().zip(expected).position(|(a, b)| a != b);
            assert_eq!(
                wrong, 0,
                "{kernel}, {n} points: {what} differs at {wrong} entries, first {first:?}"
            );
        }
    }
}
