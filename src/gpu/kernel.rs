//! Compute kernel runner: a pipeline cache, dispatches that split past the per-dimension
//! workgroup limit, and the foundation's example kernels (scale-add, sum) with their fallbacks.

use std::collections::HashMap;

use super::shaders::Shader;
use super::timing::PassTimer;
use super::{Bound, GpuContext, GpuError, readback};
use crate::gpu_struct;
use crate::wgsl_shader as shader;

pub use super::precision::Precision;
pub use super::shaders::WORKGROUP_SIZE;

gpu_struct! {
    /// Parameters of element-wise kernels: `y = scale * x + bias` over `len` elements.
    pub struct ElementwiseParams {
        pub len: u32,
        pub scale: f32,
        pub bias: f32,
        pub pad: u32,
    }
}

gpu_struct! {
    /// Parameters of the sum reduction over `len` elements.
    pub struct ReduceParams {
        pub len: u32,
        pub pad0: u32,
        pub pad1: u32,
        pub pad2: u32,
    }
}

// The GPU layer's own example kernels, declared beside their dispatch code as every
// stage's are (`nn::ops`, `splat::raster` and its neighbours, `engine::kernels`,
// `render::scene`); `crate::shaders()` lists them all.
pub const SCALE_ADD: Shader = shader!("gpu/scale_add.wgsl", [ElementwiseParams], elem);
pub const SUM_SHARED: Shader =
    shader!("gpu/sum_shared.wgsl", [ReduceParams], f16: false, subgroups: false);
pub const SUM_SUBGROUP: Shader =
    shader!("gpu/sum_subgroup.wgsl", [ReduceParams], f16: false, subgroups: true);

/// The GPU layer's shaders.
pub const SHADERS: &[Shader] = &[SCALE_ADD, SUM_SHARED, SUM_SUBGROUP];

/// A 2-D dispatch covering `workgroups` linear workgroups with at most `max_per_dim` per
/// dimension; kernels recover the linear index as `id.x + id.y * num_workgroups.x` and
/// skip the few past the end.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Grid {
    pub x: u32,
    pub y: u32,
}

impl Grid {
    pub fn for_workgroups(workgroups: u32, max_per_dim: u32) -> Self {
        if workgroups <= max_per_dim {
            return Self {
                x: workgroups,
                y: 1,
            };
        }
        let y = workgroups.div_ceil(max_per_dim);
        let x = workgroups.div_ceil(y);
        Self { x, y }
    }

    /// The grid for one thread per element at [`WORKGROUP_SIZE`] threads per workgroup.
    pub fn for_elements(elements: u32, max_per_dim: u32) -> Self {
        Self::for_workgroups(elements.div_ceil(WORKGROUP_SIZE), max_per_dim)
    }
}

/// Compute pipelines by (shader file, integer constants, precision variant), built once
/// on first use; every compute shader's entry point is `main`. (Two shaders may share a
/// file with different constants: specialised variants of one kernel.)
#[derive(Default)]
pub struct PipelineCache {
    pipelines: HashMap<PipelineKey, wgpu::ComputePipeline>,
    /// Group-0 binding counts by naga's reflection (see [`PipelineCache::bindings`]).
    bindings: HashMap<PipelineKey, usize>,
}

type PipelineKey = (&'static str, &'static [(&'static str, u32)], Precision);

impl PipelineCache {
    pub fn get(
        &mut self,
        device: &wgpu::Device,
        shader: &Shader,
        precision: Precision,
    ) -> &wgpu::ComputePipeline {
        self.pipelines
            .entry((shader.file, shader.uints, precision))
            .or_insert_with(|| {
                let module = shader.module(device, precision);
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(shader.file),
                    layout: None,
                    module: &module,
                    entry_point: Some("main"),
                    compilation_options: Default::default(),
                    cache: None,
                })
            })
    }

    /// How many group-0 bindings the shader declares (reflected once per variant), so a
    /// dispatch that binds another number is caught when it is recorded, naming the file.
    pub fn bindings(&mut self, shader: &Shader, precision: Precision) -> usize {
        *self
            .bindings
            .entry((shader.file, shader.uints, precision))
            .or_insert_with(|| match shader.bindings(precision) {
                Ok(b) => b.len(),
                Err(e) => panic!("{e}"),
            })
    }

    pub fn len(&self) -> usize {
        self.pipelines.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pipelines.is_empty()
    }
}

/// Records one compute dispatch: binds `buffers` in order to group 0 and covers `grid`.
pub fn dispatch(
    gpu: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&wgpu::Buffer],
    grid: Grid,
    timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
) {
    let bound = as_bound(buffers);
    compute_pass(gpu, encoder, pipeline, &bound, timestamp_writes)
        .dispatch_workgroups(grid.x, grid.y, 1);
}

/// [`dispatch`] over the grid the GPU wrote at byte `offset` of `grids` (three u32:
/// workgroups along x, y, z), for work whose size only the GPU knows.
pub fn dispatch_indirect(
    gpu: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&wgpu::Buffer],
    grids: &wgpu::Buffer,
    offset: u64,
) {
    let bound = as_bound(buffers);
    compute_pass(gpu, encoder, pipeline, &bound, None).dispatch_workgroups_indirect(grids, offset);
}

/// [`dispatch`] with buffers and texels bound in order to group 0.
pub fn dispatch_bound(
    gpu: &GpuContext,
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    resources: &[Bound],
    grid: Grid,
) {
    compute_pass(gpu, encoder, pipeline, resources, None).dispatch_workgroups(grid.x, grid.y, 1);
}

fn as_bound<'a>(buffers: &[&'a wgpu::Buffer]) -> Vec<Bound<'a>> {
    buffers.iter().map(|&b| Bound::Buffer(b)).collect()
}

/// A compute pass with `pipeline` and `resources` bound, counted as one dispatch.
fn compute_pass<'e>(
    gpu: &GpuContext,
    encoder: &'e mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    resources: &[Bound],
    timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
) -> wgpu::ComputePass<'e> {
    let bind_group = gpu.bind(&pipeline.get_bind_group_layout(0), resources);
    gpu.counters.dispatches(1);
    let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: None,
        timestamp_writes,
    });
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, &bind_group, &[]);
    pass
}

/// A uniform buffer holding `value` (kernel parameters).
pub fn uniform<T: bytemuck::Pod>(gpu: &GpuContext, value: &T) -> wgpu::Buffer {
    let buffer = gpu.create_buffer(&wgpu::BufferDescriptor {
        label: Some("params"),
        size: std::mem::size_of::<T>() as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    gpu.queue
        .write_buffer(&buffer, 0, bytemuck::bytes_of(value));
    buffer
}

/// The example element-wise kernel, `y = scale * x + bias`, prepared on the device in
/// `precision` so it can be recorded repeatedly (tests, benchmarks).
pub struct ScaleAdd {
    pipeline: wgpu::ComputePipeline,
    params: wgpu::Buffer,
    input: wgpu::Buffer,
    output: wgpu::Buffer,
    grid: Grid,
    len: usize,
    precision: Precision,
}

impl ScaleAdd {
    pub fn new(
        gpu: &GpuContext,
        cache: &mut PipelineCache,
        x: &[f32],
        scale: f32,
        bias: f32,
        precision: Precision,
    ) -> Result<Self, GpuError> {
        // f16 arrays are padded to 4 bytes so odd lengths still bind and copy.
        let mut bytes = precision.encode(x);
        bytes.resize(bytes.len().next_multiple_of(4), 0);
        let padded = bytes.len() as u64;
        let input = gpu.storage_buffer("scale_add.x", padded, wgpu::BufferUsages::COPY_DST)?;
        gpu.queue.write_buffer(&input, 0, &bytes);
        let output = gpu.storage_buffer("scale_add.y", padded, wgpu::BufferUsages::COPY_SRC)?;
        let len = x.len() as u32;
        let params = ElementwiseParams {
            len,
            scale,
            bias,
            pad: 0,
        };
        Ok(Self {
            pipeline: cache.get(&gpu.device, &SCALE_ADD, precision).clone(),
            params: uniform(gpu, &params),
            input,
            output,
            grid: Grid::for_elements(
                len,
                gpu.device.limits().max_compute_workgroups_per_dimension,
            ),
            len: x.len(),
            precision,
        })
    }

    /// Bytes read and written by one run.
    pub fn bytes_moved(&self) -> u64 {
        2 * (self.len * self.precision.bytes()) as u64
    }

    pub fn record(
        &self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        timer: Option<PassTimer<'_>>,
    ) {
        let buffers = [&self.params, &self.input, &self.output];
        dispatch(
            gpu,
            encoder,
            &self.pipeline,
            &buffers,
            self.grid,
            timer.as_ref().map(PassTimer::compute),
        );
    }

    /// Runs the kernel once and reads the result back.
    pub fn run(&self, gpu: &GpuContext) -> Result<Vec<f32>, GpuError> {
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        self.record(gpu, &mut encoder, None);
        gpu.submit([encoder.finish()]);
        self.read(gpu)
    }

    /// The output as f32.
    pub fn read(&self, gpu: &GpuContext) -> Result<Vec<f32>, GpuError> {
        let raw = readback::buffer(gpu, &self.output, "scale_add.y")?;
        Ok(self
            .precision
            .decode(&raw[..self.len * self.precision.bytes()]))
    }
}

/// The example reduction: the sum of `x`, with subgroup operations where available and
/// workgroup shared memory otherwise.
pub fn sum(gpu: &GpuContext, cache: &mut PipelineCache, x: &[f32]) -> Result<f32, GpuError> {
    let shader = if gpu.caps.subgroups {
        &SUM_SUBGROUP
    } else {
        &SUM_SHARED
    };
    let input = gpu.storage_buffer_init(
        "sum.x",
        bytemuck::cast_slice(x),
        wgpu::BufferUsages::empty(),
    )?;
    let output = gpu.storage_buffer("sum.out", 4, wgpu::BufferUsages::COPY_SRC)?;
    let params = uniform(
        gpu,
        &ReduceParams {
            len: x.len() as u32,
            pad0: 0,
            pad1: 0,
            pad2: 0,
        },
    );
    let pipeline = cache.get(&gpu.device, shader, Precision::F32);
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    dispatch(
        gpu,
        &mut encoder,
        pipeline,
        &[&params, &input, &output],
        Grid { x: 1, y: 1 },
        None,
    );
    gpu.submit([encoder.finish()]);
    let raw = readback::buffer(gpu, &output, "sum.out")?;
    Ok(bytemuck::pod_read_unaligned(&raw[..4]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_fits_in_one_dimension_when_it_can() {
        assert_eq!(Grid::for_workgroups(10, 65_535), Grid { x: 10, y: 1 });
        assert_eq!(
            Grid::for_workgroups(65_535, 65_535),
            Grid { x: 65_535, y: 1 }
        );
    }

    #[test]
    fn grid_splits_past_the_limit_and_covers_every_workgroup() {
        for (n, max) in [
            (65_536, 65_535),
            (1_000_000, 65_535),
            (13, 4),
            (16, 4),
            (5, 3),
        ] {
            let g = Grid::for_workgroups(n, max);
            assert!(g.x <= max && g.y <= max, "{n} {max} -> {g:?}");
            assert!(g.x as u64 * g.y as u64 >= n as u64, "{n} {max} -> {g:?}");
            // No whole row is wasted.
            assert!(
                (g.x as u64) * (g.y as u64 - 1) < n as u64,
                "{n} {max} -> {g:?}"
            );
        }
        assert_eq!(Grid::for_workgroups(13, 4), Grid { x: 4, y: 4 });
        assert_eq!(Grid::for_workgroups(5, 3), Grid { x: 3, y: 2 });
    }

    #[test]
    fn elements_round_up_to_whole_workgroups() {
        assert_eq!(Grid::for_elements(1, 65_535), Grid { x: 1, y: 1 });
        assert_eq!(Grid::for_elements(64, 65_535), Grid { x: 1, y: 1 });
        assert_eq!(Grid::for_elements(65, 65_535), Grid { x: 2, y: 1 });
    }
}
