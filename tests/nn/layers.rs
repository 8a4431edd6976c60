//! Every layer kind against its PyTorch fixture: one table, run in every kernel variant
//! (simple, CPU, GPU) and every precision to test.

use super::*;

/// One layer kind's fixture: its inputs and output, its tolerance and how to run it.
struct LayerCase {
    fixture: &'static str,
    inputs: &'static [&'static str],
    output: &'static str,
    scope: Scope,
    run: fn(&mut Recorder, &Weights, &[Tensor]) -> Tensor,
}

const LAYERS: &[LayerCase] = &[
    LayerCase {
        fixture: "down",
        inputs: &["io.in.x"],
        output: "io.out.y",
        scope: Scope::Layer,
        run: |r, w, x| {
            let conv = Conv::load(&w.at("conv"), 8, 12, 3, 2).unwrap();
            conv.forward(r, &x[0]).unwrap()
        },
    },
    LayerCase {
        fixture: "up",
        inputs: &["io.in.x"],
        output: "io.out.y",
        scope: Scope::Layer,
        run: |r, w, x| UpBlock::load(w, 8, 12).unwrap().forward(r, &x[0]).unwrap(),
    },
    LayerCase {
        fixture: "resblock",
        inputs: &["io.in.x", "io.in.emb"],
        output: "io.out.y",
        scope: Scope::Layer,
        run: |r, w, x| {
            let block = ResBlock::load(w, 8, 16, Some(32)).unwrap();
            block.forward(r, &x[0], Some(&x[1])).unwrap()
        },
    },
    LayerCase {
        fixture: "spatial_attention",
        inputs: &["io.in.x"],
        output: "io.out.y",
        scope: Scope::Layer,
        run: |r, w, x| {
            SpatialAttention::load(w, 16, 2)
                .unwrap()
                .forward(r, &x[0])
                .unwrap()
        },
    },
    LayerCase {
        fixture: "cross_attention",
        inputs: &["io.in.x", "io.in.ctx"],
        output: "io.out.y",
        scope: Scope::Layer,
        run: |r, w, x| {
            let layer = CrossAttention::load(w, 16, 32, 2).unwrap();
            layer.forward(r, &x[0], &x[1]).unwrap()
        },
    },
    LayerCase {
        // Causal, with frame positions.
        fixture: "temporal_attention",
        inputs: &["io.in.x"],
        output: "io.out.y",
        scope: Scope::Layer,
        run: |r, w, x| {
            let layer = TemporalAttention::load(w, 16, 4, 2).unwrap();
            let frames = Frames::First {
                count: 4,
                keep: None,
            };
            layer.forward(r, &x[0], frames).unwrap()
        },
    },
    LayerCase {
        // The encoder's mean.
        fixture: "vae_encoder",
        inputs: &["io.in.x"],
        output: "io.out.mean",
        scope: Scope::Model,
        run: |r, w, x| {
            let mean = Encoder::load(w, &VaeConfig::TINY)
                .unwrap()
                .forward(r, &x[0])
                .unwrap();
            assert_eq!(mean.shape, [1, 4, 16, 16]);
            mean
        },
    },
    LayerCase {
        fixture: "vae_decoder",
        inputs: &["io.in.z"],
        output: "io.out.y",
        scope: Scope::Model,
        run: |r, w, z| {
            let y = Decoder::load(w, &VaeConfig::TINY)
                .unwrap()
                .forward(r, &z[0])
                .unwrap();
            assert_eq!(y.shape, [1, 3, 128, 128]);
            y
        },
    },
    LayerCase {
        // The PCA-head decoder, on two latents so each sample's rows of the gather
        // table are checked.
        fixture: "vae_pca_decoder",
        inputs: &["io.in.z"],
        output: "io.out.y",
        scope: Scope::Model,
        run: |r, w, z| {
            let decoder = Decoder::load(w, &VaeConfig::TINY_PCA).unwrap();
            let y = decoder.forward(r, &z[0]).unwrap();
            assert_eq!(y.shape, [2, 3, 128, 128]);
            y
        },
    },
];

#[test]
fn every_layer_kind_matches_pytorch_in_every_variant_and_precision() {
    for case in LAYERS {
        check(case.fixture, case.inputs, case.output, case.scope, case.run);
    }
}

#[test]
fn a_wrong_index_would_be_caught() {
    // The check is only as good as its tolerance: a convolution without its bias (one
    // missing term) must fail it by far.
    let mut f = Fixture::open("down", Precision::F32);
    let x = f.input("io.in.x");
    let (mut r, w) = f.recorder();
    let weight = w.at("conv").tensor("weight", &[12, 8, 3, 3]).unwrap();
    let y = r.conv2d(&x, &weight, None, 2, 1).unwrap();
    r.submit();
    let error = f.error(&y, "io.out.y");
    assert!(error > 10.0 * tolerances(Precision::F16).1, "{error}");
}

#[test]
fn the_timestep_embedding_matches_pytorch() {
    // Arguments reach 999 rad, whose f32 spacing is 6.1e-5; sin/cos of the same rounded
    // argument may then differ by that much plus a few ulps of the GPU's approximations.
    let mut f = Fixture::open("timestep_embedding", Precision::F32);
    let t = f.input("io.in.t");
    let (mut r, _) = f.recorder();
    let y = r.timestep_embedding(&t, 32).unwrap();
    r.submit();
    assert_eq!(y.shape, [4, 32]);
    f.assert_close(&y, "io.out.y", 5e-4);
}
