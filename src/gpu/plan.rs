//! Recorded GPU work kept to run again (a lazy graph run as command buffers): a
//! [`Builder`] turns kernel launches into steps — each with its pipeline, uniform and bind
//! group made once, when recorded — and a [`Plan`] encodes them into any number of
//! command encoders without creating anything. Stages (the model, the splats, the engine)
//! record their own kernels through it; it knows no model.

use super::kernel::{Grid, PipelineCache, Precision, uniform};
use super::shaders::Shader;
use super::texels::Texels;
use super::{Bound, GpuContext};

/// One piece of recorded work: everything it binds was created when it was recorded.
enum Step {
    Dispatch {
        /// The shader's file (profiles).
        name: &'static str,
        pipeline: wgpu::ComputePipeline,
        bind_group: wgpu::BindGroup,
        grid: Grid,
    },
    Copy {
        source: wgpu::Buffer,
        source_offset: u64,
        target: wgpu::Buffer,
        target_offset: u64,
        size: u64,
    },
    /// Texels `first` … `first + count - 1` copied from a buffer at byte `offset` (see
    /// [`Texels::record_copy_range`]).
    CopyToTexels {
        source: wgpu::Buffer,
        target: Texels,
        offset: u64,
        first: u32,
        count: u32,
    },
}

/// Records a run of steps into `encoder` and counts its dispatches in the GPU layer's
/// counters.
fn encode_steps<'s>(
    gpu: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    steps: impl IntoIterator<Item = &'s Step>,
) {
    let dispatches = record_steps(encoder, steps);
    gpu.counters.dispatches(dispatches);
}

/// Records a run of steps into `encoder` and returns its dispatches: consecutive
/// dispatches share one compute pass (wgpu orders each dispatch's storage writes before
/// the next one's reads).
fn record_steps<'s>(
    encoder: &mut wgpu::CommandEncoder,
    steps: impl IntoIterator<Item = &'s Step>,
) -> u64 {
    let mut pass: Option<wgpu::ComputePass> = None;
    let mut dispatches = 0;
    for step in steps {
        match step {
            Step::Dispatch {
                pipeline,
                bind_group,
                grid,
                ..
            } => {
                let pass = pass.get_or_insert_with(|| {
                    encoder
                        .begin_compute_pass(&wgpu::ComputePassDescriptor {
                            label: Some("plan"),
                            timestamp_writes: None,
                        })
                        .forget_lifetime()
                });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, bind_group, &[]);
                pass.dispatch_workgroups(grid.x, grid.y, 1);
                dispatches += 1;
            }
            Step::Copy {
                source,
                source_offset,
                target,
                target_offset,
                size,
            } => {
                pass = None;
                encoder.copy_buffer_to_buffer(
                    source,
                    *source_offset,
                    target,
                    *target_offset,
                    *size,
                );
            }
            Step::CopyToTexels {
                source,
                target,
                offset,
                first,
                count,
            } => {
                pass = None;
                target.record_copy_range(encoder, source, *offset, *first, *count);
            }
        }
    }
    dispatches
}

/// How long a run of steps took.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timed {
    /// Wall clock around its submission and the wait for it.
    pub wall_ms: f64,
    /// The GPU's own time between timestamps written just before and just after it,
    /// where the device has timestamp queries.
    pub gpu_ms: Option<f64>,
}

/// Records `steps` in one submission between two timestamped empty compute passes
/// (where the device has timestamp queries), waits for it, and returns the time taken
/// (profiles; the steps' effects happen once more).
fn run_timed<'s>(gpu: &GpuContext, steps: impl IntoIterator<Item = &'s Step>) -> Timed {
    let queries = gpu.caps.timestamps.then(|| {
        let set = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("profile timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let resolve = gpu.create_buffer(&wgpu::BufferDescriptor {
            label: Some("profile timestamps resolve"),
            size: 16,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        (set, resolve)
    });
    let mark = |encoder: &mut wgpu::CommandEncoder, set: &wgpu::QuerySet, index: u32| {
        let (begin, end) = if index == 0 {
            (Some(0), None)
        } else {
            (None, Some(1))
        };
        encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("profile mark"),
            timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: begin,
                end_of_pass_write_index: end,
            }),
        });
    };
    let clock = std::time::Instant::now();
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("profile"),
        });
    if let Some((set, _)) = &queries {
        mark(&mut encoder, set, 0);
    }
    encode_steps(gpu, &mut encoder, steps);
    if let Some((set, resolve)) = &queries {
        mark(&mut encoder, set, 1);
        encoder.resolve_query_set(set, 0..2, resolve, 0);
    }
    gpu.submit([encoder.finish()]);
    gpu.wait_idle();
    let wall_ms = clock.elapsed().as_secs_f64() * 1e3;
    let gpu_ms = queries.and_then(|(_, resolve)| {
        let bytes = super::readback::buffer(gpu, &resolve, "profile timestamps").ok()?;
        let ticks: Vec<u64> = bytemuck::pod_collect_to_vec(&bytes);
        let period = f64::from(gpu.queue.get_timestamp_period());
        Some(ticks[1].saturating_sub(ticks[0]) as f64 * period / 1e6)
    });
    Timed { wall_ms, gpu_ms }
}

/// Recorded work kept to run again: its buffers, uniforms and bind groups were made when
/// it was recorded by a [`Builder`], so running it creates nothing. Inputs that
/// change between runs live in buffers the owner rewrites with `write_buffer`. The work
/// is in parts (split at [`Builder::boundary`]) so a caller can submit it piece by piece.
pub struct Plan {
    parts: Vec<Vec<Step>>,
    flops: u64,
    stages: Vec<Mark>,
}

/// Where a named stage starts: its first step (counted over all parts) and the FLOPs
/// recorded before it.
#[derive(Clone, Copy, Debug)]
struct Mark {
    name: &'static str,
    step: usize,
    flops: u64,
}

/// One stage's share of a plan ([`Plan::profile_stages`]), summed over the places it was
/// recorded (e.g. every denoising step).
#[derive(Clone, Debug, PartialEq)]
pub struct StageProfile {
    pub name: &'static str,
    pub dispatches: usize,
    /// Wall clock around the stage's submission and the wait for it.
    pub ms: f64,
    /// The GPU's own time for the stage (timestamps), where the device has them.
    pub gpu_ms: Option<f64>,
    pub flops: u64,
}

/// One step of a plan run alone: its place in the plan, shader (or copy), workgroup
/// grid (dispatches) and wall and GPU milliseconds.
#[derive(Clone, Debug, PartialEq)]
pub struct StepProfile {
    pub index: usize,
    pub name: &'static str,
    pub grid: Option<Grid>,
    pub ms: f64,
    pub gpu_ms: Option<f64>,
}

/// One shader's dispatches (or the copies) of a plan, each run alone: their count and
/// total wall and GPU milliseconds.
#[derive(Clone, Debug, PartialEq)]
pub struct ShaderProfile {
    pub name: &'static str,
    pub count: usize,
    pub ms: f64,
    pub gpu_ms: Option<f64>,
}

impl Plan {
    /// The number of parts (submission-sized pieces).
    pub fn parts(&self) -> usize {
        self.parts.len()
    }

    /// Compute dispatches in one run.
    pub fn dispatches(&self) -> usize {
        self.parts
            .iter()
            .flatten()
            .filter(|s| matches!(s, Step::Dispatch { .. }))
            .count()
    }

    /// Copies (buffer to buffer, buffer to texels) of one run.
    pub fn copies(&self) -> usize {
        self.parts
            .iter()
            .flatten()
            .filter(|s| !matches!(s, Step::Dispatch { .. }))
            .count()
    }

    /// FLOPs of one run (as its recorder counted them).
    pub fn flops(&self) -> u64 {
        self.flops
    }

    /// Records part `k` into `encoder` without counting its dispatches: the caller
    /// counts them when it submits them (a recording may be dropped unsubmitted).
    pub fn record_part(&self, encoder: &mut wgpu::CommandEncoder, k: usize) {
        record_steps(encoder, &self.parts[k]);
    }

    /// Runs every step in its own submission, waited for (the plan's effects happen once
    /// more), and returns each step's time in plan order.
    pub fn profile_steps(&self, gpu: &GpuContext) -> Vec<StepProfile> {
        self.parts
            .iter()
            .flatten()
            .enumerate()
            .map(|(index, step)| {
                let timed = run_timed(gpu, [step]);
                let (name, grid) = match step {
                    Step::Dispatch { name, grid, .. } => (*name, Some(*grid)),
                    Step::Copy { .. } => ("copy", None),
                    Step::CopyToTexels { .. } => ("copy to texels", None),
                };
                StepProfile {
                    index,
                    name,
                    grid,
                    ms: timed.wall_ms,
                    gpu_ms: timed.gpu_ms,
                }
            })
            .collect()
    }

    /// [`Plan::profile_steps`] summed by shader, slowest first (by GPU time where the
    /// device has timestamps, else by wall clock).
    pub fn profile(steps: &[StepProfile]) -> Vec<ShaderProfile> {
        let mut by_name: Vec<ShaderProfile> = Vec::new();
        for step in steps {
            match by_name.iter_mut().find(|p| p.name == step.name) {
                Some(entry) => {
                    entry.count += 1;
                    entry.ms += step.ms;
                    entry.gpu_ms = entry.gpu_ms.zip(step.gpu_ms).map(|(a, b)| a + b);
                }
                None => by_name.push(ShaderProfile {
                    name: step.name,
                    count: 1,
                    ms: step.ms,
                    gpu_ms: step.gpu_ms,
                }),
            }
        }
        let key = |p: &ShaderProfile| p.gpu_ms.unwrap_or(p.ms);
        by_name.sort_by(|a, b| key(b).total_cmp(&key(a)));
        by_name
    }

    /// Runs each stage (the steps between [`Builder::stage`] marks) in its own
    /// submission, waited for, and returns dispatches, milliseconds and FLOPs per stage
    /// in order (a stage marked more than once sums its runs).
    pub fn profile_stages(&self, gpu: &GpuContext) -> Vec<StageProfile> {
        let steps: Vec<&Step> = self.parts.iter().flatten().collect();
        let mut marks = self.stages.clone();
        if marks.first().is_none_or(|m| m.step > 0) {
            marks.insert(
                0,
                Mark {
                    name: "other",
                    step: 0,
                    flops: 0,
                },
            );
        }
        let mut out: Vec<StageProfile> = Vec::new();
        for (k, mark) in marks.iter().enumerate() {
            let (end, end_flops) = marks
                .get(k + 1)
                .map_or((steps.len(), self.flops), |next| (next.step, next.flops));
            let range = &steps[mark.step..end];
            let timed = run_timed(gpu, range.iter().copied());
            let ms = timed.wall_ms;
            let dispatches = range
                .iter()
                .filter(|s| matches!(s, Step::Dispatch { .. }))
                .count();
            let flops = end_flops - mark.flops;
            match out.iter_mut().find(|p| p.name == mark.name) {
                Some(p) => {
                    p.dispatches += dispatches;
                    p.ms += ms;
                    p.gpu_ms = p.gpu_ms.zip(timed.gpu_ms).map(|(a, b)| a + b);
                    p.flops += flops;
                }
                None => out.push(StageProfile {
                    name: mark.name,
                    dispatches,
                    ms,
                    gpu_ms: timed.gpu_ms,
                    flops,
                }),
            }
        }
        out
    }
}

/// Records steps in parts (split at [`Builder::boundary`]).
pub struct Builder<'a> {
    gpu: &'a GpuContext,
    pipelines: &'a mut PipelineCache,
    precision: Precision,
    /// The parts recorded so far; the last one is open.
    parts: Vec<Vec<Step>>,
    /// Named stages (profiles).
    stages: Vec<Mark>,
    /// Start a new part after this many steps (None: only at boundaries).
    max_part: Option<usize>,
}

impl<'a> Builder<'a> {
    pub fn new(
        gpu: &'a GpuContext,
        pipelines: &'a mut PipelineCache,
        precision: Precision,
    ) -> Self {
        Self {
            gpu,
            pipelines,
            precision,
            parts: vec![Vec::new()],
            stages: Vec::new(),
            max_part: None,
        }
    }

    /// Parts of at most `steps` steps from now on (boundaries still split too), so a
    /// caller that submits part by part keeps every submission short.
    pub fn limit_parts(&mut self, steps: usize) {
        self.max_part = Some(steps.max(1));
    }

    pub fn gpu(&self) -> &'a GpuContext {
        self.gpu
    }

    /// The variant `Elem` shaders are built in.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// One thread per element at 64 threads per workgroup.
    pub fn grid(&self, threads: usize) -> Grid {
        Grid::for_elements(threads as u32, self.max_per_dim())
    }

    /// `count` workgroups (kernels that give each workgroup one tile, query or group).
    pub fn workgroups(&self, count: usize) -> Grid {
        Grid::for_workgroups(count as u32, self.max_per_dim())
    }

    fn max_per_dim(&self) -> u32 {
        self.gpu
            .device
            .limits()
            .max_compute_workgroups_per_dimension
    }

    fn push(&mut self, step: Step) {
        if self
            .max_part
            .is_some_and(|max| self.parts.last().is_some_and(|p| p.len() >= max))
        {
            self.parts.push(Vec::new());
        }
        self.parts.last_mut().expect("an open part").push(step);
    }

    /// Records one dispatch of `shader`: `params` as a uniform at binding 0, then
    /// `buffers` at bindings 1, 2, …, over `grid`.
    pub fn dispatch<P: bytemuck::Pod>(
        &mut self,
        shader: &Shader,
        params: &P,
        buffers: &[&wgpu::Buffer],
        grid: Grid,
    ) {
        let bound: Vec<Bound> = buffers.iter().map(|&b| Bound::Buffer(b)).collect();
        self.dispatch_bound(shader, params, &bound, grid);
    }

    /// [`Builder::dispatch`] with buffers or texels at bindings 1, 2, ….
    pub fn dispatch_bound<P: bytemuck::Pod>(
        &mut self,
        shader: &Shader,
        params: &P,
        resources: &[Bound],
        grid: Grid,
    ) {
        let declared = self.pipelines.bindings(shader, self.precision);
        assert_eq!(
            resources.len() + 1,
            declared,
            "{}: {} resources bound after the parameters, the shader declares {} bindings",
            shader.file,
            resources.len(),
            declared
        );
        let params = uniform(self.gpu, params);
        let bindings: Vec<Bound> = std::iter::once(Bound::Buffer(&params))
            .chain(resources.iter().copied())
            .collect();
        let pipeline = self
            .pipelines
            .get(&self.gpu.device, shader, self.precision)
            .clone();
        let bind_group = self.gpu.bind(&pipeline.get_bind_group_layout(0), &bindings);
        self.push(Step::Dispatch {
            name: shader.file,
            pipeline,
            bind_group,
            grid,
        });
    }

    /// Records a copy of `size` bytes between buffers.
    pub fn copy(
        &mut self,
        source: &wgpu::Buffer,
        source_offset: u64,
        target: &wgpu::Buffer,
        target_offset: u64,
        size: u64,
    ) {
        self.push(Step::Copy {
            source: source.clone(),
            source_offset,
            target: target.clone(),
            target_offset,
            size,
        });
    }

    /// Records a copy of `source` into `target` (see [`Texels::record_copy`]).
    pub fn copy_to_texels(&mut self, source: &wgpu::Buffer, target: &Texels) {
        self.copy_range_to_texels(source, 0, target, 0, target.texels);
    }

    /// Records a copy of `count` texels of `source` from byte `offset` into `target`'s
    /// texels from `first` (see [`Texels::record_copy_range`]).
    pub fn copy_range_to_texels(
        &mut self,
        source: &wgpu::Buffer,
        offset: u64,
        target: &Texels,
        first: u32,
        count: u32,
    ) {
        self.push(Step::CopyToTexels {
            source: source.clone(),
            target: target.clone(),
            offset,
            first,
            count,
        });
    }

    /// Starts a new part.
    pub fn boundary(&mut self) {
        if !self.parts.last().is_some_and(Vec::is_empty) {
            self.parts.push(Vec::new());
        }
    }

    /// Submits what is recorded, in one submission, and starts afresh.
    pub fn submit(&mut self) {
        let parts = std::mem::replace(&mut self.parts, vec![Vec::new()]);
        self.stages.clear();
        let mut encoder = self
            .gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("plan"),
            });
        for part in &parts {
            encode_steps(self.gpu, &mut encoder, part);
        }
        self.gpu.submit([encoder.finish()]);
    }

    /// Starts the stage `name` (profiles): the steps recorded from here to the next mark
    /// belong to it, with the FLOPs counted from `flops` (the recorder's count so far).
    pub fn stage(&mut self, name: &'static str, flops: u64) {
        let step = self.parts.iter().map(Vec::len).sum();
        self.stages.push(Mark { name, step, flops });
    }

    /// The recorded work as a [`Plan`] of `flops` FLOPs (nothing is submitted).
    pub fn finish(mut self, flops: u64) -> Plan {
        if self.parts.len() > 1 && self.parts.last().is_some_and(Vec::is_empty) {
            self.parts.pop();
        }
        Plan {
            parts: std::mem::take(&mut self.parts),
            flops,
            stages: std::mem::take(&mut self.stages),
        }
    }
}
