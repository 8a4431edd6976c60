//! `cargo bench --bench loads`: why the CPU-driver kernels read their operands as texels.
//! One product y[c, p] = Σ_k w[c, k] · x[k, p] (576 × 64 × 256, the size of a UNet
//! convolution) in register tiles of 8 pixels × 8 channels per invocation, with the two
//! operands read from storage buffers, a uniform buffer or textures (four values a
//! texel), timed on the adapter the environment selects. Prints one line per form:
//! `loads x=FORM w=FORM: ms=… gflops=…`.

mod common;

use common::time_dispatch;
use unica::gpu::{GpuContext, GpuOptions};
use wgpu::util::DeviceExt;

const K: u32 = 576;
const CHANNELS: u32 = 64;
const PIXELS: u32 = 256;
/// Texels a texture row (as src/gpu/texels.rs).
const ROW: u32 = 1024;
const REPEATS: usize = 20;

/// How an operand is declared and how four of its values at vec4 index `i` are read.
struct Form {
    name: &'static str,
    declare: &'static str,
    load: &'static str,
}

const STORAGE: Form = Form {
    name: "storage",
    declare: "var<storage, read> NAME: array<vec4<f32>>;",
    load: "NAME[I]",
};
const UNIFORM: Form = Form {
    name: "uniform",
    declare: "var<uniform> NAME: array<vec4<f32>, 4096>;",
    load: "NAME[(I) % 4096u]",
};
const TEXELS: Form = Form {
    name: "texels",
    declare: "var NAME: texture_2d<f32>;",
    load: "textureLoad(NAME, vec2<u32>((I) % 1024u, (I) / 1024u), 0)",
};

fn shader(x: &Form, w: &Form) -> String {
    let load =
        |form: &Form, name: &str, index: &str| form.load.replace("NAME", name).replace("I", index);
    format!(
        "@group(0) @binding(0) {}
@group(0) @binding(1) {}
@group(0) @binding(2) var<storage, read_write> y: array<f32>;
@compute @workgroup_size(8)
fn main(@builtin(global_invocation_id) id: vec3<u32>, @builtin(workgroup_id) group: vec3<u32>) {{
    let block = group.y;
    var lo0 = vec4<f32>(0.0); var lo1 = vec4<f32>(0.0); var lo2 = vec4<f32>(0.0); var lo3 = vec4<f32>(0.0);
    var lo4 = vec4<f32>(0.0); var lo5 = vec4<f32>(0.0); var lo6 = vec4<f32>(0.0); var lo7 = vec4<f32>(0.0);
    var hi0 = vec4<f32>(0.0); var hi1 = vec4<f32>(0.0); var hi2 = vec4<f32>(0.0); var hi3 = vec4<f32>(0.0);
    var hi4 = vec4<f32>(0.0); var hi5 = vec4<f32>(0.0); var hi6 = vec4<f32>(0.0); var hi7 = vec4<f32>(0.0);
    for (var k = 0u; k < {K}u; k++) {{
        let p = (k * {PIXELS}u + id.x * 8u) / 4u;
        let q0 = {};
        let q1 = {};
        let wi = (block * {K}u + k) * 2u;
        let wa = {};
        let wb = {};
        lo0 = fma(vec4(q0.x), wa, lo0); lo1 = fma(vec4(q0.y), wa, lo1); lo2 = fma(vec4(q0.z), wa, lo2); lo3 = fma(vec4(q0.w), wa, lo3);
        lo4 = fma(vec4(q1.x), wa, lo4); lo5 = fma(vec4(q1.y), wa, lo5); lo6 = fma(vec4(q1.z), wa, lo6); lo7 = fma(vec4(q1.w), wa, lo7);
        hi0 = fma(vec4(q0.x), wb, hi0); hi1 = fma(vec4(q0.y), wb, hi1); hi2 = fma(vec4(q0.z), wb, hi2); hi3 = fma(vec4(q0.w), wb, hi3);
        hi4 = fma(vec4(q1.x), wb, hi4); hi5 = fma(vec4(q1.y), wb, hi5); hi6 = fma(vec4(q1.z), wb, hi6); hi7 = fma(vec4(q1.w), wb, hi7);
    }}
    let s = lo0 + lo1 + lo2 + lo3 + lo4 + lo5 + lo6 + lo7 + hi0 + hi1 + hi2 + hi3 + hi4 + hi5 + hi6 + hi7;
    y[block * {PIXELS}u + id.x] = s.x + s.y + s.z + s.w;
}}
",
        x.declare.replace("NAME", "x"),
        w.declare.replace("NAME", "w"),
        load(x, "x", "p"),
        load(x, "x", "p + 1u"),
        load(w, "w", "wi"),
        load(w, "w", "wi + 1u"),
    )
}

/// A buffer usable as storage and uniform, and a texture of the same values.
struct Operand {
    buffer: wgpu::Buffer,
    view: wgpu::TextureView,
}

fn operand(gpu: &GpuContext, values: &[f32]) -> Operand {
    let device = &gpu.device;
    let buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("operand"),
        contents: bytemuck::cast_slice(values),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::UNIFORM,
    });
    let texels = (values.len() as u32).div_ceil(4);
    let rows = texels.div_ceil(ROW);
    let mut padded = values.to_vec();
    padded.resize((ROW * rows * 4) as usize, 0.0);
    let texture = device.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some("operand"),
            size: wgpu::Extent3d {
                width: ROW,
                height: rows,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(&padded),
    );
    let view = texture.create_view(&Default::default());
    Operand { buffer, view }
}

fn resource<'a>(form: &Form, operand: &'a Operand) -> wgpu::BindingResource<'a> {
    match form.name {
        "texels" => wgpu::BindingResource::TextureView(&operand.view),
        "uniform" => wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &operand.buffer,
            offset: 0,
            size: wgpu::BufferSize::new(65536),
        }),
        _ => operand.buffer.as_entire_binding(),
    }
}

fn main() -> anyhow::Result<()> {
    let gpu = GpuContext::headless(&GpuOptions::from_env())?;
    println!("adapter: {}", gpu.adapter_label());
    let device = &gpu.device;
    let x: Vec<f32> = (0..K * PIXELS).map(|i| (i % 7) as f32 * 0.1).collect();
    let w: Vec<f32> = (0..K * CHANNELS).map(|i| (i % 5) as f32 * 0.1).collect();
    let (x, w) = (operand(&gpu, &x), operand(&gpu, &w));
    let y = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("y"),
        size: u64::from(CHANNELS * PIXELS * 4),
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    // The uniform forms read only the first 64 KiB (wrapped indices): timing only.
    let forms = [
        (&STORAGE, &STORAGE),
        (&STORAGE, &UNIFORM),
        (&STORAGE, &TEXELS),
        (&TEXELS, &TEXELS),
        (&UNIFORM, &UNIFORM),
        (&TEXELS, &UNIFORM),
    ];
    for (x_form, w_form) in forms {
        let resources = vec![
            resource(x_form, &x),
            resource(w_form, &w),
            y.as_entire_binding(),
        ];
        let groups = (PIXELS / 64, CHANNELS / 8);
        let ms = time_dispatch(&gpu, &shader(x_form, w_form), resources, groups, REPEATS);
        let gflop = 2.0 * f64::from(K * CHANNELS * PIXELS) / 1e9;
        println!(
            "loads x={} w={}: ms={ms:.3} gflops={:.2}",
            x_form.name,
            w_form.name,
            gflop / (ms / 1e3)
        );
    }
    Ok(())
}
