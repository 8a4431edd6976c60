//! The WGSL splat rasterizer: project (shaders/splat_project.wgsl) → exclusive scan of the
//! tiles each splat touches → one (tile, depth) key per covered tile → LSD radix sort, 8
//! bits a pass, in which no workgroup waits on another, over the entries kept (its grids
//! are sized on the GPU, indirect dispatches; its blocks are workgroups on a GPU and single
//! invocations on a CPU driver, [`RasterKernels`]) → each tile's range → per-tile
//! front-to-back blending with early stop (a workgroup of 256 pixels through shared
//! memory on a GPU; on a CPU driver one invocation per pixel row of a tile, up to
//! [`ROW_BLEND_MAX_SPLATS`]). Everything is recorded into one command encoder; only the
//! caller reads the image back.

use crate::wgsl_shader as shader;
use glam::{Mat4, Vec3};

use super::ply::Splat;
use super::project::SplatCamera;
use crate::gpu::kernel::{
    Grid, PipelineCache, Precision, dispatch, dispatch_bound, dispatch_indirect, uniform,
};
use crate::gpu::shaders::Shader;
use crate::gpu::texels::Texels;
use crate::gpu::{Bound, GpuContext, GpuError};
use crate::gpu_struct;

pub const SPLAT_PROJECT: Shader = shader!("splat/splat_project.wgsl", [RasterView, GpuSplat, ProjectedSplat], f16: false, subgroups: false);
pub const SCAN_BLOCKS: Shader =
    shader!("splat/scan_blocks.wgsl", [ScanParams], f16: false, subgroups: false)
        .with_uints(&[("SCAN_PER_LANE", SCAN_PER_LANE as u32)]);
pub const SCAN_ADD: Shader =
    shader!("splat/scan_add.wgsl", [ScanParams], f16: false, subgroups: false)
        .with_uints(&[("SCAN_PER_LANE", SCAN_PER_LANE as u32)]);
pub const SORT_GRIDS: Shader = shader!(
    "splat/sort_grids.wgsl",
    [RasterView, ScanParams],
    f16: false,
    subgroups: false
);
pub const SPLAT_KEYS: Shader =
    shader!("splat/splat_keys.wgsl", [RasterView, ProjectedSplat], f16: false, subgroups: false);
pub const RADIX_HISTOGRAM: Shader =
    shader!("splat/radix_histogram.wgsl", [RadixParams], f16: false, subgroups: false);
pub const RADIX_SCATTER: Shader =
    shader!("splat/radix_scatter.wgsl", [RadixParams], f16: false, subgroups: false);
pub const RADIX_HISTOGRAM_SERIAL: Shader = shader!(
    "splat/radix_histogram_serial.wgsl",
    [RadixParams],
    f16: false,
    subgroups: false
);
pub const RADIX_SCATTER_SERIAL: Shader = shader!(
    "splat/radix_scatter_serial.wgsl",
    [RadixParams],
    f16: false,
    subgroups: false
);
/// The digit offsets of a sort pass for CPU drivers (GPUs scan with [`SCAN_BLOCKS`]).
pub const RADIX_SCAN_SERIAL: Shader =
    shader!("splat/radix_scan_serial.wgsl", [], f16: false, subgroups: false);
pub const SPLAT_RANGES: Shader =
    shader!("splat/splat_ranges.wgsl", [RasterView], f16: false, subgroups: false);
pub const SPLAT_RENDER: Shader =
    shader!("splat/splat_render.wgsl", [RasterView, ProjectedSplat], f16: false, subgroups: false)
        .with_uints(&[("TILE", super::project::TILE)]);
pub const SPLAT_RENDER_ROWS: Shader = shader!(
    "splat/splat_render_rows.wgsl",
    [RasterView, ProjectedSplat],
    f16: false,
    subgroups: false
)
.with_uints(&[("TILE", super::project::TILE)]);

/// Every shader of this file (gathered by `splat::shaders`).
pub const SHADERS: &[Shader] = &[
    SPLAT_PROJECT,
    SCAN_BLOCKS,
    SCAN_ADD,
    SPLAT_KEYS,
    SORT_GRIDS,
    RADIX_HISTOGRAM,
    RADIX_SCATTER,
    RADIX_HISTOGRAM_SERIAL,
    RADIX_SCATTER_SERIAL,
    RADIX_SCAN_SERIAL,
    SPLAT_RANGES,
    SPLAT_RENDER,
    SPLAT_RENDER_ROWS,
];

/// Which kernels sort and blend; both give the same image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RasterKernels {
    /// For GPUs: each radix block is a workgroup of 256 (shared-memory counts and ranks),
    /// and each tile a workgroup of 256 pixels that loads its splats into shared memory
    /// 256 at a time (splat_render.wgsl).
    Gpu,
    /// For CPU drivers, without atomics: one invocation a radix block counts and places
    /// its entries (radix_histogram_serial.wgsl, radix_scatter_serial.wgsl), one
    /// workgroup of 256 lanes with one barrier scans the counts (radix_scan_serial.wgsl,
    /// up to [`RADIX_SCAN_SERIAL_MAX_BLOCKS`] blocks), and one invocation a pixel row of a
    /// tile blends each splat over only the pixels of the row it can reach
    /// (splat_render_rows.wgsl), for up to [`ROW_BLEND_MAX_SPLATS`] splats; more are
    /// scanned and blended as on a GPU.
    Cpu,
}

/// The most splats the row blend draws. Its walk over a tile's sort entries is a loop of
/// one iteration an entry, and lavapipe ends every loop of an invocation once all of its
/// loops together have run 65,535 iterations (docs/architecture.md); a splat enters a
/// tile once, so up to this many (less the row's two 16-pixel loops, with a margin) no
/// tile can reach that. The shared-memory blend walks 8 entries an iteration and has no
/// such bound below half a million. Unrolled the same way the row blend drew the
/// Witch's window 40-70 % slower (1280×800: 117-148 ms against 85-90 ms, level 256), so
/// the two are kept: at level 256 (18,036 splats) every window takes the row blend.
pub const ROW_BLEND_MAX_SPLATS: usize = 65_000;

/// The most radix blocks (256 sort entries each, over the capacity) whose digit offsets
/// `radix_scan_serial.wgsl` computes: each of its lanes loops over the blocks twice and
/// over up to 255 digit totals, under lavapipe's 65,535 iterations. More blocks (over
/// half a million splats) are scanned as on a GPU.
pub const RADIX_SCAN_SERIAL_MAX_BLOCKS: usize = 32_000;
const _: () = assert!(2 * RADIX_SCAN_SERIAL_MAX_BLOCKS + 256 + 3 < 65_535);

impl RasterKernels {
    /// `Cpu` on a CPU driver, `Gpu` on anything else.
    pub fn for_adapter(gpu: &GpuContext) -> Self {
        if gpu.cpu_driver() {
            Self::Cpu
        } else {
            Self::Gpu
        }
    }
}

/// Values each lane of the prefix sum adds up serially: a workgroup scans 256 times as
/// many. One value a lane took 38 ms to scan a 640 × 400 frame's 288k-entry histogram on
/// lavapipe (each workgroup's barriers are what a CPU driver pays for), 16 take 5 ms
/// (docs/performance.md).
pub const SCAN_PER_LANE: usize = 16;

gpu_struct! {
    /// The camera and sizes of one rasterized frame.
    pub struct RasterView {
        pub view: Mat4,
        pub fx: f32,
        pub fy: f32,
        pub width: u32,
        pub height: u32,
        pub near: f32,
        pub depth_range: f32,
        pub tiles_x: u32,
        pub tiles_y: u32,
        pub splats: u32,
        pub capacity: u32,
        /// The device's workgroups per grid dimension (sort_grids.wgsl sizes grids).
        pub max_groups: u32,
        pub reserved1: u32,
        pub background: [f32; 4],
    }
}

gpu_struct! {
    /// A Gaussian as the rasterizer reads it: xyz + opacity (activated), linear scales,
    /// rotation (x y z w), SH degree-0 coefficients.
    pub struct GpuSplat {
        pub position_opacity: [f32; 4],
        pub scale: [f32; 4],
        pub rotation: [f32; 4],
        pub f_dc: [f32; 4],
    }
}

gpu_struct! {
    /// A projected Gaussian: centre, depth, radius; conic and opacity; colour; tiles.
    pub struct ProjectedSplat {
        pub center_depth: [f32; 4],
        pub conic_opacity: [f32; 4],
        pub color: [f32; 4],
        pub tiles: [u32; 4],
    }
}

gpu_struct! {
    /// An exclusive scan of `len` values in `blocks` blocks of 256 · [`SCAN_PER_LANE`].
    pub struct ScanParams {
        pub len: u32,
        pub blocks: u32,
        pub reserved0: u32,
        pub reserved1: u32,
    }
}

gpu_struct! {
    /// One radix pass over the digit at `shift` (the entries kept, in blocks of 256,
    /// come from the GPU's count).
    pub struct RadixParams {
        pub shift: u32,
        pub reserved0: u32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

impl From<&Splat> for GpuSplat {
    fn from(s: &Splat) -> Self {
        Self {
            position_opacity: s.position.extend(s.opacity).to_array(),
            scale: s.scale.extend(0.0).to_array(),
            rotation: s.rotation.to_array(),
            f_dc: s.f_dc.extend(0.0).to_array(),
        }
    }
}

impl GpuSplat {
    /// The splat as the rest of the crate holds it (exports, tests).
    pub fn to_splat(&self) -> Splat {
        let [x, y, z, opacity] = self.position_opacity;
        Splat {
            position: Vec3::new(x, y, z),
            f_dc: Vec3::from_slice(&self.f_dc[..3]),
            opacity,
            scale: Vec3::from_slice(&self.scale[..3]),
            rotation: glam::Quat::from_array(self.rotation),
        }
    }
}

/// Sort entries allowed per splat on average; beyond that, entries are dropped (and
/// counted in [`Raster::info`]).
pub const ENTRIES_PER_SPLAT: usize = 16;

/// Sort entries for `count` splats.
fn capacity(count: usize) -> usize {
    (count.max(1) * ENTRIES_PER_SPLAT).next_multiple_of(256)
}

/// What one rasterized frame leaves on the GPU.
pub struct Raster {
    /// `width × height` linear RGBA f32, row-major.
    pub image: wgpu::Buffer,
    /// [sort entries kept, sort entries wanted].
    pub info: wgpu::Buffer,
}

/// The working buffers of one (splat count, image size), kept between frames.
struct Buffers {
    key: (usize, u32, u32, bool),
    projected: wgpu::Buffer,
    touched: wgpu::Buffer,
    offsets: wgpu::Buffer,
    keys: [wgpu::Buffer; 2],
    values: [wgpu::Buffer; 2],
    info: wgpu::Buffer,
    ranges: wgpu::Buffer,
    image: wgpu::Buffer,
    hist: wgpu::Buffer,
    /// Indirect dispatch grids sized by the sort entries kept (sort_grids.wgsl).
    grids: wgpu::Buffer,
    /// The histogram scan's [`ScanParams`], its length from the entries kept.
    hist_scan: wgpu::Buffer,
    /// For the row blend: the projected splats and the sorted splat indices as texels
    /// (copied before it), which lavapipe reads as vector gathers where a storage load
    /// is a loop over lanes per value.
    row_texels: Option<(Texels, Texels)>,
}

impl Buffers {
    fn new(
        gpu: &GpuContext,
        count: usize,
        camera: &SplatCamera,
        row_blend: bool,
    ) -> Result<Self, GpuError> {
        let (tiles_x, tiles_y) = camera.tiles();
        let capacity = capacity(count);
        let projected_values = count * std::mem::size_of::<ProjectedSplat>() / 4;
        let row_texels = match row_blend {
            true => Some((
                Texels::new(
                    gpu,
                    "splat.projected.texels",
                    projected_values,
                    Precision::F32,
                )?,
                Texels::new_u32(gpu, "splat.values.texels", capacity)?,
            )),
            false => None,
        };
        let buffer =
            |label: &str, bytes: usize| gpu.storage_buffer(label, bytes.max(4) as u64, STORAGE);
        let hist_scan = gpu.storage_buffer(
            "splat.hist_scan",
            std::mem::size_of::<ScanParams>() as u64,
            STORAGE | wgpu::BufferUsages::UNIFORM,
        )?;
        let blocks = capacity.div_ceil(256 * SCAN_PER_LANE);
        let scan = ScanParams {
            len: capacity as u32,
            blocks: blocks as u32,
            reserved0: 0,
            reserved1: 0,
        };
        gpu.queue
            .write_buffer(&hist_scan, 0, bytemuck::bytes_of(&scan));
        Ok(Self {
            key: (count, camera.width, camera.height, row_blend),
            row_texels,
            projected: buffer(
                "splat.projected",
                count * std::mem::size_of::<ProjectedSplat>(),
            )?,
            touched: buffer("splat.touched", 4 * count)?,
            offsets: buffer("splat.offsets", 4 * count)?,
            keys: [
                buffer("splat.keys", 4 * capacity)?,
                buffer("splat.keys2", 4 * capacity)?,
            ],
            values: [
                buffer("splat.values", 4 * capacity)?,
                buffer("splat.values2", 4 * capacity)?,
            ],
            info: buffer("splat.info", 8)?,
            ranges: buffer("splat.ranges", 8 * (tiles_x * tiles_y) as usize)?,
            image: buffer("splat.image", 16 * (camera.width * camera.height) as usize)?,
            hist: buffer("splat.hist", 4 * capacity)?,
            grids: gpu.storage_buffer(
                "splat.grids",
                4 * 6,
                STORAGE | wgpu::BufferUsages::INDIRECT,
            )?,
            hist_scan,
        })
    }
}

#[derive(Default)]
pub struct Rasterizer {
    pipelines: PipelineCache,
    buffers: Option<Buffers>,
    /// Sort grids over the capacity even where indirect dispatches exist.
    direct: bool,
    /// The kernels asked for, else the adapter's ([`RasterKernels::for_adapter`]).
    kernels: Option<RasterKernels>,
}

const STORAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_SRC)
    .union(wgpu::BufferUsages::COPY_DST);

impl Rasterizer {
    /// Uploads splats for [`Rasterizer::record`].
    pub fn upload(gpu: &GpuContext, splats: &[Splat]) -> Result<wgpu::Buffer, GpuError> {
        let data: Vec<GpuSplat> = splats.iter().map(GpuSplat::from).collect();
        gpu.storage_buffer_init(
            "splats",
            bytemuck::cast_slice(&data),
            wgpu::BufferUsages::empty(),
        )
    }

    /// Whether `count` splats fit the device's storage bindings (the sort buffers are the
    /// largest: 4 bytes per entry).
    pub fn fits(gpu: &GpuContext, count: usize) -> Result<(), GpuError> {
        let bytes = (4 * capacity(count)).max(count * std::mem::size_of::<ProjectedSplat>()) as u64;
        if bytes > gpu.max_storage_binding() {
            return Err(GpuError::TooLarge {
                what: format!("{count} splats"),
                limit: format!(
                    "{} splats on this adapter ({} bytes per storage binding)",
                    gpu.max_storage_binding() as usize / (4 * ENTRIES_PER_SPLAT),
                    gpu.max_storage_binding()
                ),
            });
        }
        Ok(())
    }

    /// Replaces the splats in a buffer made by [`Rasterizer::upload`] with as many new ones.
    pub fn write(gpu: &GpuContext, buffer: &wgpu::Buffer, splats: &[Splat]) {
        let data: Vec<GpuSplat> = splats.iter().map(GpuSplat::from).collect();
        gpu.queue
            .write_buffer(buffer, 0, bytemuck::cast_slice(&data));
    }

    /// Records the rasterization of `count` splats from `camera` over `background`.
    pub fn record(
        &mut self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        splats: &wgpu::Buffer,
        count: usize,
        camera: &SplatCamera,
        background: Vec3,
    ) -> Result<Raster, GpuError> {
        let (tiles_x, tiles_y) = camera.tiles();
        if tiles_x * tiles_y > 1 << 16 {
            return Err(GpuError::TooLarge {
                what: format!("a {} × {} splat image", camera.width, camera.height),
                limit: "65,536 tiles of 16 × 16 pixels (e.g. 4096 × 4096)".into(),
            });
        }
        Self::fits(gpu, count)?;
        let count = count.max(1);
        let capacity = capacity(count);
        let frame = RasterView {
            view: camera.view,
            fx: camera.fx,
            fy: camera.fy,
            width: camera.width,
            height: camera.height,
            near: camera.near,
            depth_range: camera.depth_range,
            tiles_x,
            tiles_y,
            splats: count as u32,
            capacity: capacity as u32,
            max_groups: gpu.device.limits().max_compute_workgroups_per_dimension,
            reserved1: 0,
            background: background.extend(1.0).to_array(),
        };
        let frame = uniform(gpu, &frame);
        let kernels = self
            .kernels
            .unwrap_or_else(|| RasterKernels::for_adapter(gpu));
        let row_blend = kernels == RasterKernels::Cpu && count <= ROW_BLEND_MAX_SPLATS;
        let key = (count, camera.width, camera.height, row_blend);
        if self.buffers.as_ref().is_none_or(|b| b.key != key) {
            self.buffers = Some(Buffers::new(gpu, count, camera, row_blend)?);
        }
        let b = self.buffers.take().expect("made above");
        let blocks = capacity / 256;

        let max = gpu.device.limits().max_compute_workgroups_per_dimension;
        let threads = |n: usize| Grid::for_elements(n as u32, max);
        let groups = |n: usize| Grid::for_workgroups(n as u32, max);
        self.run(
            gpu,
            encoder,
            &SPLAT_PROJECT,
            &[&frame, splats, &b.projected, &b.touched],
            threads(count),
        );
        encoder.copy_buffer_to_buffer(&b.touched, 0, &b.offsets, 0, 4 * count as u64);
        self.scan(gpu, encoder, &b.offsets, count, None)?;
        let bindings = [
            &frame,
            &b.projected,
            &b.touched,
            &b.offsets,
            &b.keys[0],
            &b.values[0],
            &b.info,
        ];
        self.run(gpu, encoder, &SPLAT_KEYS, &bindings, threads(count));
        // The sort runs over the entries kept, not the capacity (on a 640 × 400 frame of
        // the Witch 53k of 289k): its grids and the histogram scan's length come from the
        // GPU's count.
        self.run(
            gpu,
            encoder,
            &SORT_GRIDS,
            &[&frame, &b.info, &b.grids, &b.hist_scan],
            groups(1),
        );
        let grids = self.indirect(gpu).then_some(&b.grids);
        let (histogram, scatter) = match kernels {
            RasterKernels::Gpu => (&RADIX_HISTOGRAM, &RADIX_SCATTER),
            RasterKernels::Cpu => (&RADIX_HISTOGRAM_SERIAL, &RADIX_SCATTER_SERIAL),
        };
        for pass in 0..4 {
            let (from, to) = (pass % 2, 1 - pass % 2);
            let params = uniform(
                gpu,
                &RadixParams {
                    shift: 8 * pass as u32,
                    reserved0: 0,
                    reserved1: 0,
                    reserved2: 0,
                },
            );
            let bindings = [&params, &b.keys[from], &b.info, &b.hist];
            self.run_sized(
                gpu,
                encoder,
                histogram,
                &bindings,
                grids.map(|g| (g, 0)),
                groups(blocks),
            );
            if kernels == RasterKernels::Cpu && blocks <= RADIX_SCAN_SERIAL_MAX_BLOCKS {
                self.run(
                    gpu,
                    encoder,
                    &RADIX_SCAN_SERIAL,
                    &[&b.info, &b.hist],
                    groups(1),
                );
            } else {
                self.scan(gpu, encoder, &b.hist, 256 * blocks, Some(&b.hist_scan))?;
            }
            let bindings = [
                &params,
                &b.keys[from],
                &b.values[from],
                &b.info,
                &b.hist,
                &b.keys[to],
                &b.values[to],
            ];
            self.run_sized(
                gpu,
                encoder,
                scatter,
                &bindings,
                grids.map(|g| (g, 0)),
                groups(blocks),
            );
        }
        encoder.clear_buffer(&b.ranges, 0, None);
        self.run_sized(
            gpu,
            encoder,
            &SPLAT_RANGES,
            &[&b.keys[0], &b.info, &b.ranges],
            grids.map(|g| (g, 12)),
            threads(capacity),
        );
        let tiles = groups((tiles_x * tiles_y) as usize);
        match &b.row_texels {
            Some((projected, values)) => {
                projected.record_copy(encoder, &b.projected);
                values.record_copy(encoder, &b.values[0]);
                let pipeline = self
                    .pipelines
                    .get(&gpu.device, &SPLAT_RENDER_ROWS, Precision::F32);
                let bound = [
                    Bound::Buffer(&frame),
                    Bound::Texels(projected),
                    Bound::Texels(values),
                    Bound::Buffer(&b.ranges),
                    Bound::Buffer(&b.image),
                ];
                dispatch_bound(gpu, encoder, pipeline, &bound, tiles);
            }
            None => {
                let bindings = [&frame, &b.projected, &b.values[0], &b.ranges, &b.image];
                self.run(gpu, encoder, &SPLAT_RENDER, &bindings, tiles);
            }
        }
        let raster = Raster {
            image: b.image.clone(),
            info: b.info.clone(),
        };
        self.buffers = Some(b);
        Ok(raster)
    }

    /// Records an exclusive prefix sum of the first `len` u32 of `data`, in place; with
    /// `written`, of as many as the GPU wrote into those [`ScanParams`] (at most `len`).
    fn scan(
        &mut self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        data: &wgpu::Buffer,
        len: usize,
        written: Option<&wgpu::Buffer>,
    ) -> Result<(), GpuError> {
        let blocks = len.div_ceil(256 * SCAN_PER_LANE);
        let sums = gpu.storage_buffer("scan.sums", 4 * blocks as u64, STORAGE)?;
        let params = match written {
            Some(params) => params.clone(),
            None => uniform(
                gpu,
                &ScanParams {
                    len: len as u32,
                    blocks: blocks as u32,
                    reserved0: 0,
                    reserved1: 0,
                },
            ),
        };
        let grid = Grid::for_workgroups(
            blocks as u32,
            gpu.device.limits().max_compute_workgroups_per_dimension,
        );
        self.run(gpu, encoder, &SCAN_BLOCKS, &[&params, data, &sums], grid);
        if blocks > 1 {
            self.scan(gpu, encoder, &sums, blocks, None)?;
            self.run(gpu, encoder, &SCAN_ADD, &[&params, data, &sums], grid);
        }
        Ok(())
    }

    /// Whether the sort's grids are sized on the GPU (indirect dispatches): unless the
    /// adapter cannot, or [`Rasterizer::direct_grids`] asked for grids over the capacity.
    fn indirect(&self, gpu: &GpuContext) -> bool {
        !self.direct
            && gpu
                .adapter
                .get_downlevel_capabilities()
                .flags
                .contains(wgpu::DownlevelFlags::INDIRECT_EXECUTION)
    }

    /// Runs `kernels` whatever the adapter (tests run both).
    pub fn with_kernels(mut self, kernels: RasterKernels) -> Self {
        self.kernels = Some(kernels);
        self
    }

    /// Sizes the sort's grids by its capacity, as on an adapter without indirect
    /// dispatches (tests run both ways).
    pub fn direct_grids(mut self) -> Self {
        self.direct = true;
        self
    }

    /// Dispatches `shader` over the grid at (buffer, byte offset) `indirect`, or else over
    /// `grid`.
    fn run_sized(
        &mut self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        shader: &Shader,
        buffers: &[&wgpu::Buffer],
        indirect: Option<(&wgpu::Buffer, u64)>,
        grid: Grid,
    ) {
        let Some((grids, offset)) = indirect else {
            return self.run(gpu, encoder, shader, buffers, grid);
        };
        let pipeline = self.pipelines.get(&gpu.device, shader, Precision::F32);
        dispatch_indirect(gpu, encoder, pipeline, buffers, grids, offset);
    }

    fn run(
        &mut self,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        shader: &Shader,
        buffers: &[&wgpu::Buffer],
        grid: Grid,
    ) {
        let pipeline = self.pipelines.get(&gpu.device, shader, Precision::F32);
        dispatch(gpu, encoder, pipeline, buffers, grid, None);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::{GpuOptions, readback};

    /// The prefix sum against a CPU loop: within one block, across blocks (two levels of
    /// block sums) and past 4096² values (three levels); values chosen so that sums wrap
    /// like u32 arithmetic does.
    #[test]
    fn the_scan_is_an_exclusive_prefix_sum_at_every_depth() {
        let gpu = GpuContext::headless(&GpuOptions::from_env()).unwrap();
        let block = 256 * SCAN_PER_LANE;
        for len in [
            1,
            255,
            block - 1,
            block,
            block + 1,
            18 * block + 77,
            block * block + 300,
        ] {
            let data: Vec<u32> = (0..len as u32)
                .map(|i| i.wrapping_mul(2_654_435_761) >> 22)
                .collect();
            let buffer = gpu
                .storage_buffer_init("scan", bytemuck::cast_slice(&data), STORAGE)
                .unwrap();
            let mut rasterizer = Rasterizer::default();
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            rasterizer
                .scan(&gpu, &mut encoder, &buffer, len, None)
                .unwrap();
            gpu.submit([encoder.finish()]);
            let got: Vec<u32> =
                bytemuck::pod_collect_to_vec(&readback::buffer(&gpu, &buffer, "scan").unwrap());
            let mut sum = 0u32;
            for (i, (&value, &got)) in data.iter().zip(&got).enumerate() {
                assert_eq!(got, sum, "length {len}, index {i}");
                sum = sum.wrapping_add(value);
            }
        }
    }
}
