use super::*;

#[test]
fn a_whole_unet_step_matches_pytorch() {
    for precision in precisions() {
        let mut f = Fixture::open("tiny_unet", precision);
        let (x, t, a) = (f.input("io.in.x"), f.stored("io.in.t").0, action(&f));
        let (mut r, w) = f.recorder();
        let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
        let eps = unet.groups(&mut r, &x, &t, &[a]).unwrap();
        r.submit();
        assert_eq!(eps.shape, [1, 4, 4, 16, 16]);
        f.assert_close(&eps, "io.out.eps", tolerances(precision).1);
    }
}

#[test]
fn the_cached_context_path_gives_the_whole_groups_target_noise() {
    // Context frames once, then the target alone, against PyTorch's full 4-frame pass.
    let mut f = Fixture::open("tiny_unet", Precision::F32);
    let (context, target) = context_and_target(&f);
    let (t, a) = (f.stored("io.in.t").0, action(&f));
    let (mut r, w) = f.recorder();
    let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
    let cache = unet.context(&mut r, &context, &[a]).unwrap();
    let eps = unet.next(&mut r, &target, t[3], &cache).unwrap();
    r.submit();
    let got = eps.read(&f.gpu).unwrap();
    let want = f.stored("io.out.eps").0;
    let want = &want[3 * want.len() / 4..];
    let error = relative_error(&got, want);
    assert!(error <= 1e-4, "{error}");
}

/// The tiny UNet fixture's input [1, 4 frames, 4, 16, 16] as its 3 context frames and
/// its target frame, in the fixture's precision.
fn context_and_target(f: &Fixture) -> (Tensor, Tensor) {
    let (x, shape) = f.stored("io.in.x");
    assert_eq!(shape, [1, 4, 4, 16, 16]);
    let frame = x.len() / 4;
    let upload = |name: &str, shape: &[usize], values: &[f32]| {
        Tensor::upload(&f.gpu, name, shape, values, f.precision).unwrap()
    };
    (
        upload("context", &[1, 3, 4, 16, 16], &x[..3 * frame]),
        upload("target", &[1, 4, 16, 16], &x[3 * frame..]),
    )
}

fn schedule() -> Schedule {
    Schedule::scaled_linear(1000, 0.00085, 0.012)
}

#[test]
fn the_schedule_matches_pytorch() {
    let f = Fixture::open("alphas_cumprod", Precision::F32);
    let want = f.stored("io.out.alphas_cumprod").0;
    let s = schedule();
    assert_eq!(s.steps(), want.len());
    for (t, w) in want.iter().enumerate() {
        assert!((s.alpha_bar(t as i64) as f32 - w).abs() <= 1e-7, "t = {t}");
    }
}

#[test]
fn a_ddim_step_with_classifier_free_guidance_matches_pytorch() {
    for precision in precisions() {
        let mut f = Fixture::open("tiny_unet", precision);
        let (context, target) = context_and_target(&f);
        let (a, scale, t_prev) = (
            action(&f),
            f.scalar("io.in.cfg_scale"),
            f.scalar("io.in.t_prev") as i64,
        );
        let t = f.stored("io.in.t").0[3] as i64;
        let (mut r, w) = f.recorder();
        let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
        let both = r.concat(&context, &context, 0).unwrap();
        let cache = unet
            .context(&mut r, &both, &[a, unet.cfg.null_action()])
            .unwrap();
        let eps = sampler::guided_eps(&mut r, &unet, &target, t, &cache, scale).unwrap();
        let (ca, cb) = schedule().ddim_coefficients(t, t_prev);
        let x_prev = r.axpby(ca, &target, 0, cb, &eps, 0, &target.shape).unwrap();
        r.submit();
        let tolerance = tolerances(precision).1;
        f.assert_close(&eps, "io.out.guided_eps", tolerance);
        f.assert_close(&x_prev, "io.out.x_prev", tolerance);
    }
}

#[test]
fn a_four_step_ddim_sample_matches_pytorch() {
    for precision in precisions() {
        let mut f = Fixture::open("tiny_unet", precision);
        let (context, noise, a) = (f.input("io.in.context"), f.input("io.in.noise"), action(&f));
        let sampling = Sampling::new(
            f.scalar("io.in.steps") as usize,
            f.scalar("io.in.cfg_scale"),
        );
        let (mut r, w) = f.recorder();
        let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
        let x0 = sampler::sample_next(&mut r, &unet, &schedule(), &context, &[a], &noise, sampling)
            .unwrap();
        r.submit();
        f.assert_close(&x0, "io.out.x0", tolerances(precision).1);
    }
}

#[test]
fn the_recorded_flops_agree_with_the_trainers_counter() {
    // unica_train.unet.conv_and_linear_flops on the tiny configs (batch 1, 4 frames):
    // UNet 121,053,184, decoder 53,968,896. The engine runs the cross-attention to the
    // one action token as a table looked up at load, so it does not run that work per
    // frame: per cross layer and frame, q and out (2·64·32·32 each), the attention
    // product (4·64·32) and the token's kv (2·32·64): 274,432 × 4 frames × 3 layers =
    // 3,293,184 fewer. Nor does it repeat the time MLP and the ResBlocks' projections of
    // its output, which depend only on the timesteps: they run once when the work is
    // recorded (2·32·32 twice, and 2·32·(16+32+32+32+32+16), per frame: 57,344 for 4
    // frames). The decoder agrees exactly.
    let mut f = Fixture::open("tiny_unet", Precision::F32);
    let (x, t, a) = (f.input("io.in.x"), f.stored("io.in.t").0, action(&f));
    let (mut r, w) = f.recorder();
    let unet = UNet::load(&w, &UNetConfig::TINY).unwrap();
    unet.groups(&mut r, &x, &t, &[a]).unwrap();
    assert_eq!(r.flops(), 121_053_184 - 3_293_184 - 57_344);

    let mut f = Fixture::open("vae_decoder", Precision::F32);
    let z = f.input("io.in.z");
    let (mut r, w) = f.recorder();
    Decoder::load(&w, &VaeConfig::TINY)
        .unwrap()
        .forward(&mut r, &z)
        .unwrap();
    assert_eq!(r.flops(), 53_968_896);
}
