//! Named per-stage timings: GPU timestamp queries where the device has them, CPU wall
//! clock around a blocking submit otherwise. Feeds the HUD and the benchmarks.

use std::time::Instant;

use super::{GpuContext, GpuError, readback};

/// Stages a profiler can time with timestamps; later stages fall back to CPU timing.
pub const MAX_TIMESTAMP_STAGES: u32 = 32;

/// One named stage and how long it took.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StageTiming {
    pub name: String,
    pub ms: f64,
    /// "gpu" for timestamp queries, "cpu" for wall clock around a blocking submit, "cpu,
    /// recording" for the CPU time of recording alone (the window's stages).
    pub clock: &'static str,
}

/// Where a timed pass writes its begin and end timestamps.
pub struct PassTimer<'a> {
    set: &'a wgpu::QuerySet,
    begin: u32,
}

impl<'a> PassTimer<'a> {
    pub fn compute(&self) -> wgpu::ComputePassTimestampWrites<'a> {
        wgpu::ComputePassTimestampWrites {
            query_set: self.set,
            beginning_of_pass_write_index: Some(self.begin),
            end_of_pass_write_index: Some(self.begin + 1),
        }
    }

    pub fn render(&self) -> wgpu::RenderPassTimestampWrites<'a> {
        wgpu::RenderPassTimestampWrites {
            query_set: self.set,
            beginning_of_pass_write_index: Some(self.begin),
            end_of_pass_write_index: Some(self.begin + 1),
        }
    }
}

struct Queries {
    set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
}

enum Measured {
    /// Index of the stage's first timestamp in the query set.
    Gpu(u32),
    Cpu(f64),
}

/// Times a sequence of stages; each stage is recorded and submitted on its own.
pub struct Profiler {
    queries: Option<Queries>,
    stages: Vec<(String, Measured)>,
    next_query: u32,
}

impl Profiler {
    pub fn new(gpu: &GpuContext) -> Self {
        let queries = gpu.caps.timestamps.then(|| Queries {
            set: gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("stage timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: MAX_TIMESTAMP_STAGES * 2,
            }),
            resolve: gpu.create_buffer(&wgpu::BufferDescriptor {
                label: Some("stage timestamps resolve"),
                size: MAX_TIMESTAMP_STAGES as u64 * 2 * 8,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
        });
        Self {
            queries,
            stages: Vec::new(),
            next_query: 0,
        }
    }

    /// Records one stage with `record` and submits it. `record` gets a [`PassTimer`] when
    /// timestamps are in use and must then pass it to exactly one pass (the one timed).
    pub fn stage(
        &mut self,
        gpu: &GpuContext,
        name: &str,
        record: impl FnOnce(&mut wgpu::CommandEncoder, Option<PassTimer<'_>>),
    ) {
        let slot = self
            .queries
            .as_ref()
            .filter(|_| self.next_query < MAX_TIMESTAMP_STAGES * 2);
        if let Some(queries) = slot {
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(name) });
            let begin = self.next_query;
            record(
                &mut encoder,
                Some(PassTimer {
                    set: &queries.set,
                    begin,
                }),
            );
            gpu.submit([encoder.finish()]);
            self.next_query += 2;
            self.stages.push((name.into(), Measured::Gpu(begin)));
        } else {
            self.cpu_stage(gpu, name, |encoder| record(encoder, None));
        }
    }

    /// Records one stage of many passes and times it with the CPU clock around a
    /// blocking submit (a timestamp pair covers one pass only).
    pub fn cpu_stage(
        &mut self,
        gpu: &GpuContext,
        name: &str,
        record: impl FnOnce(&mut wgpu::CommandEncoder),
    ) {
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(name) });
        let start = Instant::now();
        record(&mut encoder);
        gpu.submit([encoder.finish()]);
        gpu.wait_idle();
        let ms = start.elapsed().as_secs_f64() * 1e3;
        self.stages.push((name.into(), Measured::Cpu(ms)));
    }

    /// Waits for the stages and returns their timings in order.
    pub fn finish(self, gpu: &GpuContext) -> Result<Vec<StageTiming>, GpuError> {
        let ticks: Vec<u64> = match (&self.queries, self.next_query) {
            (Some(queries), used) if used > 0 => {
                let mut encoder = gpu.device.create_command_encoder(&Default::default());
                encoder.resolve_query_set(&queries.set, 0..used, &queries.resolve, 0);
                gpu.submit([encoder.finish()]);
                let raw = readback::buffer(gpu, &queries.resolve, "stage timestamps")?;
                bytemuck::cast_slice(&raw[..used as usize * 8]).to_vec()
            }
            _ => Vec::new(),
        };
        let ns_per_tick = f64::from(gpu.queue.get_timestamp_period());
        Ok(self
            .stages
            .into_iter()
            .map(|(name, measured)| match measured {
                Measured::Gpu(begin) => {
                    let (a, b) = (ticks[begin as usize], ticks[begin as usize + 1]);
                    StageTiming {
                        name,
                        ms: b.saturating_sub(a) as f64 * ns_per_tick * 1e-6,
                        clock: "gpu",
                    }
                }
                Measured::Cpu(ms) => StageTiming {
                    name,
                    ms,
                    clock: "cpu",
                },
            })
            .collect())
    }
}
