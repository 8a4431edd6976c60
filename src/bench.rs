//! GPU benchmarks printed as a table: `unica bench` and `cargo bench` run the same code.
//! Numbers come from stage timings (GPU timestamps where available), never from tests.

use std::io::Write;

use crate::gpu::GpuContext;
use crate::gpu::kernel::{PipelineCache, Precision, ScaleAdd};
use crate::gpu::timing::Profiler;

/// Elements per element-wise run (64 MiB of f32 in and out).
const ELEMENTS: usize = 1 << 24;
const REPEATS: usize = 10;

/// Runs every benchmark on `gpu` and prints the table to `out`.
pub fn run(gpu: &GpuContext, out: &mut impl Write) -> anyhow::Result<()> {
    writeln!(out, "adapter: {}", gpu.adapter_label())?;
    writeln!(
        out,
        "capabilities: f16 {}, subgroups {}, timestamps {}",
        gpu.caps.shader_f16, gpu.caps.subgroups, gpu.caps.timestamps
    )?;
    writeln!(
        out,
        "{:<28} {:>10} {:>10} {:>10}",
        "kernel", "median ms", "min ms", "GB/s"
    )?;
    let mut cache = PipelineCache::default();
    let x: Vec<f32> = (0..ELEMENTS).map(|i| (i % 1000) as f32 * 1e-3).collect();
    let mut precisions = vec![Precision::F32];
    if gpu.caps.shader_f16 {
        precisions.push(Precision::F16);
    }
    for precision in precisions {
        let kernel = ScaleAdd::new(gpu, &mut cache, &x, 2.0, 1.0, precision)?;
        let mut profiler = Profiler::new(gpu);
        for _ in 0..REPEATS + 1 {
            profiler.stage(gpu, "scale_add", |encoder, timer| {
                kernel.record(gpu, encoder, timer)
            });
        }
        // The first run includes pipeline warm-up; drop it.
        let mut ms: Vec<f64> = profiler
            .finish(gpu)?
            .into_iter()
            .skip(1)
            .map(|t| t.ms)
            .collect();
        ms.sort_by(f64::total_cmp);
        let median = ms[ms.len() / 2];
        let gbps = kernel.bytes_moved() as f64 / (median * 1e-3) / 1e9;
        let name = format!("scale_add {precision:?} x{ELEMENTS}");
        writeln!(
            out,
            "{name:<28} {median:>10.3} {:>10.3} {gbps:>10.2}",
            ms[0]
        )?;
    }
    Ok(())
}
