use super::*;
use unica::splat::base::RESIDUALS;
use unica::splat::frame::FEATURES;
use unica::splat::serialise::host_orders;

/// The refiner's residuals of `features` for points at `unit`, serialised on the host.
fn refine(r: &mut Recorder, refiner: &Refiner, features: &Tensor, unit: &[glam::Vec3]) -> Tensor {
    let o = host_orders(unit, refiner.cfg.stride)
        .upload(r.gpu())
        .unwrap();
    refiner
        .forward(r, features, &o.fine, &o.coarse, &o.groups)
        .unwrap()
}

/// Points of a fixture tensor [N, 3].
fn points(f: &Fixture, name: &str) -> Vec<glam::Vec3> {
    f.stored(name)
        .0
        .chunks_exact(3)
        .map(glam::Vec3::from_slice)
        .collect()
}

#[test]
fn the_refiner_matches_pytorch() {
    // 300 points in 18 patches of 16 and a tail of 12, pooled by 4 into 75 (4 patches
    // and a tail of 11): serialisation, patch attention, pooling and unpooling; then the
    // same network with a random residual per point added (`refiner_pixel`).
    for (fixture, pixel_residuals) in [("refiner", 0), ("refiner_pixel", 300)] {
        refiner_matches(fixture, pixel_residuals);
    }
}

fn refiner_matches(fixture: &str, pixel_residuals: usize) {
    let cfg = RefinerConfig {
        channels: [16, 32],
        depths: [1, 1],
        heads: [2, 2],
        decoder_depth: 1,
        patch: 16,
        stride: 4,
        mean_bound: 0.004,
        pixel_residuals,
    };
    for (precision, kernels) in variants() {
        let mut f = Fixture::open(fixture, precision);
        let unit = points(&f, "io.in.unit");
        let features = f.input("io.in.features");
        let (mut r, w) = f.recorder();
        r.set_kernels(kernels);
        let refiner = Refiner::load(&w, &cfg, FEATURES, RESIDUALS).unwrap();
        let y = refine(&mut r, &refiner, &features, &unit);
        r.submit();
        f.assert_close(&y, "io.out.y", tolerances(precision).1);
    }
}

#[test]
fn the_shipped_refiner_matches_pytorch_on_a_witch_frame() {
    for (precision, kernels) in variants() {
        let mut f = Fixture::open("witch_refiner", precision);
        let manifest: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(witch_bundle().join("manifest.json")).unwrap(),
        )
        .unwrap();
        let cfg: RefinerConfig = serde_json::from_value(manifest["refiner"].clone()).unwrap();
        let file = TensorFile::open(&witch_bundle().join("weights.safetensors")).unwrap();
        let unit = points(&f, "io.in.unit");
        let features = f.input("io.in.features");
        let mut r = Recorder::new(&f.gpu, &mut f.pipelines, precision);
        r.set_kernels(kernels);
        let w = Weights::new(&file, &f.gpu, precision);
        let refiner = Refiner::load(&w.at("refiner"), &cfg, FEATURES, RESIDUALS).unwrap();
        let y = refine(&mut r, &refiner, &features, &unit);
        r.submit();
        f.assert_close(&y, "io.out.y", tolerances(precision).1);
    }
}
