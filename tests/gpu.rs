//! Device tests on whatever adapter the environment gives (lavapipe in CI): the example
//! kernels on the preferred and the forced-fallback paths, dispatch splitting, buffer
//! limits, stage timing and an off-screen scene render.

use glam::Vec3;
use unica::gpu::kernel::{self, Grid, PipelineCache, Precision, ScaleAdd, WORKGROUP_SIZE};
use unica::gpu::timing::Profiler;
use unica::gpu::{GpuContext, GpuError, GpuOptions, readback};
use unica::mesh::Mesh;
use unica::render::scene::BACKGROUND;
use unica::render::{OrbitCamera, RenderTarget, SceneRenderer};

fn device(force_fallback: bool) -> GpuContext {
    let options = GpuOptions {
        force_fallback,
        ..GpuOptions::from_env()
    };
    GpuContext::headless(&options).unwrap_or_else(|e| panic!("no GPU for the tests: {e}"))
}

fn ramp(n: usize) -> Vec<f32> {
    (0..n)
        .map(|i| ((i % 2001) as f32 - 1000.0) * 0.01)
        .collect()
}

#[test]
fn forced_fallback_uses_no_optional_feature() {
    let gpu = device(true);
    assert!(!gpu.caps.shader_f16 && !gpu.caps.subgroups && !gpu.caps.timestamps);
    assert!(
        gpu.device.features().is_empty(),
        "{:?}",
        gpu.device.features()
    );
    assert_eq!(Precision::preferred(&gpu), Precision::F32);
}

#[test]
fn capabilities_follow_the_adapter() {
    let gpu = device(false);
    let has = gpu.adapter.features();
    assert_eq!(
        gpu.caps.shader_f16,
        has.contains(wgpu::Features::SHADER_F16)
    );
    assert_eq!(gpu.caps.subgroups, has.contains(wgpu::Features::SUBGROUP));
    assert_eq!(
        gpu.caps.timestamps,
        has.contains(wgpu::Features::TIMESTAMP_QUERY)
    );
    eprintln!("adapter {}: {:?}", gpu.adapter_label(), gpu.caps);
}

#[test]
fn scale_add_f32_matches_the_cpu_on_both_paths() {
    let x = ramp(10_000);
    for fallback in [false, true] {
        // One rounding (fused or not): within 1 ulp-ish of the exact value.
        let what = format!("fallback {fallback}");
        assert_scale_add(&device(fallback), &x, Precision::F32, 1e-6, &what);
    }
}

/// `ScaleAdd` of (x, 1.5, -0.25) in `precision` within `relative` of the exact
/// value (relative to max(1, |value|)) everywhere.
fn assert_scale_add(gpu: &GpuContext, x: &[f32], precision: Precision, relative: f32, what: &str) {
    let mut pipelines = PipelineCache::default();
    let kernel = ScaleAdd::new(gpu, &mut pipelines, x, 1.5, -0.25, precision).unwrap();
    let y = kernel.run(gpu).unwrap();
    for (i, (&got, &xi)) in y.iter().zip(x).enumerate() {
        let want = 1.5 * xi - 0.25;
        assert!(
            (got - want).abs() <= relative * want.abs().max(1.0),
            "{what}, [{i}]: {got} vs {want}"
        );
    }
}

#[test]
fn scale_add_f16_path_matches_within_half_precision() {
    let gpu = device(false);
    if !gpu.caps.shader_f16 {
        // This adapter has no f16: the preferred path must then be f32.
        assert_eq!(Precision::preferred(&gpu), Precision::F32);
        eprintln!("adapter without SHADER_F16: checked that the f32 path is preferred");
        return;
    }
    assert_eq!(Precision::preferred(&gpu), Precision::F16);
    let x = ramp(4_097); // odd length: the f16 buffer is padded
    // Input, product and sum each round to 11 significant bits: 3 half-ulps of 2^-11.
    assert_scale_add(&gpu, &x, Precision::F16, 3.0 * 2f32.powi(-11), "f16");
}

#[test]
fn dispatches_past_the_workgroup_limit_cover_every_element() {
    let gpu = device(false);
    let max = gpu.device.limits().max_compute_workgroups_per_dimension;
    let n = (max as usize + 3) * WORKGROUP_SIZE as usize + 17;
    let grid = Grid::for_elements(n as u32, max);
    assert!(grid.y > 1, "{grid:?} should need a second dimension");
    let x: Vec<f32> = (0..n).map(|i| (i % 4096) as f32).collect();
    let mut cache = PipelineCache::default();
    let kernel = ScaleAdd::new(&gpu, &mut cache, &x, 1.0, 1.0, Precision::F32).unwrap();
    let y = kernel.run(&gpu).unwrap();
    let wrong = y.iter().zip(&x).position(|(&got, &xi)| got != xi + 1.0);
    assert_eq!(wrong, None, "first wrong element of {n}");
}

#[test]
fn sum_is_exact_on_the_subgroup_and_shared_memory_paths() {
    let x: Vec<f32> = (1..=1000).map(|i| i as f32).collect();
    for fallback in [false, true] {
        let gpu = device(fallback);
        let total = kernel::sum(&gpu, &mut PipelineCache::default(), &x).unwrap();
        assert_eq!(
            total, 500_500.0,
            "fallback {fallback}, subgroups {}",
            gpu.caps.subgroups
        );
    }
}

#[test]
fn oversized_storage_buffers_are_refused_by_name() {
    let gpu = device(false);
    let max = gpu.max_storage_binding();
    let err = gpu
        .storage_buffer("huge activations", max + 4, wgpu::BufferUsages::empty())
        .unwrap_err();
    assert!(matches!(err, GpuError::BufferTooLarge { size, .. } if size == max + 4));
    assert!(err.to_string().contains("huge activations"), "{err}");
    assert!(
        gpu.storage_buffer("fits", 1024, wgpu::BufferUsages::empty())
            .is_ok()
    );
}

#[test]
fn pipelines_are_cached() {
    let gpu = device(false);
    let mut cache = PipelineCache::default();
    let x = ramp(10);
    for scale in [1.0, 2.0] {
        let kernel = ScaleAdd::new(&gpu, &mut cache, &x, scale, 0.0, Precision::F32).unwrap();
        kernel.run(&gpu).unwrap();
    }
    assert_eq!(cache.len(), 1);
}

#[test]
fn stages_are_timed_by_name_with_the_available_clock() {
    for fallback in [false, true] {
        let gpu = device(fallback);
        let x = ramp(1 << 16);
        let kernel = kernel::ScaleAdd::new(
            &gpu,
            &mut PipelineCache::default(),
            &x,
            1.0,
            0.0,
            Precision::F32,
        )
        .unwrap();
        let mut profiler = Profiler::new(&gpu);
        profiler.stage(&gpu, "first", |enc, timer| kernel.record(&gpu, enc, timer));
        profiler.stage(&gpu, "second", |enc, timer| kernel.record(&gpu, enc, timer));
        let timings = profiler.finish(&gpu).unwrap();
        let names: Vec<&str> = timings.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(names, ["first", "second"]);
        let clock = if gpu.caps.timestamps { "gpu" } else { "cpu" };
        for t in &timings {
            assert_eq!(t.clock, clock);
            assert!(t.ms.is_finite() && t.ms >= 0.0 && t.ms < 10_000.0, "{t:?}");
        }
    }
}

#[test]
fn the_scene_renders_a_lit_box_over_the_background() {
    let gpu = device(false);
    let renderer = SceneRenderer::new(&gpu);
    let mesh = renderer.upload(
        &gpu,
        &Mesh::cuboid(
            Vec3::new(-0.5, 0.0, -0.5),
            Vec3::new(0.5, 1.0, 0.5),
            Vec3::new(0.8, 0.2, 0.2),
        ),
    );
    let target = RenderTarget::new(&gpu, 96, 64);
    let mut camera = OrbitCamera::default();
    camera.frame(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5));
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let options = unica::render::scene::DrawOptions::default();
    renderer.draw(
        &gpu,
        &mut encoder,
        &target,
        &camera,
        &[&mesh],
        &options,
        None,
    );
    gpu.queue.submit([encoder.finish()]);
    let image = readback::rgba_texture(&gpu, &target.color).unwrap();
    assert_eq!(image.dimensions(), (96, 64));
    let centre = image.get_pixel(48, 32).0;
    assert!(
        centre[0] > 100 && centre[0] > centre[2] + 60,
        "box colour at the centre: {centre:?}"
    );
    let corner = image.get_pixel(0, 0).0;
    let srgb = |linear: f64| {
        (255.0
            * if linear <= 0.003_130_8 {
                12.92 * linear
            } else {
                1.055 * linear.powf(1.0 / 2.4) - 0.055
            })
        .round() as i32
    };
    let background = [BACKGROUND.r, BACKGROUND.g, BACKGROUND.b].map(srgb);
    for c in 0..3 {
        assert!(
            (corner[c] as i32 - background[c]).abs() <= 1,
            "background in the corner: {corner:?} vs {background:?}"
        );
    }
}
