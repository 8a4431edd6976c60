//! `cargo bench`: the same table as `unica bench`, on the adapter the environment selects.

fn main() -> anyhow::Result<()> {
    let gpu = unica::gpu::GpuContext::headless(&unica::gpu::GpuOptions::from_env())?;
    unica::bench::run(&gpu, &mut std::io::stdout())
}
