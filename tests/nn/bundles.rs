use super::*;

#[test]
fn the_shipped_witch_bundle_generates_and_decodes_what_pytorch_does() {
    // Trained weights, the bundle's teacher sampler (10 DDIM steps, its guidance; Idle
    // sampled as its manifest says) and its distilled student's one pass, then the
    // decoder: values are latents of size ~3 and map coordinates in [0, 1]. Forward and
    // Idle.
    for (name, precision) in [
        "witch_frame",
        "witch_idle_frame",
        "witch_one_pass_frame",
        "witch_one_pass_idle_frame",
    ]
    .into_iter()
    .flat_map(|name| precisions().into_iter().map(move |p| (name, p)))
    {
        let mut f = Fixture::open(name, precision);
        let (noise, a) = (f.input("io.in.noise"), action(&f));
        let bundle = Bundle::load(&witch_bundle(), &f.gpu, precision).unwrap();
        let teacher = bundle.manifest.sampler;
        let sampling = if name.contains("one_pass") {
            assert_eq!(bundle.live_sampling().unet_passes(), 1, "{name}");
            bundle.live_sampling()
        } else {
            teacher.ddim(teacher.steps)
        };
        let mut r = Recorder::new(&f.gpu, &mut f.pipelines, precision);
        let context = bundle.context.reshaped(&[1, 3, 4, 16, 16]);
        let z = bundle
            .generate(&mut r, &context, a, &noise, sampling)
            .unwrap();
        let map = bundle.decode(&mut r, &z).unwrap();
        r.submit();
        // In f16 storage a trained model's frame is further off than the tiny models':
        // its latents are ~3 in size and the student's weights (an int8 difference added
        // to the UNet's) are rounded to 11 bits on upload. Measured on lavapipe: z 0.4e-3
        // to 5.2e-3, map 3e-4. 1e-2 is still 100x below an indexing error.
        let tolerance = match precision {
            Precision::F32 => tolerances(precision).1,
            Precision::F16 => 1e-2,
        };
        f.assert_close(&z, "io.out.z", tolerance);
        f.assert_close(&map, "io.out.map", tolerance);
    }
}

/// A copy of the Witch bundle whose manifest `edit` changes.
fn edited_bundle(edit: impl FnOnce(&mut serde_json::Value)) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let source = witch_bundle();
    std::fs::copy(
        source.join("weights.safetensors"),
        dir.path().join("weights.safetensors"),
    )
    .unwrap();
    let mut manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(source.join("manifest.json")).unwrap())
            .unwrap();
    edit(&mut manifest);
    std::fs::write(dir.path().join("manifest.json"), manifest.to_string()).unwrap();
    dir
}

fn load_error(dir: &Path) -> String {
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    match Bundle::load(dir, &gpu, Precision::F32) {
        Ok(_) => panic!("{} loaded", dir.display()),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bundles_of_another_version_or_format_are_refused() {
    let dir = edited_bundle(|m| m["version"] = 2.into());
    let message = load_error(dir.path());
    assert!(
        message.contains("manifest.json")
            && message.contains("bundle version 2, this build reads version 1"),
        "{message}"
    );
    let dir = edited_bundle(|m| m["format"] = "something-else".into());
    let message = load_error(dir.path());
    assert!(message.contains("not a unica bundle"), "{message}");
}

#[test]
fn the_first_tensor_that_disagrees_with_the_config_is_named() {
    // A manifest claiming a 64-d embedding: the first embedding-sized tensor loaded is
    // the action table (for the cross-attention tables), stored as [6, 128].
    let dir = edited_bundle(|m| m["unet"]["embed"] = 64.into());
    let message = load_error(dir.path());
    assert!(
        message.contains("weights.safetensors")
            && message.contains("'unet.action.weight' has shape [6, 128], expected [6, 64]"),
        "{message}"
    );
    // A missing file is named too.
    let dir = edited_bundle(|_| {});
    std::fs::remove_file(dir.path().join("weights.safetensors")).unwrap();
    let message = load_error(dir.path());
    assert!(message.contains("weights.safetensors"), "{message}");
}

#[test]
fn unsupported_model_shapes_are_refused_before_loading() {
    let dir = edited_bundle(|m| m["unet"]["heads"] = 1.into());
    let message = load_error(dir.path());
    assert!(message.contains("at most 64 channels"), "{message}");
}

#[test]
fn index_tensors_out_of_order_or_out_of_range_are_refused_by_name() {
    use unica::tensors::{TensorData as Stored, write};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.safetensors");
    let tensors = [
        ("pixels", Stored::i32(&[3], &[5, 2, 9])),
        ("far", Stored::i32(&[2], &[1, 99])),
        ("good", Stored::i32(&[2], &[1, 15])),
    ];
    write(&path, &tensors).unwrap();
    let file = TensorFile::open(&path).unwrap();
    let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
    let w = Weights::new(&file, &gpu, Precision::F32);
    let error = w.indices("pixels", 3, 16).unwrap_err().to_string();
    assert!(
        error.contains("bad.safetensors")
            && error.contains("'pixels' is not increasing at index 1 (5 then 2)"),
        "{error}"
    );
    let error = w.indices("far", 2, 16).unwrap_err().to_string();
    assert!(error.contains("'far' holds 99, outside 0..16"), "{error}");
    assert_eq!(w.indices("good", 2, 16).unwrap(), [1, 15]);
}
