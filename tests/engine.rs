//! The live frame on the GPU (src/engine): the captured plan against a CPU reference of
//! the same loop on the shipped Witch bundle (generate and decode recorded the ordinary
//! way, then clamping, root shift, PCA projection, world placement and the window's slide
//! as maps on the host, the slid maps encoded the ordinary way), the frame-state kernel on known values, determinism, and the counts of a
//! generated frame (nothing created, one readback of at most 256 bytes).

use std::path::{Path, PathBuf};

use glam::Vec3;
use unica::action::Action;
use unica::engine::bundle::Bundle;
use unica::engine::bundle::{Heading, RootMotion};
use unica::engine::kernels::{self, FrameState, HeadingTurns, PostParams};
use unica::engine::{Engine, EngineOptions, pca};
use unica::gpu::kernel::{Grid, PipelineCache, Precision};
use unica::gpu::{GpuContext, GpuOptions, readback};
use unica::nn::sampler::{KeyRun, Sampling};
use unica::nn::{Kernels, Recorder, Tensor};
use unica::random::Rng;
use unica::splat::ply::Splat;

fn witch_bundle() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/witch/bundle")
}

/// A copy of the shipped bundle whose manifest says `root_motion: motion`, `heading:
/// heading`, `grounded` and `stand_speed: stand` (the weights linked or copied), in
/// `dir/motion-heading-grounded-stand`.
fn bundle_with(
    dir: &Path,
    motion: &str,
    heading: &str,
    grounded: bool,
    stand: Option<f32>,
) -> PathBuf {
    let from = witch_bundle();
    let to = dir.join(format!("{motion}-{heading}-{grounded}-{stand:?}"));
    std::fs::create_dir_all(&to).unwrap();
    let weights = to.join("weights.safetensors");
    if std::fs::hard_link(from.join("weights.safetensors"), &weights).is_err() {
        std::fs::copy(from.join("weights.safetensors"), &weights).unwrap();
    }
    let text = std::fs::read_to_string(from.join("manifest.json")).unwrap();
    let mut manifest: serde_json::Value = serde_json::from_str(&text).unwrap();
    manifest["root_motion"] = motion.into();
    manifest["heading"] = heading.into();
    manifest["grounded"] = grounded.into();
    manifest["stand_speed"] = stand.into();
    std::fs::write(to.join("manifest.json"), manifest.to_string()).unwrap();
    to
}

fn gpu() -> GpuContext {
    GpuContext::headless(&GpuOptions::default()).expect("a GPU adapter (lavapipe in CI)")
}

fn options(sampling: Sampling, seed: u64) -> EngineOptions {
    EngineOptions {
        seed,
        sampling: Some(sampling),
        ..EngineOptions::default()
    }
}

/// Whether each map pixel is foreground.
fn foreground(bundle: &Bundle) -> Vec<bool> {
    let mut out = vec![false; bundle.manifest.map_size * bundle.manifest.map_size];
    for &p in &bundle.pixels {
        out[p as usize] = true;
    }
    out
}

/// A heading-turns buffer holding `to_model`, `to_world` and whether the key is Idle.
fn heading_buffer(gpu: &GpuContext, to_model: u32, to_world: u32, idle: bool) -> wgpu::Buffer {
    let turns = HeadingTurns {
        to_model,
        to_world,
        idle: u32::from(idle),
        ..bytemuck::Zeroable::zeroed()
    };
    gpu.storage_buffer_init(
        "heading",
        bytemuck::bytes_of(&turns),
        wgpu::BufferUsages::empty(),
    )
    .unwrap()
}

/// A frame-state buffer starting at `state`, readable back.
fn state_buffer(gpu: &GpuContext, state: &FrameState) -> wgpu::Buffer {
    gpu.storage_buffer_init(
        "state",
        bytemuck::bytes_of(state),
        wgpu::BufferUsages::COPY_SRC,
    )
    .unwrap()
}

/// The window's maps before the first frame: the standing-start context decoded, the
/// background set to 0.
fn start_maps(gpu: &GpuContext, bundle: &Bundle) -> Vec<f32> {
    let mut pipelines = PipelineCache::default();
    let mut r = Recorder::new(gpu, &mut pipelines, Precision::F32);
    let maps = bundle.decode(&mut r, &bundle.context).unwrap();
    r.submit();
    let mut maps = maps.read(gpu).unwrap();
    let foreground = foreground(bundle);
    let plane = foreground.len();
    for (i, v) in maps.iter_mut().enumerate() {
        if !foreground[i % plane] {
            *v = 0.0;
        }
    }
    maps
}

/// One engine frame's result on the host.
struct Reference {
    points: Vec<Vec3>,
    /// The window's maps after the slide.
    maps: Vec<f32>,
    root: Vec3,
    clamped: usize,
    /// Whether the stand latch holds after the frame.
    standing: bool,
}

/// A normalised point turned `turns` quarter turns about the vertical through the
/// centre, one turn (x, z) -> (z, -x) about (0.5, 0.5) at a time (the trainer's
/// `dataset.quarter_turn`).
fn turn(v: Vec3, turns: u32) -> Vec3 {
    let mut out = v;
    for _ in 0..turns % 4 {
        out = Vec3::new(out.z, out.y, 1.0 - out.x);
    }
    out
}

/// The window's `maps` [F, 3, S, S] with every foreground point turned `turns`, the
/// background 0.
fn turn_maps(bundle: &Bundle, maps: &[f32], turns: u32) -> Vec<f32> {
    let plane = bundle.manifest.map_size * bundle.manifest.map_size;
    let mut out = vec![0.0; maps.len()];
    for (f, frame) in maps.chunks(3 * plane).enumerate() {
        for &p in &bundle.pixels {
            let p = p as usize;
            let v = turn(
                Vec3::new(frame[p], frame[plane + p], frame[2 * plane + p]),
                turns,
            );
            for k in 0..3 {
                out[f * 3 * plane + k * plane + p] = v[k];
            }
        }
    }
    out
}

/// The loop of one engine frame on the host: the window's `maps` [F-1, 3, S, S] turned
/// to the model's heading (`quarters` from W: turned back by them) and encoded, the
/// frame generated under `action` turned the same way, decoded, turned back; `root` is
/// the world root before the frame.
#[allow(clippy::too_many_arguments)]
fn reference_frame(
    gpu: &GpuContext,
    bundle: &Bundle,
    maps: &[f32],
    quarters: u32,
    noise: &[f32],
    action: Action,
    sampling: Sampling,
    root: Vec3,
    root_motion: RootMotion,
    (stand, standing): (f32, bool),
    pipelines: &mut PipelineCache,
) -> Reference {
    let cfg = &bundle.unet.cfg;
    let side = 16;
    let size = bundle.manifest.map_size;
    let frames = cfg.frames - 1;
    let to_model = (4 - quarters) % 4;
    let mut r = Recorder::new(gpu, pipelines, Precision::F32);
    let turned = turn_maps(bundle, maps, to_model);
    let input = r.upload("maps", &[frames, 3, size, size], &turned).unwrap();
    let means = bundle.encoder.forward(&mut r, &input).unwrap();
    r.submit();
    let context: Vec<f32> = means
        .read(gpu)
        .unwrap()
        .iter()
        .map(|v| v * bundle.manifest.latent_scale)
        .collect();
    let mut r = Recorder::new(gpu, pipelines, Precision::F32);
    let ctx = r
        .upload("ctx", &[1, frames, cfg.latent, side, side], &context)
        .unwrap();
    let noise = r
        .upload("noise", &[1, cfg.latent, side, side], noise)
        .unwrap();
    let latent = bundle
        .generate(
            &mut r,
            &ctx,
            action.turned(to_model).id() as usize,
            &noise,
            sampling,
        )
        .unwrap();
    let map = bundle.decode(&mut r, &latent).unwrap();
    r.submit();
    let map = map.read(gpu).unwrap();
    let plane = map.len() / 3;
    let mut clamped = 0;
    let unit: Vec<Vec3> = bundle
        .pixels
        .iter()
        .map(|&p| {
            let kept = Vec3::from_array([0, 1, 2].map(|k| {
                let x = map[k * plane + p as usize];
                let kept = if x.is_nan() { 0.5 } else { x.clamp(0.0, 1.0) };
                clamped += usize::from(kept != x);
                kept
            }));
            turn(kept, quarters)
        })
        .collect();
    let centre =
        bundle.waist.iter().map(|&w| unit[w as usize]).sum::<Vec3>() / bundle.waist.len() as f32;
    let shift = centre - Vec3::splat(0.5);
    // The root motion: the shift, or the root minus the root of the context's last
    // latent decoded (its values cut out here on the host).
    let motion = match root_motion {
        RootMotion::Centre => shift,
        RootMotion::Decoded => {
            let len = context.len() / (cfg.frames - 1);
            let last = &context[context.len() - len..];
            let mut r = Recorder::new(gpu, pipelines, Precision::F32);
            let z = r
                .upload("last", &[1, cfg.latent, side, side], last)
                .unwrap();
            let map = bundle.decode(&mut r, &z).unwrap();
            r.submit();
            let map = map.read(gpu).unwrap();
            let kept = |x: f32| if x.is_nan() { 0.5 } else { x.clamp(0.0, 1.0) };
            let from = bundle
                .waist
                .iter()
                .map(|&w| {
                    let p = bundle.pixels[w as usize] as usize;
                    turn(
                        Vec3::from_array([0, 1, 2].map(|k| kept(map[k * plane + p]))),
                        quarters,
                    )
                })
                .sum::<Vec3>()
                / bundle.waist.len() as f32;
            centre - from
        }
    };
    let scale = bundle.manifest.normalisation.scale;
    // Grounded: the height that puts the lowest kept point on the floor, y = 0.
    let mut motion = motion;
    if bundle.manifest.grounded {
        let lowest = unit.iter().map(|p| p.y).fold(f32::INFINITY, f32::min);
        motion.y = centre.y - lowest - scale * root.y;
    }
    // The stand latch: under Idle the horizontal motion is 0 once held or below `stand`.
    let mut standing = standing;
    if stand > 0.0 {
        if action != Action::Idle {
            standing = false;
        } else if standing || glam::Vec2::new(motion.x, motion.z).length() < stand {
            standing = true;
            (motion.x, motion.z) = (0.0, 0.0);
        }
    }
    let drawn = pca::project_points(&unit, shift, &bundle.pca_mean, &bundle.pca_basis);
    let points = drawn
        .iter()
        .map(|&p| (p - shift + motion - Vec3::splat(0.5)) / scale + root)
        .collect();
    // The slide: frames 1.. of the window then the new frame's clamped points, all moved
    // by -shift, background 0 (encoded at the next frame's start).
    let per_frame = 3 * plane;
    let mut next: Vec<f32> = maps[per_frame..].to_vec();
    next.resize(frames * per_frame, 0.0);
    let foreground = foreground(bundle);
    let last = (frames - 1) * per_frame;
    for (point, &p) in bundle.pixels.iter().enumerate() {
        for k in 0..3 {
            next[last + k * plane + p as usize] = unit[point][k];
        }
    }
    for (i, v) in next.iter_mut().enumerate() {
        if foreground[i % plane] {
            *v -= shift[(i / plane) % 3];
        }
    }
    Reference {
        points,
        maps: next,
        root: root + motion / scale,
        clamped,
        standing,
    }
}

fn worst(a: &[Vec3], b: &[Vec3]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| x.distance(*y))
        .fold(0.0, f32::max)
}

#[test]
fn the_gpu_frame_equals_the_host_loop_on_the_shipped_bundle() {
    // Four frames (W, D, Idle, Idle) each without guidance, with guidance, with guidance
    // but Idle unguided and the noise scaled, with Idle guided at its own scale, and
    // braking the first Idle frame after a key at a third scale, beside Idle at its own
    // scale and beside unguided Idle (two DDIM steps: the plan's structure is the same
    // for any count); then two of them with the root motion measured from the decoded
    // last context latent, two with that and the canonical heading (the window turned
    // by D's quarter turns from the second frame on, the action with it), one also
    // grounded (the root's height puts the lowest point on the floor), and that one with
    // the stand latch holding the root through both Idle frames. Tolerance: 2e-5
    // m (0.02 mm) on world points and 2e-5 m on the root; both sides run the same f32
    // kernels (the encoder of the turned maps included) and differ only in summation
    // order and fused multiply-adds of the turns, the PCA, the slide and the world
    // placement (measured ≈ 1e-6 m).
    let gpu = gpu();
    let unguided_idle = Sampling {
        guide_idle: false,
        noise_scale: 0.5,
        ..Sampling::new(2, 2.0)
    };
    let idle_scaled = Sampling {
        idle_cfg_scale: Some(1.5),
        ..unguided_idle
    };
    // Braking the first Idle frame after a key, and the first frame of a turn (W then
    // D below) unguided, as one pass.
    let braking = Sampling {
        idle_brake_cfg_scale: Some(3.0),
        idle_brake_frames: 1,
        turn_brake_cfg_scale: Some(1.0),
        turn_brake_frames: 1,
        ..idle_scaled
    };
    // Braking beside unguided Idle: the braking frame pairs Idle with the null action.
    let braking_unguided = Sampling {
        idle_cfg_scale: None,
        ..braking
    };
    // The root motion measured from the centre and, with the guided and the braking
    // sampler, from the last context latent decoded, with the world's heading and the
    // canonical one (copies of the bundle whose manifests say so).
    let dir = tempfile::tempdir().unwrap();
    let decoded = bundle_with(dir.path(), "decoded", "world", false, None);
    let centred = bundle_with(dir.path(), "centre", "world", false, None);
    let canonical = bundle_with(dir.path(), "decoded", "canonical", false, None);
    let grounded = bundle_with(dir.path(), "decoded", "canonical", true, None);
    // The stand latch at a speed every Idle frame's motion is under: both Idle frames
    // hold the world root.
    let standing = bundle_with(dir.path(), "decoded", "canonical", true, Some(1e3));
    let centre = |s| (s, centred.clone(), RootMotion::Centre, Heading::World);
    // One cache for every reference frame: the pipelines are built once, not per frame.
    let mut pipelines = PipelineCache::default();
    for (sampling, bundle, root_motion, heading) in [
        centre(Sampling::new(2, 1.0)),
        centre(Sampling::new(2, 2.0)),
        centre(unguided_idle),
        centre(idle_scaled),
        centre(braking),
        centre(braking_unguided),
        (
            Sampling::new(2, 2.0),
            decoded.clone(),
            RootMotion::Decoded,
            Heading::World,
        ),
        (
            braking,
            decoded.clone(),
            RootMotion::Decoded,
            Heading::World,
        ),
        (
            Sampling::new(2, 2.0),
            canonical.clone(),
            RootMotion::Decoded,
            Heading::Canonical,
        ),
        (
            braking,
            canonical.clone(),
            RootMotion::Decoded,
            Heading::Canonical,
        ),
        (
            braking,
            grounded.clone(),
            RootMotion::Decoded,
            Heading::Canonical,
        ),
        (
            braking,
            standing.clone(),
            RootMotion::Decoded,
            Heading::Canonical,
        ),
    ] {
        let cfg_scale = sampling.cfg_scale;
        let mut engine = Engine::new(&gpu, &bundle, &options(sampling, 7)).unwrap();
        assert_eq!(engine.bundle.manifest.root_motion, root_motion);
        assert_eq!(engine.bundle.manifest.heading, heading);
        let latents = engine.bundle.context.read(&gpu).unwrap().len();
        let mut maps = start_maps(&gpu, &engine.bundle);
        let mut quarters = 0;
        let mut root = engine.root();
        let mut noise = Rng::new(7);
        let mut run = KeyRun::default();
        let stand = engine.bundle.manifest.stand_per_frame();
        let mut standing = true;
        for action in [Action::Forward, Action::Right, Action::Idle, Action::Idle] {
            let frame = engine.step(action).unwrap();
            run = run.then(action);
            if heading == Heading::Canonical
                && let Some(q) = action.quarter()
            {
                quarters = q;
            }
            let n: Vec<f32> = noise
                .gaussian(latents / 3)
                .iter()
                .map(|v| v * sampling.noise_scale)
                .collect();
            let reference = reference_frame(
                &gpu,
                &engine.bundle,
                &maps,
                quarters,
                &n,
                action,
                sampling.for_frame(action, run),
                root,
                root_motion,
                (stand, standing),
                &mut pipelines,
            );
            standing = reference.standing;
            if stand > 0.0 && action == Action::Idle {
                let held = (frame.root - root) * Vec3::new(1.0, 0.0, 1.0);
                assert!(
                    held.length() < 1e-6,
                    "the stand latch moved the root by {held}"
                );
            }
            let error = worst(&frame.points, &reference.points);
            assert!(
                error < 2e-5,
                "cfg {cfg_scale} {root_motion:?} {heading:?} {action:?} {run:?}: points differ by {error} m"
            );
            assert!(
                frame.root.distance(reference.root) < 2e-5,
                "root {} vs {}",
                frame.root,
                reference.root
            );
            assert_eq!(frame.clamped, reference.clamped);
            (maps, root) = (reference.maps, reference.root);
        }
    }
}

#[test]
fn the_frame_state_kernel_clamps_counts_and_finds_the_root() {
    // A 2×2 "map" (plane 4) with 3 foreground pixels; pixel 3's values include NaN,
    // -1 and 2 (three clamps); the waist is points 0 and 1 (pixels 0 and 2): root
    // (0.3, 0.6, 0.2), shift root - 0.5. The reference map's waist pixels hold x 0.25
    // and 0.45, y 0.55 and 0.65, z 1.5 (kept as 1) and 0.1: root (0.35, 0.6, 0.55). The
    // motion is the shift, or with the decoded reference root - (0.35, 0.6, 0.55); the
    // reference's values are never counted as clamps. Turned to the world by one quarter
    // turn, (x, y, z) -> (z, y, 1 - x): the points (0.1, 0.5, 0.8), (0.3, 0.7, 0.6),
    // (1, 0, 0.5), the root (0.2, 0.6, 0.7), the reference's root (0.55, 0.6, 0.65).
    // Grounded, with the world root before the frame at height 0.25 (scale 1), the
    // motion's height puts the lowest kept point (y 0) on the floor: 0.6 - 0 - 0.25.
    let gpu = gpu();
    let nan = f32::NAN;
    #[rustfmt::skip]
    let map = [
        0.2, 0.0, 0.4, nan,   // x
        0.5, 0.0, 0.7, -1.0,  // y
        0.1, 0.0, 0.3, 2.0,   // z
    ];
    #[rustfmt::skip]
    let reference = [
        0.25, 9.0, 0.45, nan,
        0.55, 9.0, 0.65, 0.0,
        1.5, 9.0, 0.1, 0.0,
    ];
    let map = Tensor::upload(&gpu, "map", &[1, 3, 2, 2], &map, Precision::F32).unwrap();
    let reference =
        Tensor::upload(&gpu, "reference", &[1, 3, 2, 2], &reference, Precision::F32).unwrap();
    let u32s = |v: &[u32]| {
        gpu.storage_buffer_init("ids", bytemuck::cast_slice(v), wgpu::BufferUsages::empty())
            .unwrap()
    };
    let (pixels, waist) = (u32s(&[0, 2, 3]), u32s(&[0, 1]));
    let shift = [0.3 - 0.5, 0.6 - 0.5, 0.2 - 0.5];
    let kept = [0.2, 0.5, 0.1, 0.4, 0.7, 0.3, 0.5, 0.0, 1.0];
    let turned_shift = [0.2 - 0.5, 0.6 - 0.5, 0.7 - 0.5];
    let turned = [0.1, 0.5, 0.8, 0.3, 0.7, 0.6, 1.0, 0.0, 0.5];
    let grounded_y = 0.6 - 0.0 - 0.25;
    // The kernel on the map from `start` (the world root at height 0.25, 5 clamps before).
    let run = |params: PostParams, to_world: u32, idle: bool, standing: u32| {
        let heading = heading_buffer(&gpu, 7, to_world, idle); // to_model never read here
        let mut pipelines = PipelineCache::default();
        let mut r = Recorder::new(&gpu, &mut pipelines, Precision::F32);
        let unit = gpu
            .storage_buffer("unit", 36, wgpu::BufferUsages::COPY_SRC)
            .unwrap();
        let start = FrameState {
            root: [0.0, 0.25, 0.0, 0.0],
            clamped_total: 5,
            standing,
            ..bytemuck::Zeroable::zeroed()
        };
        let state = state_buffer(&gpu, &start);
        r.dispatch(
            &kernels::FRAME_UNIT,
            &params,
            &[
                &map.buffer,
                &pixels,
                &waist,
                &unit,
                &state,
                &reference.buffer,
                &heading,
            ],
            Grid { x: 1, y: 1 },
        );
        r.submit();
        let unit: Vec<f32> =
            bytemuck::pod_collect_to_vec(&readback::buffer(&gpu, &unit, "unit").unwrap());
        let state: FrameState =
            bytemuck::pod_read_unaligned(&readback::buffer(&gpu, &state, "state").unwrap());
        (unit, state)
    };
    let params = PostParams {
        points: 3,
        plane: 4,
        waist: 2,
        components: 0,
        scale: 1.0,
        frames: 1,
        decoded_reference: 0,
        grounded: 0,
        stand: 0.0,
        reserved: 0,
    };
    for (to_world, decoded_reference, grounded, want_unit, want_shift, motion) in [
        (0, 0, 0, kept, shift, shift),
        (0, 1, 0, kept, shift, [0.3 - 0.35, 0.0, 0.2 - 0.55]),
        (1, 0, 0, turned, turned_shift, turned_shift),
        (1, 1, 0, turned, turned_shift, [0.2 - 0.55, 0.0, 0.7 - 0.65]),
        (0, 0, 1, kept, shift, [shift[0], grounded_y, shift[2]]),
        (
            1,
            1,
            1,
            turned,
            turned_shift,
            [0.2 - 0.55, grounded_y, 0.7 - 0.65],
        ),
    ] {
        let params = PostParams {
            decoded_reference,
            grounded,
            ..params
        };
        let (unit, state) = run(params, to_world, false, 0);
        for (got, want) in unit.iter().zip(want_unit) {
            assert!((got - want).abs() < 1e-6, "turns {to_world}: {unit:?}");
        }
        assert_eq!((state.clamped, state.clamped_total), (3, 8));
        for (got, want) in state.shift.iter().zip(want_shift) {
            assert!(
                (got - want).abs() < 1e-6,
                "turns {to_world}: {:?}",
                state.shift
            );
        }
        for (got, want) in state.motion.iter().zip(motion) {
            assert!(
                (got - want).abs() < 1e-6,
                "turns {to_world}, reference {decoded_reference}, grounded {grounded}: {:?}",
                state.motion
            );
        }
    }
    // The stand latch, on the unturned centre motion (-0.2, 0.1, -0.3), horizontally
    // 0.3606 long: (stand, Idle, held before) -> (horizontal motion zeroed, held after).
    // Off (stand 0) it never holds and leaves the flag; under Idle it holds below the
    // threshold or once held; a movement key releases it.
    for (stand, idle, before, zeroed, after) in [
        (0.0, true, 1, false, 1),
        (0.5, true, 0, true, 1),
        (0.3, true, 0, false, 0),
        (0.3, true, 1, true, 1),
        (0.5, false, 1, false, 0),
    ] {
        let (_, state) = run(PostParams { stand, ..params }, 0, idle, before);
        let want = if zeroed { [0.0, shift[1], 0.0] } else { shift };
        for (got, want) in state.motion.iter().zip(want) {
            assert!(
                (got - want).abs() < 1e-6,
                "stand {stand}, idle {idle}, held {before}: {:?}",
                state.motion
            );
        }
        assert_eq!(
            state.standing, after,
            "stand {stand}, idle {idle}, held {before}"
        );
    }
}

#[test]
fn the_turn_kernel_turns_each_frames_foreground_and_zeroes_the_background() {
    // Two frames of 2×2 maps (plane 4), foreground pixels 0, 2 and 3; pixel 1 holds 9 in
    // the input and must come out 0. One quarter turn takes (x, y, z) to (z, y, 1 - x),
    // three to (1 - z, y, x); frame 1 is the centre (0.5, 0.5, 0.5), which no turn moves.
    let gpu = gpu();
    #[rustfmt::skip]
    let maps = [
        0.1, 9.0, 0.2, 0.3,  0.4, 9.0, 0.5, 0.6,  0.7, 9.0, 0.8, 0.9,
        0.5, 9.0, 0.5, 0.5,  0.5, 9.0, 0.5, 0.5,  0.5, 9.0, 0.5, 0.5,
    ];
    // No turn: the input with the background zeroed.
    #[rustfmt::skip]
    let unturned = [
        0.1, 0.0, 0.2, 0.3,  0.4, 0.0, 0.5, 0.6,  0.7, 0.0, 0.8, 0.9,
        0.5, 0.0, 0.5, 0.5,  0.5, 0.0, 0.5, 0.5,  0.5, 0.0, 0.5, 0.5,
    ];
    #[rustfmt::skip]
    let once = [
        0.7, 0.0, 0.8, 0.9,  0.4, 0.0, 0.5, 0.6,  0.9, 0.0, 0.8, 0.7,
        0.5, 0.0, 0.5, 0.5,  0.5, 0.0, 0.5, 0.5,  0.5, 0.0, 0.5, 0.5,
    ];
    #[rustfmt::skip]
    let thrice = [
        0.3, 0.0, 0.2, 0.1,  0.4, 0.0, 0.5, 0.6,  0.1, 0.0, 0.2, 0.3,
        0.5, 0.0, 0.5, 0.5,  0.5, 0.0, 0.5, 0.5,  0.5, 0.0, 0.5, 0.5,
    ];
    let maps = Tensor::upload(&gpu, "maps", &[2, 3, 2, 2], &maps, Precision::F32).unwrap();
    let point_of = [0, u32::MAX, 1, 2];
    let point_of = gpu
        .storage_buffer_init(
            "point_of",
            bytemuck::cast_slice(&point_of),
            wgpu::BufferUsages::empty(),
        )
        .unwrap();
    for (to_model, want) in [(1, once), (3, thrice), (0, unturned)] {
        let mut pipelines = PipelineCache::default();
        let mut r = Recorder::new(&gpu, &mut pipelines, Precision::F32);
        let out = Tensor::empty(&gpu, "out", &[2, 3, 2, 2], Precision::F32).unwrap();
        let heading = heading_buffer(&gpu, to_model, 5, false); // to_world never read here
        let params = PostParams {
            plane: 4,
            frames: 2,
            ..bytemuck::Zeroable::zeroed()
        };
        r.dispatch(
            &kernels::TURN,
            &params,
            &[&maps.buffer, &point_of, &heading, &out.buffer],
            Grid { x: 1, y: 1 },
        );
        r.submit();
        let got = out.read(&gpu).unwrap();
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert!((g - w).abs() < 1e-6, "turns {to_model}, value {i}: {got:?}");
        }
    }
}

#[test]
fn the_slide_kernel_slides_the_maps_recentres_them_and_moves_the_root() {
    // A window of 2 frames of 2×2 maps (plane 4) with foreground pixels 0, 2 and 3 (pixel 1
    // is background, 0 in the maps); shift (0.1, -0.2, 0.05), motion (0.02, 0.04, -0.06),
    // scale 2. Frame 0 of the result is frame 1 moved by -shift, frame 1 the new points
    // moved by -shift, the background 0 everywhere; the root moves by motion / scale and
    // the frame is counted.
    let gpu = gpu();
    let mut pipelines = PipelineCache::default();
    let mut r = Recorder::new(&gpu, &mut pipelines, Precision::F32);
    #[rustfmt::skip]
    let maps = [
        // frame 0 (dropped)
        9.0, 0.0, 9.0, 9.0,  9.0, 0.0, 9.0, 9.0,  9.0, 0.0, 9.0, 9.0,
        // frame 1: x, y, z planes
        0.1, 0.0, 0.2, 0.3,  0.4, 0.0, 0.5, 0.6,  0.7, 0.0, 0.8, 0.9,
    ];
    let maps = Tensor::upload(&gpu, "maps", &[2, 3, 2, 2], &maps, Precision::F32).unwrap();
    let next = Tensor::empty(&gpu, "next", &[2, 3, 2, 2], Precision::F32).unwrap();
    let buffer = |v: &[u8]| {
        gpu.storage_buffer_init("in", v, wgpu::BufferUsages::empty())
            .unwrap()
    };
    // The new frame's points 0, 1, 2 (pixels 0, 2, 3), xyz each.
    let unit = buffer(bytemuck::cast_slice(&[
        0.11f32, 0.12, 0.13, 0.21, 0.22, 0.23, 0.31, 0.32, 0.33,
    ]));
    let background = unica::engine::recentre::BACKGROUND;
    let point_of = buffer(bytemuck::cast_slice(&[0u32, background, 1, 2]));
    let start = FrameState {
        root: [1.0, 2.0, 3.0, 0.0],
        shift: [0.1, -0.2, 0.05, 0.0],
        motion: [0.02, 0.04, -0.06, 0.0],
        frames: 4,
        ..bytemuck::Zeroable::zeroed()
    };
    let state = state_buffer(&gpu, &start);
    let params = PostParams {
        points: 3,
        plane: 4,
        waist: 0,
        components: 0,
        scale: 2.0,
        frames: 2,
        decoded_reference: 0,
        grounded: 0,
        stand: 0.0,
        reserved: 0,
    };
    r.dispatch(
        &kernels::SLIDE,
        &params,
        &[&maps.buffer, &unit, &point_of, &state, &next.buffer],
        r.grid(24),
    );
    r.submit();
    #[rustfmt::skip]
    let want = [
        0.1 - 0.1, 0.0, 0.2 - 0.1, 0.3 - 0.1,
        0.4 + 0.2, 0.0, 0.5 + 0.2, 0.6 + 0.2,
        0.7 - 0.05, 0.0, 0.8 - 0.05, 0.9 - 0.05,
        0.11 - 0.1, 0.0, 0.21 - 0.1, 0.31 - 0.1,
        0.12 + 0.2, 0.0, 0.22 + 0.2, 0.32 + 0.2,
        0.13 - 0.05, 0.0, 0.23 - 0.05, 0.33 - 0.05,
    ];
    let got = next.read(&gpu).unwrap();
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() < 1e-6, "value {i}: {g} against {w}");
    }
    let state: FrameState =
        bytemuck::pod_read_unaligned(&readback::buffer(&gpu, &state, "state").unwrap());
    // The root moves by the motion / scale (the slide is the shift).
    let root = [1.01, 2.02, 2.97];
    for (g, w) in state.root.iter().zip(root) {
        assert!((g - w).abs() < 1e-6, "{:?}", state.root);
    }
    assert_eq!(state.frames, 5);
}

#[test]
fn a_generated_frame_creates_nothing_and_reads_back_one_small_state() {
    let gpu = gpu();
    for cfg_scale in [1.0, 2.0] {
        let mut engine = Engine::new(
            &gpu,
            &witch_bundle(),
            &options(Sampling::new(2, cfg_scale), 1),
        )
        .unwrap();
        engine.frame(Action::Forward).unwrap();
        engine.finish();
        let before = gpu.counts();
        for action in [Action::Forward, Action::Left, Action::Idle] {
            engine.frame(action).unwrap();
            engine.finish();
        }
        let c = gpu.counts() - before;
        assert_eq!((c.buffers, c.bind_groups), (0, 0), "cfg {cfg_scale}: {c:?}");
        assert_eq!(c.submissions, 3, "{c:?}");
        assert_eq!(c.readbacks, 3, "{c:?}");
        assert!(c.readback_bytes <= 3 * 256, "{c:?}");
        assert_eq!(
            c.dispatches,
            3 * engine.plan_counts(Action::Forward).0 as u64,
            "{c:?}"
        );
        assert_eq!(engine.state().frames, 4);
        // A settings change captures a new plan once, then creates nothing again.
        engine.set_sampling(Sampling::new(3, cfg_scale));
        engine.frame(Action::Forward).unwrap();
        engine.finish();
        let before = gpu.counts();
        engine.frame(Action::Forward).unwrap();
        engine.finish();
        let c = gpu.counts() - before;
        assert_eq!((c.buffers, c.bind_groups), (0, 0), "{c:?}");
    }
}

#[test]
fn the_gpu_kernel_variant_makes_the_frames_of_the_cpu_variant() {
    // The frame plan recorded with the GPU kernels (convolutions, linear layers,
    // attention and PCA sums split over workgroups) against the CPU kernels, on the
    // shipped bundle's one-pass sampler, same seed and keys, with the refined splats.
    // Both are parity-tested layer by layer (tests/nn/); here the whole frame, the
    // engine's own GPU-variant kernel (pca_coefficients_split.wgsl) included, over four
    // frames that feed each other. They differ only in summation order; tolerance 1e-4 m
    // (0.1 mm) on every world point.
    let gpu = gpu();
    let run = |kernels: Kernels| -> Vec<Vec<Vec3>> {
        let options = EngineOptions {
            kernels: Some(kernels),
            splat_level: Some(256),
            ..EngineOptions::default()
        };
        let mut engine = Engine::new(&gpu, &witch_bundle(), &options).unwrap();
        assert_eq!(engine.kernels(), kernels);
        [Action::Forward, Action::Left, Action::Forward, Action::Idle]
            .into_iter()
            .map(|a| engine.step(a).unwrap().points)
            .collect()
    };
    let (cpu, gpu_kernels) = (run(Kernels::Cpu), run(Kernels::Gpu));
    for (frame, (a, b)) in cpu.iter().zip(&gpu_kernels).enumerate() {
        let error = worst(a, b);
        println!("frame {frame}: worst {error:.2e} m");
        assert!(error < 1e-4, "frame {frame}: {error} m");
    }
}

#[test]
fn frames_recorded_ahead_equal_frames_submitted_in_parts() {
    // An unsplit frame submits commands recorded while the GPU ran the frame before, on
    // the guess that its plan stays; a wrong guess (Idle's one-batch plan after W, a
    // settings change) records again. Split frames record each part as it is
    // submitted. Same seed and keys: the same bytes, and the same dispatch counts.
    let gpu = gpu();
    let sampling = Sampling {
        guide_idle: false,
        ..Sampling::new(2, 2.0)
    };
    let keys = [
        Action::Forward,
        Action::Forward,
        Action::Idle,
        Action::Idle,
        Action::Left,
        Action::Idle,
    ];
    let run = |split: bool| -> (Vec<Vec<Vec3>>, u64) {
        let mut engine = Engine::new(
            &gpu,
            &witch_bundle(),
            &EngineOptions {
                split,
                ..options(sampling, 5)
            },
        )
        .unwrap();
        let before = gpu.counts();
        let mut frames = Vec::new();
        for (i, &action) in keys.iter().enumerate() {
            if i == 4 {
                engine.set_sampling(Sampling::new(3, 2.0));
            }
            engine.frame(action).unwrap();
            engine.finish();
            frames.push(engine.read_points().unwrap());
        }
        (frames, (gpu.counts() - before).dispatches)
    };
    let (ahead, ahead_dispatches) = run(false);
    let (parts, parts_dispatches) = run(true);
    assert!(
        ahead == parts,
        "frames recorded ahead differ from split frames"
    );
    assert_eq!(ahead_dispatches, parts_dispatches);
}

#[test]
fn the_same_seed_and_keys_give_the_same_bytes() {
    let gpu = gpu();
    let run = |seed: u64| -> Vec<Vec<Vec3>> {
        let mut engine =
            Engine::new(&gpu, &witch_bundle(), &options(Sampling::new(2, 1.0), seed)).unwrap();
        [Action::Forward, Action::Right, Action::Idle]
            .into_iter()
            .map(|a| engine.step(a).unwrap().points)
            .collect()
    };
    let (a, b) = (run(3), run(3));
    assert!(a == b, "same seed, different frames");
    assert!(a != run(4), "another seed, the same frames");
}

/// The largest differences between two splat lists: (position m, scale relative,
/// rotation 1 - |q·q'|, opacity, colour).
fn splat_differences(a: &[Splat], b: &[Splat]) -> [f32; 5] {
    assert_eq!(a.len(), b.len(), "splat counts");
    let mut worst = [0.0f32; 5];
    for (x, y) in a.iter().zip(b) {
        let d = [
            x.position.distance(y.position),
            ((x.scale - y.scale).abs() / y.scale.abs().max(Vec3::splat(1e-9))).max_element(),
            1.0 - x.rotation.dot(y.rotation).abs(),
            (x.opacity - y.opacity).abs(),
            x.color().distance(y.color()),
        ];
        for (w, v) in worst.iter_mut().zip(d) {
            *w = w.max(v);
        }
    }
    worst
}

#[test]
fn the_gpu_splats_equal_the_cpu_appearance_on_the_shipped_bundle() {
    // The standing start's and a generated frame's points through the CPU appearance
    // stage (base splats, the refiner fed host orders, upscale, fine splats) and through
    // the frame plan's splat kernels (`draw_standing` runs them alone), at level 128, 256 and 512, with and without the refiner. Tolerances (f32): the
    // two sides differ only in summation order and fused multiply-adds (lengths,
    // logarithms, the refiner's inputs), so positions within 1e-5 m, scales within 1e-3
    // relative, rotations within 1e-4 of |q·q'| = 1, opacity and colour within 1e-3.
    use unica::engine::appearance::Appearance;
    // The splat stage's GPU kernels (the tiled rank) at level 128 with the refiner.
    let gpu = gpu();
    let cases = [
        (128, true, None),
        (128, true, Some(unica::nn::Kernels::Gpu)),
        (256, true, None),
        (256, false, None),
        // Above 256 the drawn splats are widened (base::widen).
        (512, true, None),
    ];
    for (level, refine, kernels) in cases {
        let mut options = options(Sampling::new(2, 1.0), 11);
        options.splat_level = Some(level);
        options.refine = refine;
        options.kernels = kernels;
        let mut engine = Engine::new(&gpu, &witch_bundle(), &options).unwrap();
        let mut look = Appearance::new(&gpu, &engine.bundle, Precision::F32, level).unwrap();
        look.refine = refine;
        // The standing start drawn alone (before any frame), then a generated frame.
        engine.draw_standing().unwrap();
        let standing = engine.read_splats().unwrap();
        let want = look
            .splats(&engine.bundle, &engine.standing_points())
            .unwrap();
        let case = format!("level {level} refiner {refine} kernels {kernels:?}");
        assert_close_splats(&standing, &want, &format!("{case}, standing"));
        let frame = engine.step(Action::Forward).unwrap();
        let got = engine.read_splats().unwrap();
        let want = look.splats(&engine.bundle, &frame.points).unwrap();
        assert_close_splats(&got, &want, &case);
    }
}

fn assert_close_splats(got: &[Splat], want: &[Splat], case: &str) {
    let d = splat_differences(got, want);
    eprintln!("{case}: {} splats, worst {d:?}", got.len());
    assert!(d[0] < 1e-5, "{case}: positions {d:?}");
    assert!(d[1] < 1e-3, "{case}: scales {d:?}");
    assert!(d[2] < 1e-4, "{case}: rotations {d:?}");
    assert!(d[3] < 1e-3 && d[4] < 1e-3, "{case}: opacity, colour {d:?}");
}

#[test]
fn a_dispatch_with_the_wrong_bindings_is_caught_when_recorded() {
    let gpu = gpu();
    let buffer = gpu
        .storage_buffer("x", 64, wgpu::BufferUsages::empty())
        .unwrap();
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let mut pipelines = PipelineCache::default();
        let mut r = Recorder::new(&gpu, &mut pipelines, Precision::F32);
        let params = PostParams {
            points: 1,
            plane: 1,
            waist: 1,
            components: 0,
            scale: 1.0,
            frames: 1,
            decoded_reference: 0,
            grounded: 0,
            stand: 0.0,
            reserved: 0,
        };
        // frame_unit binds seven buffers after its parameters; four are given.
        r.dispatch(
            &kernels::FRAME_UNIT,
            &params,
            &[&buffer, &buffer, &buffer, &buffer],
            Grid { x: 1, y: 1 },
        );
    }));
    let message = result.expect_err("the dispatch must be refused");
    let text = message
        .downcast_ref::<String>()
        .cloned()
        .unwrap_or_default();
    assert!(
        text.contains("engine/frame_unit.wgsl") && text.contains("declares 8"),
        "{text}"
    );
}

#[test]
fn an_unguided_idle_runs_a_one_batch_plan_and_a_guided_idle_the_guided_one() {
    // With guidance on and Idle unguided, Idle frames run a second captured plan whose
    // UNet runs one batch (the conditional prediction alone) instead of two; both plans
    // are made once, and switching between them creates nothing.
    let gpu = gpu();
    let unguided_idle = Sampling {
        guide_idle: false,
        ..Sampling::new(2, 2.0)
    };
    let mut engine = Engine::new(&gpu, &witch_bundle(), &options(unguided_idle, 1)).unwrap();
    engine.frame(Action::Forward).unwrap();
    engine.finish();
    let (moving, moving_flops) = engine.plan_counts(Action::Forward);
    let (idle, idle_flops) = engine.plan_counts(Action::Idle);
    println!(
        "moving {moving} dispatches {moving_flops} FLOP; idle {idle} dispatches {idle_flops} FLOP"
    );
    assert!(
        idle < moving && 10 * idle_flops < 7 * moving_flops,
        "{idle_flops} vs {moving_flops}"
    );
    let before = gpu.counts();
    for action in [Action::Idle, Action::Idle, Action::Forward, Action::Idle] {
        engine.frame(action).unwrap();
        engine.finish();
    }
    let c = gpu.counts() - before;
    assert_eq!((c.buffers, c.bind_groups), (0, 0), "{c:?}");
    assert_eq!(c.dispatches, (3 * idle + moving) as u64, "{c:?}");
    // A sampler that guides Idle (older bundles) runs the guided plan for every key.
    let mut guided =
        Engine::new(&gpu, &witch_bundle(), &options(Sampling::new(2, 2.0), 1)).unwrap();
    guided.frame(Action::Idle).unwrap();
    guided.finish();
    assert_eq!(
        guided.plan_counts(Action::Idle),
        guided.plan_counts(Action::Forward)
    );
    assert_eq!(guided.plan_counts(Action::Forward), (moving, moving_flops));
    // Idle guided at a scale of its own: a second guided plan, the same work.
    let idle_scaled = Sampling {
        idle_cfg_scale: Some(1.5),
        ..unguided_idle
    };
    let mut scaled = Engine::new(&gpu, &witch_bundle(), &options(idle_scaled, 1)).unwrap();
    scaled.frame(Action::Idle).unwrap();
    scaled.finish();
    assert_eq!(
        scaled.plan_counts(Action::Idle),
        scaled.plan_counts(Action::Forward)
    );
    assert_eq!(scaled.brake_plan_counts(), None);
    // Braking the first Idle frames after a key: a third guided plan, the same work,
    // run for the first two Idle frames after W (not at the standing start), made once.
    let braking = Sampling {
        idle_brake_cfg_scale: Some(3.0),
        idle_brake_frames: 2,
        ..idle_scaled
    };
    let mut brakes = Engine::new(&gpu, &witch_bundle(), &options(braking, 1)).unwrap();
    assert_eq!(
        brakes.brake_plan_counts(),
        Some(brakes.plan_counts(Action::Forward))
    );
    let before = gpu.counts();
    let mut runs = vec![];
    for action in [
        Action::Idle,
        Action::Forward,
        Action::Idle,
        Action::Idle,
        Action::Idle,
    ] {
        brakes.frame(action).unwrap();
        brakes.finish();
        runs.push(brakes.after_key());
    }
    assert_eq!(runs, [None, Some(0), Some(1), Some(2), Some(3)]);
    let c = gpu.counts() - before;
    assert_eq!((c.buffers, c.bind_groups), (0, 0), "{c:?}");
    // Braking turns at scale 1: a fourth plan, of one batch, run for the first frame
    // under a key of a new direction (D after W, A after D; not W from rest, nor D
    // again after Idle), made once.
    let turning = Sampling {
        turn_brake_cfg_scale: Some(1.0),
        turn_brake_frames: 1,
        ..braking
    };
    let mut turns = Engine::new(&gpu, &witch_bundle(), &options(turning, 1)).unwrap();
    turns.frame(Action::Forward).unwrap();
    turns.finish();
    let (keys, keys_flops) = turns.plan_counts(Action::Forward);
    let (turn, turn_flops) = turns.plan_counts(Action::Right);
    assert_eq!(turns.turn_plan_counts(), Some((turn, turn_flops)));
    assert!(
        turn < keys && 10 * turn_flops < 7 * keys_flops,
        "{turn_flops} vs {keys_flops}"
    );
    let before = gpu.counts();
    let mut runs = vec![];
    for action in [
        Action::Right,
        Action::Right,
        Action::Idle,
        Action::Right,
        Action::Left,
    ] {
        turns.frame(action).unwrap();
        turns.finish();
        runs.push(turns.after_turn());
    }
    assert_eq!(runs, [Some(1), Some(2), None, None, Some(1)]);
    let c = gpu.counts() - before;
    assert_eq!((c.buffers, c.bind_groups), (0, 0), "{c:?}");
    // Right, Left: turning; Right, Right after Idle: keys; Idle: braking (as keys).
    assert_eq!(c.dispatches, (2 * turn + 3 * keys) as u64, "{c:?}");
}
