//! Every WGSL file is registered or imported, parses and validates with naga (no device needed) in
//! every precision variant it has, and every shared struct has the same size and field
//! offsets in WGSL as in Rust.

use std::collections::BTreeSet;

use unica::gpu::kernel::Precision;
use unica::gpu::shaders::Shader;
use wgpu::naga;

/// Every shader of the crate: the GPU layer's and each stage's own.
fn all() -> Vec<Shader> {
    unica::shaders()
}

/// The `.wgsl` files under `dir`, named relative to `shaders/` (one level of stage folders).
fn wgsl_files(dir: &std::path::Path, prefix: &str, out: &mut Vec<String>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let entry = entry.unwrap();
        let name = entry.file_name().to_string_lossy().into_owned();
        if entry.file_type().unwrap().is_dir() {
            wgsl_files(&entry.path(), &format!("{prefix}{name}/"), out);
        } else if name.ends_with(".wgsl") {
            out.push(format!("{prefix}{name}"));
        }
    }
}

fn parse(shader: &Shader, precision: Precision) -> naga::Module {
    let source = shader.source(precision);
    naga::front::wgsl::parse_str(&source)
        .unwrap_or_else(|e| panic!("{}: {}", shader.file, e.emit_to_string(&source)))
}

fn capabilities(shader: &Shader, precision: Precision) -> naga::valid::Capabilities {
    use naga::valid::Capabilities as C;
    let mut caps = C::empty();
    caps.set(C::SHADER_FLOAT16, shader.needs_f16_for(precision));
    caps.set(C::SUBGROUP, shader.needs_subgroups);
    caps
}

/// The variants a shader is built in: both precisions for `Elem` shaders.
fn variants(shader: &Shader) -> Vec<Precision> {
    if shader.elem {
        vec![Precision::F32, Precision::F16]
    } else {
        vec![Precision::F32]
    }
}

#[test]
fn every_shader_parses_and_validates_with_only_the_features_it_declares() {
    for shader in &all() {
        for precision in variants(shader) {
            let module = parse(shader, precision);
            let source = shader.source(precision);
            let caps = capabilities(shader, precision);
            naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
                .subgroup_stages(naga::valid::ShaderStages::all())
                .subgroup_operations(naga::valid::SubgroupOperationSet::all())
                .validate(&module)
                .unwrap_or_else(|e| {
                    panic!(
                        "{} ({precision:?}): {}",
                        shader.file,
                        e.emit_to_string(&source)
                    )
                });
        }
    }
}

#[test]
fn the_f32_variant_of_an_elem_shader_needs_no_f16() {
    let shader = unica::nn::ops::shaders()
        .into_iter()
        .find(|s| s.file == "nn/conv/conv2d.wgsl")
        .expect("conv2d.wgsl is registered");
    assert!(!shader.needs_f16_for(Precision::F32));
    assert!(shader.needs_f16_for(Precision::F16));
    assert!(shader.source(Precision::F16).starts_with("enable f16;"));
    let f32_source = shader.source(Precision::F32);
    assert!(f32_source.starts_with("alias Elem = f32;") && !f32_source.contains("enable f16"));
}

#[test]
fn every_file_in_shaders_is_registered_once() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/shaders");
    let mut files = Vec::new();
    wgsl_files(std::path::Path::new(dir), "", &mut files);
    let on_disk: BTreeSet<String> = files.into_iter().collect();
    // A file may be registered more than once with different integer constants (the
    // specialised variants of one kernel), never twice the same way.
    let registered: Vec<String> = all()
        .iter()
        .map(|s| format!("{} {:?}", s.file, s.uints))
        .collect();
    let unique: BTreeSet<String> = registered.iter().cloned().collect();
    assert_eq!(
        unique.len(),
        registered.len(),
        "a shader is registered twice"
    );
    let unique: BTreeSet<String> = all().iter().map(|s| s.file.to_string()).collect();
    // Every other file is imported by a shader (`#import`, src/gpu/shaders.rs::expand),
    // and no shader's entry file is imported by another.
    let imported: BTreeSet<String> = all()
        .iter()
        .flat_map(|s| s.imports().unwrap_or_else(|e| panic!("{e}")))
        .collect();
    assert!(
        unique.is_disjoint(&imported),
        "a file is both a shader and an import: {:?}",
        unique.intersection(&imported).collect::<Vec<_>>()
    );
    assert_eq!(
        on_disk,
        &unique | &imported,
        "every file under shaders/ is a shader or imported"
    );
    let embedded: BTreeSet<String> = unica::gpu::shaders::files()
        .iter()
        .map(|(name, _)| name.to_string())
        .collect();
    assert_eq!(
        on_disk, embedded,
        "build.rs embeds every file under shaders/"
    );
}

#[test]
fn every_import_resolves_and_leaves_no_directive() {
    for shader in &all() {
        let text = unica::gpu::shaders::expand(shader.file, shader.body)
            .unwrap_or_else(|e| panic!("{e}"))
            .text;
        assert!(
            !text.contains("#import"),
            "{}: a directive was left",
            shader.file
        );
    }
}

#[test]
fn shared_structs_have_the_host_layout() {
    let mut checked = 0;
    for shader in &all() {
        let module = parse(shader, Precision::F32);
        for shared in shader.structs {
            let (span, members) = module
                .types
                .iter()
                .find_map(|(_, ty)| match &ty.inner {
                    naga::TypeInner::Struct { members, span }
                        if ty.name.as_deref() == Some(shared.name) =>
                    {
                        Some((*span, members.clone()))
                    }
                    _ => None,
                })
                .unwrap_or_else(|| panic!("{}: struct {} not found", shader.file, shared.name));
            assert_eq!(
                span as usize, shared.size,
                "{}: size of {}",
                shader.file, shared.name
            );
            let wgsl: Vec<(String, usize)> = members
                .iter()
                .map(|m| (m.name.clone().unwrap(), m.offset as usize))
                .collect();
            let host: Vec<(String, usize)> = (shared.field_offsets)()
                .into_iter()
                .map(|(n, o)| (n.to_string(), o))
                .collect();
            assert_eq!(
                wgsl, host,
                "{}: field offsets of {}",
                shader.file, shared.name
            );
            checked += 1;
        }
    }
    assert!(checked >= 3, "only {checked} shared structs checked");
}

#[test]
fn a_misaligned_struct_would_be_caught() {
    // The layout check above is only useful if naga disagrees with a naive Rust layout;
    // a vec4 after one u32 is padded to offset 16 in WGSL (and would be 4 in packed Rust).
    let module = naga::front::wgsl::parse_str("struct S { a: u32, b: vec4<f32> }").unwrap();
    let offsets: Vec<u32> = module
        .types
        .iter()
        .find_map(|(_, ty)| match &ty.inner {
            naga::TypeInner::Struct { members, .. } => {
                Some(members.iter().map(|m| m.offset).collect())
            }
            _ => None,
        })
        .unwrap();
    assert_eq!(offsets, [0, 16]);
}

#[test]
fn every_compute_kernel_binds_its_parameters_then_buffers_in_order() {
    // The dispatch convention (gpu::plan::Builder::dispatch, gpu::kernel::dispatch):
    // group 0, binding 0 the uniform parameters (if any), then storage buffers with no
    // gaps; the builder checks the count against this reflection when it records.
    let mut checked = 0;
    for shader in &all() {
        let source = shader.source(Precision::F32);
        if !source.contains("@compute") {
            continue;
        }
        let bindings = shader.bindings(Precision::F32).unwrap();
        let numbers: Vec<u32> = bindings.iter().map(|b| b.0).collect();
        let expected: Vec<u32> = (0..bindings.len() as u32).collect();
        assert_eq!(numbers, expected, "{}: bindings not 0..n", shader.file);
        // Parameters, where a kernel has them, come first (the rasterizer's range
        // kernel has none).
        assert!(
            bindings[1..].iter().all(|b| !b.1),
            "{}: a uniform after binding 0",
            shader.file
        );
        checked += 1;
    }
    assert!(checked >= 40, "only {checked} compute kernels found");
}
