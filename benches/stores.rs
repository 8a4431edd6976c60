//! `cargo bench --bench stores`: what a register tile's stores cost on the present
//! adapter. Each invocation holds 8 pixels × 8 channels (16 vec4 sums from a short
//! product, as the CPU-driver 3×3 convolution's tile) and stores them into an NCHW
//! image: as 64 scalar stores into `array<f32>` (what the kernels do), as 16 vec4
//! stores into `array<vec4<f32>>`, or as 16 texel stores into an rgba32float storage
//! texture (the layout of src/gpu/texels.rs). Prints one line per form:
//! `stores FORM: ms=… per_value_ns=…`.

mod common;

use common::time_dispatch;
use unica::gpu::{GpuContext, GpuOptions};

const CHANNELS: u32 = 64;
const HEIGHT: u32 = 64;
const WIDTH: u32 = 64;
/// Texels a texture row (as src/gpu/texels.rs).
const ROW: u32 = 1024;
const REPEATS: usize = 20;
/// Multiply-adds per sum before the stores (a little work, so the sums are not constant).
const K: u32 = 8;

struct Form {
    name: &'static str,
    declare: &'static str,
    /// Functions the body calls.
    helpers: &'static str,
    /// The body of `put_row(at, plane, l0 … l7, h0 … h7)`, which stores the sums of
    /// pixels 0 … 7 (channels 0-3 in lj, 4-7 in hj): `at` is the flat index of the
    /// tile's first value, `plane` the channel stride.
    body: &'static str,
}

const PUT_ROW: &str = "fn put_row(at: u32, plane: u32, l0: vec4<f32>, l1: vec4<f32>, l2: vec4<f32>, l3: vec4<f32>, l4: vec4<f32>, l5: vec4<f32>, l6: vec4<f32>, l7: vec4<f32>, h0: vec4<f32>, h1: vec4<f32>, h2: vec4<f32>, h3: vec4<f32>, h4: vec4<f32>, h5: vec4<f32>, h6: vec4<f32>, h7: vec4<f32>)";

/// Four pixels of a channel a call to `put4(vec4 index, values)`.
const FOURS: &str = "
    let q = at / 4u;
    let s = plane / 4u;
    put4(q, vec4(l0.x, l1.x, l2.x, l3.x)); put4(q + 1u, vec4(l4.x, l5.x, l6.x, l7.x));
    put4(q + s, vec4(l0.y, l1.y, l2.y, l3.y)); put4(q + s + 1u, vec4(l4.y, l5.y, l6.y, l7.y));
    put4(q + 2u * s, vec4(l0.z, l1.z, l2.z, l3.z)); put4(q + 2u * s + 1u, vec4(l4.z, l5.z, l6.z, l7.z));
    put4(q + 3u * s, vec4(l0.w, l1.w, l2.w, l3.w)); put4(q + 3u * s + 1u, vec4(l4.w, l5.w, l6.w, l7.w));
    put4(q + 4u * s, vec4(h0.x, h1.x, h2.x, h3.x)); put4(q + 4u * s + 1u, vec4(h4.x, h5.x, h6.x, h7.x));
    put4(q + 5u * s, vec4(h0.y, h1.y, h2.y, h3.y)); put4(q + 5u * s + 1u, vec4(h4.y, h5.y, h6.y, h7.y));
    put4(q + 6u * s, vec4(h0.z, h1.z, h2.z, h3.z)); put4(q + 6u * s + 1u, vec4(h4.z, h5.z, h6.z, h7.z));
    put4(q + 7u * s, vec4(h0.w, h1.w, h2.w, h3.w)); put4(q + 7u * s + 1u, vec4(h4.w, h5.w, h6.w, h7.w));
";

const SCALAR: Form = Form {
    name: "scalar",
    declare: "@group(0) @binding(1) var<storage, read_write> y: array<f32>;",
    helpers: "
fn put(at: u32, plane: u32, lo: vec4<f32>, hi: vec4<f32>) {
    for (var c = 0u; c < 4u; c++) {
        y[at + c * plane] = lo[c];
        y[at + (4u + c) * plane] = hi[c];
    }
}",
    body: "
    put(at, plane, l0, h0); put(at + 1u, plane, l1, h1); put(at + 2u, plane, l2, h2); put(at + 3u, plane, l3, h3);
    put(at + 4u, plane, l4, h4); put(at + 5u, plane, l5, h5); put(at + 6u, plane, l6, h6); put(at + 7u, plane, l7, h7);
",
};

const VEC4: Form = Form {
    name: "vec4",
    declare: "@group(0) @binding(1) var<storage, read_write> y: array<vec4<f32>>;",
    helpers: "
fn put4(i: u32, v: vec4<f32>) {
    y[i] = v;
}",
    body: FOURS,
};

const TEXELS: Form = Form {
    name: "texels",
    declare: "@group(0) @binding(1) var y: texture_storage_2d<rgba32float, write>;",
    helpers: "
fn put4(i: u32, v: vec4<f32>) {
    textureStore(y, vec2<u32>(i % 1024u, i / 1024u), v);
}",
    body: FOURS,
};

const NONE: Form = Form {
    name: "none (one value)",
    declare: "@group(0) @binding(1) var<storage, read_write> y: array<f32>;",
    helpers: "",
    body: "
    let s = l0 + l1 + l2 + l3 + l4 + l5 + l6 + l7 + h0 + h1 + h2 + h3 + h4 + h5 + h6 + h7;
    y[at] = s.x + s.y + s.z + s.w;
",
};

fn shader(form: &Form) -> String {
    format!(
        "@group(0) @binding(0) var x: texture_2d<f32>;
{}
{}
{PUT_ROW} {{{}}}
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {{
    // Tile id.x: pixel tile fastest, then row, then channel block.
    let tiles = {WIDTH}u / 8u;
    let ox0 = (id.x % tiles) * 8u;
    let oy = (id.x / tiles) % {HEIGHT}u;
    let block = id.x / (tiles * {HEIGHT}u);
    var l0 = vec4<f32>(0.0); var l1 = vec4<f32>(0.0); var l2 = vec4<f32>(0.0); var l3 = vec4<f32>(0.0);
    var l4 = vec4<f32>(0.0); var l5 = vec4<f32>(0.0); var l6 = vec4<f32>(0.0); var l7 = vec4<f32>(0.0);
    var h0 = vec4<f32>(0.0); var h1 = vec4<f32>(0.0); var h2 = vec4<f32>(0.0); var h3 = vec4<f32>(0.0);
    var h4 = vec4<f32>(0.0); var h5 = vec4<f32>(0.0); var h6 = vec4<f32>(0.0); var h7 = vec4<f32>(0.0);
    for (var k = 0u; k < {K}u; k++) {{
        let q = (k * {HEIGHT}u * {WIDTH}u + oy * {WIDTH}u + ox0) / 4u;
        let a = textureLoad(x, vec2<u32>(q % 1024u, q / 1024u), 0);
        let b = textureLoad(x, vec2<u32>((q + 1u) % 1024u, (q + 1u) / 1024u), 0);
        let wa = textureLoad(x, vec2<u32>((block * 2u + k) % 1024u, 0u), 0);
        let wb = textureLoad(x, vec2<u32>((block * 2u + k + 1u) % 1024u, 0u), 0);
        l0 += a.x * wa; l1 += a.y * wa; l2 += a.z * wa; l3 += a.w * wa;
        l4 += b.x * wa; l5 += b.y * wa; l6 += b.z * wa; l7 += b.w * wa;
        h0 += a.x * wb; h1 += a.y * wb; h2 += a.z * wb; h3 += a.w * wb;
        h4 += b.x * wb; h5 += b.y * wb; h6 += b.z * wb; h7 += b.w * wb;
    }}
    let plane = {HEIGHT}u * {WIDTH}u;
    put_row(block * 8u * plane + oy * {WIDTH}u + ox0, plane, l0, l1, l2, l3, l4, l5, l6, l7, h0, h1, h2, h3, h4, h5, h6, h7);
}}
",
        form.declare, form.helpers, form.body
    )
}

fn texture(gpu: &GpuContext, values: u32, usage: wgpu::TextureUsages) -> wgpu::Texture {
    gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: Some("stores"),
        size: wgpu::Extent3d {
            width: ROW,
            height: (values / 4).div_ceil(ROW),
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage,
        view_formats: &[],
    })
}

fn main() -> anyhow::Result<()> {
    let gpu = GpuContext::headless(&GpuOptions::from_env())?;
    println!("adapter: {}", gpu.adapter_label());
    let device = &gpu.device;
    let values = CHANNELS * HEIGHT * WIDTH;
    let x = texture(
        &gpu,
        K * HEIGHT * WIDTH,
        wgpu::TextureUsages::TEXTURE_BINDING,
    );
    let x_view = x.create_view(&Default::default());
    let y_buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("y"),
        size: u64::from(values * 4),
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let y_texture = texture(&gpu, values, wgpu::TextureUsages::STORAGE_BINDING);
    let y_view = y_texture.create_view(&Default::default());
    for form in [&SCALAR, &VEC4, &TEXELS, &NONE] {
        let y = match form.name {
            "texels" => wgpu::BindingResource::TextureView(&y_view),
            _ => y_buffer.as_entire_binding(),
        };
        let x = wgpu::BindingResource::TextureView(&x_view);
        let tiles = values / 64;
        let ms = time_dispatch(&gpu, &shader(form), vec![x, y], (tiles / 64, 1), REPEATS);
        println!(
            "stores {}: ms={ms:.3} per_value_ns={:.2}",
            form.name,
            ms * 1e6 / f64::from(values)
        );
    }
    Ok(())
}
