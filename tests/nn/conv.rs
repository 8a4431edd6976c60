use super::*;
use unica::nn::ops::PackedConv;

/// Packed convolution weights `[c_out, c_in, k]` holding [`wave`] values.
fn packed_wave(
    gpu: &GpuContext,
    name: &str,
    shape: [usize; 3],
    k: f32,
    precision: Precision,
) -> PackedConv {
    let [c_out, c_in, size] = shape;
    PackedConv::new(
        gpu,
        name,
        &wave(c_out * c_in * size * size, k),
        shape,
        precision,
    )
    .unwrap()
}

#[test]
fn a_residual_block_over_a_concatenation_equals_the_block_over_the_concatenated_tensor() {
    // The UNet's skip connections: the block over two tensors concatenated along the
    // channels (on CPU drivers only texels copied from the two, read by the first norm
    // and the 1×1 skip) must equal the concatenation kernel then the block, bit for bit,
    // in every variant and precision: the fixture's 8 input channels split 3 + 5.
    for (precision, kernels) in variants() {
        let mut f = Fixture::open("resblock", precision);
        let x = f.input("io.in.x");
        let emb = f.input("io.in.emb");
        let [n, _, h, wd] = x.shape[..] else {
            panic!("NCHW fixture")
        };
        let values = x.read(&f.gpu).unwrap();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for image in values.chunks(8 * h * wd) {
            a.extend_from_slice(&image[..3 * h * wd]);
            b.extend_from_slice(&image[3 * h * wd..]);
        }
        let a = Tensor::upload(&f.gpu, "a", &[n, 3, h, wd], &a, precision).unwrap();
        let b = Tensor::upload(&f.gpu, "b", &[n, 5, h, wd], &b, precision).unwrap();
        let gpu = f.gpu.clone();
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let block = ResBlock::load(&w, 8, 16, Some(32)).unwrap();
        let projected = block.project(&mut r, &emb).unwrap();
        let split = block
            .forward_concat(&mut r, &a, &b, projected.as_ref())
            .unwrap();
        let whole = block
            .forward_projected(&mut r, &x, projected.as_ref())
            .unwrap();
        r.submit();
        let what = format!("{precision:?} {kernels:?}");
        assert_same_bits(
            precision,
            &split.read(&gpu).unwrap(),
            &whole.read(&gpu).unwrap(),
            &what,
        );
    }
}

#[test]
fn every_variant_of_the_group_norm_and_the_packed_convolutions_agrees_on_odd_shapes() {
    // Shapes the fixtures do not reach: a 12-channel group norm over 4 groups of 76,800
    // values (near the CPU kernel's SERIAL_NORM_LIMIT; lavapipe's loop limiter once
    // truncated it silently above 65,535 iterations), and 3×3 convolutions whose 12
    // output channels are not a multiple of 8, with rows of 12 (a half 8-pixel tile,
    // whole vec4s: the CPU kernel) and of 13 (not whole vec4s: CPU drivers then run the
    // GPU kernel).
    // The simple kernels are the PyTorch-tested reference here.
    let f = Fixture::open("down", Precision::F32);
    let mut pipelines = PipelineCache::default();
    let x = f.wave("x", &[1, 12, 160, 160], 0.37);
    let gamma = f.wave("g", &[12], 1.3);
    let beta = f.wave("b", &[12], 0.7);
    let x2 = f.wave("x2", &[2, 5, 11, 12], 0.11);
    let x13 = f.wave("x13", &[2, 5, 11, 13], 0.11);
    let weights = packed_wave(&f.gpu, "w", [12, 5, 3], 0.23, Precision::F32);
    // A 1×1 convolution over planes of 12 × 13 = 156 pixels: 39 vec4s, so the last
    // 8-pixel tile is half full.
    let x3 = f.wave("x3", &[2, 5, 12, 13], 0.13);
    let pointwise = packed_wave(&f.gpu, "w1", [12, 5, 1], 0.29, Precision::F32);
    let bias = f.wave("bias", &[12], 0.5);
    // A per-image addend for the 3×3 convolution's two images (a ResBlock's embedding).
    let extra = f.wave("extra", &[2, 12], 0.9);
    let run = |kernels: Kernels, pipelines: &mut PipelineCache| {
        let mut r = Recorder::new(&f.gpu, pipelines, Precision::F32);
        r.set_kernels(kernels);
        let norm = r.group_norm(&x, &gamma, &beta, 4, true).unwrap();
        let conv = r
            .conv3x3(&x2, &weights, Some(&bias), Some(&extra), None)
            .unwrap();
        let conv13 = r
            .conv3x3(&x13, &weights, Some(&bias), Some(&extra), None)
            .unwrap();
        let point = r.conv1x1(&x3, &pointwise, Some(&bias)).unwrap();
        r.submit();
        let read = |t: &Tensor| t.read(&f.gpu).unwrap();
        (read(&norm), read(&conv), read(&conv13), read(&point))
    };
    let (norm, conv, conv13, point) = run(Kernels::Simple, &mut pipelines);
    for kernels in [Kernels::Cpu, Kernels::Gpu] {
        let (n, c, c13, q) = run(kernels, &mut pipelines);
        let norm_error = worst_difference(&n, &norm);
        let conv_error = worst_difference(&c, &conv);
        let conv13_error = worst_difference(&c13, &conv13);
        let point_error = worst_difference(&q, &point);
        println!(
            "{kernels:?}: group norm {norm_error:.1e}, conv3x3 {conv_error:.1e} (rows of 13: {conv13_error:.1e}), conv1x1 {point_error:.1e}"
        );
        // The norm's statistics sum in another order (1e-5 of unit values); the
        // convolutions sum the same terms in the same order, except the GPU 3×3 one,
        // whose threads split the input channels (sums of ~10: a few f32 steps).
        let conv_bound = if kernels == Kernels::Gpu { 1e-5 } else { 1e-6 };
        assert!(norm_error < 1e-5, "{kernels:?} group norm: {norm_error}");
        assert!(conv_error < conv_bound, "{kernels:?} conv3x3: {conv_error}");
        assert!(
            conv13_error < 1e-5,
            "{kernels:?} conv3x3, rows of 13: {conv13_error}"
        );
        assert!(point_error < 1e-6, "{kernels:?} conv1x1: {point_error}");
    }
}

#[test]
fn the_convolution_with_its_residual_equals_a_separate_add_bit_for_bit() {
    // A ResBlock's `skip + conv2(h)`: the residual fused into conv3x3's epilogue must give
    // exactly what conv3x3 then add.wgsl gives, in every kernel variant and precision
    // (the ResBlock fixtures then check both against PyTorch). Rows of 12: a half
    // 8-pixel tile of the CPU kernel.
    for mut v in Variant::all() {
        let x = v.wave("x", &[2, 5, 11, 12], 0.11);
        let skip = v.wave("skip", &[2, 12, 11, 12], 0.17);
        let bias = v.wave("bias", &[12], 0.5);
        let extra = v.wave("extra", &[2, 12], 0.9);
        let weights = packed_wave(&v.gpu, "w", [12, 5, 3], 0.23, v.precision);
        // The fused form is one dispatch (the simple variant: conv2d and two adds).
        let mut c = Recorder::capture(&v.gpu, &mut v.pipelines, v.precision);
        c.set_kernels(v.kernels);
        c.conv3x3(&x, &weights, Some(&bias), Some(&extra), Some(&skip))
            .unwrap();
        let fused_dispatches = c.finish().dispatches();
        let mut r = v.recorder();
        let fused = r
            .conv3x3(&x, &weights, Some(&bias), Some(&extra), Some(&skip))
            .unwrap();
        let conv = r
            .conv3x3(&x, &weights, Some(&bias), Some(&extra), None)
            .unwrap();
        let separate = r.add(&skip, &conv, Broadcast::Leading).unwrap();
        r.submit();
        let (a, b) = (v.read(&fused), v.read(&separate));
        assert_same_bits(v.precision, &a, &b, &v.name());
        let expected = if v.kernels == Kernels::Simple { 3 } else { 1 };
        assert_eq!(fused_dispatches, expected, "{:?}", v.kernels);
    }
}

#[test]
fn the_upsampled_convolution_equals_upsample_then_convolution_bit_for_bit() {
    // Up (decoder and UNet): nearest ×2 upsampling fused into the 3×3 convolution's loads
    // must equal the two ops, in every variant and precision, on 5 × 6 images (12-pixel
    // rows: a partial 8-pixel tile) and 3 × 3 ones (6-pixel rows: the two-op fallback).
    for mut v in Variant::all() {
        let bias = v.wave("b", &[12], 0.5);
        let weights = packed_wave(&v.gpu, "w", [12, 5, 3], 0.23, v.precision);
        for (h, w) in [(5, 6), (3, 3)] {
            let x = v.wave("x", &[2, 5, h, w], 0.11);
            let mut r = v.recorder();
            let fused = r.upsampled_conv3x3(&x, &weights, Some(&bias)).unwrap();
            let up = r.upsample_nearest2x(&x).unwrap();
            let separate = r.conv3x3(&up, &weights, Some(&bias), None, None).unwrap();
            r.submit();
            assert_eq!(fused.shape, vec![2, 12, 2 * h, 2 * w]);
            let (a, b) = (v.read(&fused), v.read(&separate));
            assert_same_bits(v.precision, &a, &b, &format!("{} {h}x{w}", v.name()));
        }
    }
}

#[test]
fn the_convolution_of_a_normed_input_equals_the_norm_then_the_convolution() {
    // A ResBlock's norm-SiLU-conv: for CPU drivers the norm is folded into conv3x3's
    // loads (its statistics computed per workgroup, the serial norm's sums in the same
    // order), which must give what group_norm then conv3x3 give. Two shapes: 16 channels
    // in 8 groups over 16² (the decoder's first level) with an addend and a residual, and
    // 12 channels in 4 groups over 10 × 12 (rows not a multiple of the 8-pixel tiles).
    type Shape = ([usize; 4], usize, usize);
    let shapes: [Shape; 2] = [([2, 16, 16, 16], 16, 8), ([2, 12, 10, 12], 12, 4)];
    for precision in precisions() {
        let f = Fixture::open("down", precision);
        let mut pipelines = PipelineCache::default();
        for ([n, c, h, w], c_out, groups) in shapes {
            let x = f.wave("x", &[n, c, h, w], 0.37);
            let gamma = f.wave("gamma", &[c], 1.3);
            let beta = f.wave("beta", &[c], 0.7);
            let bias = f.wave("bias", &[c_out], 0.5);
            let extra = f.wave("extra", &[n, c_out], 0.9);
            let skip = f.wave("skip", &[n, c_out, h, w], 0.17);
            let weights = packed_wave(&f.gpu, "w", [c_out, c, 3], 0.23, precision);
            let norm = unica::nn::ops::InputNorm {
                gamma: &gamma,
                beta: &beta,
                groups,
                silu: true,
            };
            let what = format!("{precision:?} {:?}", [n, c, h, w]);
            let fold = |r: &mut Recorder| {
                let (bias, extra, skip) = (Some(&bias), Some(&extra), Some(&skip));
                r.normed_conv3x3(&x, Some(norm), &weights, bias, extra, skip)
            };
            let mut plan = Recorder::capture(&f.gpu, &mut pipelines, precision);
            plan.set_kernels(Kernels::Cpu);
            assert!(plan.can_fold_norm([n, c, h, w], groups), "{what}");
            fold(&mut plan).unwrap();
            assert_eq!(plan.finish().dispatches(), 1, "{what}: one dispatch");
            let run = |kernels: Kernels, fused: bool, pipelines: &mut PipelineCache| {
                let mut r = Recorder::new(&f.gpu, pipelines, precision);
                r.set_kernels(kernels);
                let y = if fused {
                    fold(&mut r)
                } else {
                    let h = r.group_norm(&x, &gamma, &beta, groups, true).unwrap();
                    r.conv3x3(&h, &weights, Some(&bias), Some(&extra), Some(&skip))
                }
                .unwrap();
                r.submit();
                y.read(&f.gpu).unwrap()
            };
            let fused = run(Kernels::Cpu, true, &mut pipelines);
            let separate = run(Kernels::Cpu, false, &mut pipelines);
            assert_same_bits(precision, &fused, &separate, &what);
            // And the simple kernels (the PyTorch-tested reference), within the layer
            // tolerance.
            let simple = run(Kernels::Simple, false, &mut pipelines);
            let error = relative_error(&fused, &simple);
            println!("{what}: fused against simple {error:.1e}");
            assert!(error <= tolerances(precision).0, "{what}: {error}");
        }
    }
}

#[test]
fn the_decoder_records_its_norms_inside_its_convolutions_for_cpu_drivers() {
    // The tiny decoder (16² to 128²): the four norms of the 16² and 32² blocks go into
    // the convolutions after them; the 64² block's and the 128² output norm stay
    // dispatches of their own. The layer table (layers.rs) checks the result.
    let f = Fixture::open("vae_decoder", Precision::F32);
    let z = f.input("io.in.z");
    let w = Weights::new(&f.file, &f.gpu, Precision::F32);
    let decoder = Decoder::load(&w, &VaeConfig::TINY).unwrap();
    let mut pipelines = PipelineCache::default();
    let mut counts = vec![];
    for kernels in [Kernels::Cpu, Kernels::Gpu] {
        let mut c = Recorder::capture(&f.gpu, &mut pipelines, Precision::F32);
        c.set_kernels(kernels);
        decoder.forward(&mut c, &z).unwrap();
        counts.push(c.finish().dispatches());
    }
    // 11 convolutions and 3 norms; the GPU kernels record all 7 norms.
    assert_eq!(counts, [14, 18]);
}
