//! `cargo bench`: the same tables as `unica bench` with its defaults (kernels, the tiny and
//! default models in f32 and f16), on the adapter the environment selects.

fn main() -> anyhow::Result<()> {
    let gpu = unica::gpu::GpuContext::headless(&unica::gpu::GpuOptions::from_env())?;
    unica::bench::run(&gpu, &Default::default(), &mut std::io::stdout())
}
