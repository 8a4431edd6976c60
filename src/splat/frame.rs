//! A generated frame's splats made on the GPU, from its world-space points (3N f32 in the
//! 128² map's pixel order) to the rasterizer's input buffer, with the same arithmetic as
//! the CPU path (`base.rs`, `upscale.rs`, `serialise.rs`; tested equal in tests/splat.rs):
//! the root and normalised points, the median spacing (an exact two-pass radix select),
//! base splats and the refiner's features, the refiner's serialisation orders (codes and
//! a stable rank: counted against a shared tile on GPUs, radix-sorted by one invocation
//! on CPU drivers), then either the refined splats at 128² or the upscale of
//! positions and residuals to the splat level and the fine splats. Every buffer is made
//! in [`SplatFrame::new`]; [`SplatFrame::record_coarse`] and [`SplatFrame::record_finish`]
//! record kernels into a [`Builder`], so they become part of the engine's frame plan. The
//! refiner itself runs between the two (the engine wires it: `splat` never imports `nn`).

use glam::Vec3;

use super::base::{self, OPACITY, RESIDUALS, SPREAD, THICKNESS};
use super::ply::SH_C0;
use super::raster::GpuSplat;
use super::serialise::{ORDERS, SerialOrders};
use crate::gpu::kernel::{Grid, Precision};
use crate::gpu::plan::Builder;
use crate::gpu::shaders::Shader;
use crate::gpu::{GpuContext, GpuError, Indices, Permutation};
use crate::gpu_struct;
use crate::wgsl_shader;

/// The map size the model draws (the refiner's points).
pub const COARSE: usize = 128;
/// Refiner input values per point.
pub const FEATURES: usize = 11;
/// Bins of each radix-select pass (16 bits).
const BINS: u64 = 1 << 16;

gpu_struct! {
    /// Sizes and switches of the splat kernels (one struct for all of them).
    pub struct SplatParams {
        /// Points at this level.
        pub points: u32,
        /// Waist points (root).
        pub waist: u32,
        /// Normalisation scale (normalised units per metre).
        pub scale: f32,
        /// Neighbour pairs of the median spacing.
        pub pairs: u32,
        /// The rank of the median among the pairs.
        pub mid: u32,
        /// Radix-select pass: 0 the high 16 bits, 1 the low.
        pub round: u32,
        /// First channel and channels per row (scatter, gather).
        pub first: u32,
        pub channels: u32,
        /// Pixels per map plane (scatter, gather).
        pub plane: u32,
        /// Pooling stride of the refiner.
        pub stride: u32,
        /// Serialisation curve (0..4) of a rank pass.
        pub curve: u32,
        /// The refiner's mean-offset bound, world units.
        pub bound: f32,
        /// Base: also write the refiner's features. Rank: also write the pooled groups.
        pub features: u32,
        /// Refine: apply the residuals.
        pub residuals: u32,
        /// Refine: the drawn splats' in-surface scales times this (`base::widen`).
        pub widen: f32,
        /// Upscale: the fine level's size / 128.
        pub factor: u32,
    }
}

const CONSTANTS: &[(&str, f32)] = &[
    ("SH_C0", SH_C0),
    ("SPREAD", SPREAD),
    ("THICKNESS", THICKNESS),
    ("OPACITY", OPACITY),
];

pub const ROOT: Shader =
    wgsl_shader!("splat/root.wgsl", [SplatParams], f16: false, subgroups: false);
pub const UNIT: Shader =
    wgsl_shader!("splat/unit.wgsl", [SplatParams], f16: false, subgroups: false);
pub const DISTANCES: Shader =
    wgsl_shader!("splat/distances.wgsl", [SplatParams], f16: false, subgroups: false);
pub const SELECT_HISTOGRAM: Shader =
    wgsl_shader!("splat/select_histogram.wgsl", [SplatParams], f16: false, subgroups: false);
pub const SELECT_PICK: Shader =
    wgsl_shader!("splat/select_pick.wgsl", [SplatParams], f16: false, subgroups: false);
pub const BASE: Shader =
    wgsl_shader!("splat/base.wgsl", [SplatParams, GpuSplat], elem).with_constants(CONSTANTS);
pub const CODES: Shader =
    wgsl_shader!("splat/codes.wgsl", [SplatParams], f16: false, subgroups: false);
/// The most points whose ranks [`RANK_SERIAL`] sorts; more take [`RANK_TILED`] on any
/// adapter. Lavapipe silently ends every loop of an invocation once all of them together
/// have run 65,535 iterations, and the serial sort runs 3 + 6 · 1,024 + 7 · n (three
/// passes of two 1,024-digit loops and two over the points, then the inverse order). The
/// Witch's 128² map has 4,414 points, the Knight's 5,014; a map full of points 16,384.
pub const RANK_SERIAL_MAX_POINTS: usize = 8_000;
const _: () = assert!(3 + 6 * 1024 + 7 * RANK_SERIAL_MAX_POINTS < 65_535);
/// The ranks for CPU drivers: one invocation radix-sorts a curve's codes.
pub const RANK_SERIAL: Shader =
    wgsl_shader!("splat/rank_serial.wgsl", [SplatParams], f16: false, subgroups: false);
/// The ranks for GPUs: every thread counts against the codes a workgroup-shared tile at a
/// time.
pub const RANK_TILED: Shader =
    wgsl_shader!("splat/rank_tiled.wgsl", [SplatParams], f16: false, subgroups: false);
pub const POOLED: Shader =
    wgsl_shader!("splat/pooled.wgsl", [SplatParams], f16: false, subgroups: false);
pub const ROWS_TO_F32: Shader = wgsl_shader!("splat/rows_to_f32.wgsl", [SplatParams], elem);
/// The fine level's rows from the coarse points' rows (the fine level's upscale).
pub const UPSCALE_POINTS: Shader =
    wgsl_shader!("splat/upscale_points.wgsl", [SplatParams], f16: false, subgroups: false)
        .with_uints(&[("COARSE", COARSE as u32)]);
pub const REFINE: Shader =
    wgsl_shader!("splat/refine.wgsl", [SplatParams, GpuSplat], f16: false, subgroups: false)
        .with_constants(CONSTANTS);

/// Every shader of the GPU splat frame.
pub const ALL: &[Shader] = &[
    ROOT,
    UNIT,
    DISTANCES,
    SELECT_HISTOGRAM,
    SELECT_PICK,
    BASE,
    CODES,
    RANK_SERIAL,
    RANK_TILED,
    POOLED,
    ROWS_TO_F32,
    UPSCALE_POINTS,
    REFINE,
];

/// The static layout and working buffers of one map level.
struct Level {
    size: usize,
    count: usize,
    pixels: wgpu::Buffer,
    neighbours: wgpu::Buffer,
    pairs: wgpu::Buffer,
    pair_count: usize,
    colors: wgpu::Buffer,
    distances: wgpu::Buffer,
    histogram: wgpu::Buffer,
    select: wgpu::Buffer,
    /// Root xyz (coarse) and the median spacing in [3].
    frame: wgpu::Buffer,
    base: wgpu::Buffer,
}

impl Level {
    fn new(
        gpu: &GpuContext,
        size: usize,
        pixels: &[u32],
        colors: &[Vec3],
    ) -> Result<Self, GpuError> {
        let neighbours = base::neighbours(pixels, size);
        let packed: Vec<[i32; 4]> = neighbours
            .iter()
            .map(|n| n.map(|k| k.map_or(-1, |k| k as i32)))
            .collect();
        let pairs: Vec<[u32; 2]> = [0, 2]
            .iter()
            .flat_map(|&k| {
                neighbours
                    .iter()
                    .enumerate()
                    .filter_map(move |(i, n)| n[k].map(|n| [i as u32, n]))
            })
            .collect();
        let colors: Vec<f32> = colors.iter().flat_map(|c| c.to_array()).collect();
        let none = wgpu::BufferUsages::empty();
        let count = pixels.len();
        Ok(Self {
            size,
            count,
            pixels: gpu.storage_buffer_init("splat.pixels", bytemuck::cast_slice(pixels), none)?,
            neighbours: gpu.storage_buffer_init(
                "splat.neighbours",
                bytemuck::cast_slice(&packed),
                none,
            )?,
            pairs: gpu.storage_buffer_init("splat.pairs", bytemuck::cast_slice(&pairs), none)?,
            pair_count: pairs.len(),
            colors: gpu.storage_buffer_init("splat.colors", bytemuck::cast_slice(&colors), none)?,
            distances: gpu.storage_buffer(
                "splat.distances",
                4 * pairs.len().max(1) as u64,
                none,
            )?,
            histogram: gpu.storage_buffer("splat.histogram", 4 * BINS, none)?,
            select: gpu.storage_buffer("splat.select", 16, none)?,
            frame: gpu.storage_buffer("splat.frame", 16, wgpu::BufferUsages::COPY_SRC)?,
            base: gpu.storage_buffer(
                "splat.base",
                (count.max(1) * std::mem::size_of::<GpuSplat>()) as u64,
                wgpu::BufferUsages::COPY_SRC,
            )?,
        })
    }

    fn params(&self) -> SplatParams {
        SplatParams {
            points: self.count as u32,
            waist: 0,
            scale: 1.0,
            pairs: self.pair_count as u32,
            mid: (self.pair_count / 2) as u32,
            round: 0,
            first: 0,
            channels: 3,
            plane: (self.size * self.size) as u32,
            stride: 1,
            curve: 0,
            bound: 0.0,
            features: 0,
            residuals: 0,
            widen: 1.0,
            factor: 1,
        }
    }

    /// The median spacing of `points` into frame[3], then the base splats (and features).
    fn record_base(
        &self,
        b: &mut Builder,
        points: &wgpu::Buffer,
        unit: &wgpu::Buffer,
        features: Option<&wgpu::Buffer>,
    ) {
        let mut p = self.params();
        let one = Grid { x: 1, y: 1 };
        let pairs = b.grid(self.pair_count);
        b.dispatch(
            &DISTANCES,
            &p,
            &[points, &self.pairs, &self.distances],
            pairs,
        );
        for pass in 0..2 {
            p.round = pass;
            b.dispatch(
                &SELECT_HISTOGRAM,
                &p,
                &[&self.distances, &self.select, &self.histogram],
                pairs,
            );
            b.dispatch(
                &SELECT_PICK,
                &p,
                &[&self.histogram, &self.select, &self.frame],
                one,
            );
        }
        p.features = u32::from(features.is_some());
        let grid = b.grid(self.count);
        b.dispatch(
            &BASE,
            &p,
            &[
                points,
                &self.neighbours,
                &self.colors,
                &self.frame,
                unit,
                &self.base,
                features.unwrap_or(&self.distances),
            ],
            grid,
        );
    }
}

/// The fine level's extra buffers (splat level above 128).
struct Fine {
    level: Level,
    /// The 128² map's point index per pixel, -1 on the background.
    index: wgpu::Buffer,
    points: wgpu::Buffer,
    residuals: wgpu::Buffer,
}

/// The refiner's side of the coarse level.
struct Refining {
    bound: f32,
    stride: usize,
    features: wgpu::Buffer,
    codes: wgpu::Buffer,
    /// Whether the ranks are counted by `rank_tiled.wgsl` (GPUs, and maps of more than
    /// [`RANK_SERIAL_MAX_POINTS`] points) rather than sorted by `rank_serial.wgsl`.
    tiled_rank: bool,
    /// The orders of the points and of the pooled points, and each point's group.
    orders: SerialOrders,
    pooled: wgpu::Buffer,
    pooled_codes: wgpu::Buffer,
    residuals: wgpu::Buffer,
}

impl Refining {
    /// Records one serialisation order from `codes` by `p.curve`, with each point's group
    /// where `p.features` is set.
    fn record_rank(
        &self,
        b: &mut Builder,
        p: &SplatParams,
        codes: &wgpu::Buffer,
        order: &Permutation,
        grid: Grid,
    ) {
        let bound = [
            codes,
            order.sort.buffer(),
            order.unsort.buffer(),
            self.orders.groups.buffer(),
        ];
        if self.tiled_rank {
            b.dispatch(&RANK_TILED, p, &bound, grid);
        } else {
            b.dispatch(&RANK_SERIAL, p, &bound, Grid { x: 1, y: 1 });
        }
    }
}

/// The GPU splats of a frame at one splat level (see the module header).
pub struct SplatFrame {
    scale: f32,
    waist: wgpu::Buffer,
    waist_count: usize,
    coarse: Level,
    unit: wgpu::Buffer,
    refining: Option<Refining>,
    fine: Option<Fine>,
    /// The rasterizer's input: [`SplatFrame::count`] [`GpuSplat`]s.
    pub splats: wgpu::Buffer,
}

/// What the refiner needs from the coarse level, on the GPU.
pub struct RefinerInputs<'a> {
    /// [N, 11] features in the engine's precision.
    pub features: &'a wgpu::Buffer,
    /// The four serialisation orders of the points and of the pooled points, and each
    /// point's pooled group.
    pub orders: &'a SerialOrders,
    pub points: usize,
}

impl SplatFrame {
    /// The buffers of splats at map size `level` (128, 256, 512 or 1024) for the 128²
    /// foreground `pixels` with linear `colors`, `waist` point indices and normalisation
    /// `scale`; `refiner`: (mean bound in normalised units, pooling stride) when the
    /// refiner runs, its features stored in `precision`. `for_gpus` picks the kernels
    /// written for GPUs where the splat stage has two (the rank).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gpu: &GpuContext,
        pixels: &[u32],
        waist: &[u32],
        colors: &[Vec3],
        scale: f32,
        level: usize,
        refiner: Option<(f32, usize)>,
        precision: Precision,
        for_gpus: bool,
    ) -> Result<Self, GpuError> {
        assert!(
            level >= COARSE && level.is_multiple_of(COARSE),
            "splat level {level}"
        );
        let n = pixels.len();
        let none = wgpu::BufferUsages::empty();
        let coarse = Level::new(gpu, COARSE, pixels, colors)?;
        let orders = |label: &str, count: usize| -> Result<Vec<Permutation>, GpuError> {
            (0..ORDERS.len())
                .map(|_| Permutation::storage(gpu, label, count))
                .collect()
        };
        let refining = match refiner {
            Some((bound, stride)) => {
                let pooled = n.div_ceil(stride);
                let elem = precision.bytes() as u64;
                Some(Refining {
                    bound: bound / scale,
                    stride,
                    features: gpu.storage_buffer(
                        "splat.features",
                        // Whole 16-byte texels: the refiner may read it as texels.
                        (elem * (FEATURES * n.max(1)) as u64).next_multiple_of(16),
                        wgpu::BufferUsages::COPY_SRC,
                    )?,
                    codes: gpu.storage_buffer(
                        "splat.codes",
                        16 * n.max(1).next_multiple_of(4) as u64,
                        wgpu::BufferUsages::COPY_SRC,
                    )?,
                    tiled_rank: for_gpus || n > RANK_SERIAL_MAX_POINTS,
                    orders: SerialOrders {
                        fine: orders("splat.order", n)?,
                        coarse: orders("splat.pooled_order", pooled)?,
                        groups: Indices::storage(gpu, "splat.groups", n)?,
                    },
                    pooled: gpu.storage_buffer("splat.pooled", 12 * pooled.max(1) as u64, none)?,
                    pooled_codes: gpu.storage_buffer(
                        "splat.pooled_codes",
                        16 * pooled.max(1).next_multiple_of(4) as u64,
                        wgpu::BufferUsages::COPY_SRC,
                    )?,
                    residuals: gpu.storage_buffer(
                        "splat.residuals",
                        4 * (RESIDUALS * n.max(1)) as u64,
                        wgpu::BufferUsages::COPY_SRC,
                    )?,
                })
            }
            None => None,
        };
        let fine = if level > COARSE {
            let plane = COARSE * COARSE;
            let mut mask = vec![0.0f32; plane];
            let mut index = vec![-1i32; plane];
            for (i, &p) in pixels.iter().enumerate() {
                mask[p as usize] = 1.0;
                index[p as usize] = i as i32;
            }
            let mut color_map = vec![0.0f32; 3 * plane];
            for (&p, c) in pixels.iter().zip(colors) {
                for k in 0..3 {
                    color_map[k * plane + p as usize] = c[k];
                }
            }
            // The layout comes from the GPU kernel itself (as the frame's upscales do), so
            // a pixel on the 0.25 mask threshold is foreground on both.
            let mut pipelines = crate::gpu::kernel::PipelineCache::default();
            let (up_colors, up_mask) = super::upscale::run(
                gpu,
                &mut pipelines,
                &color_map,
                &mask,
                COARSE,
                COARSE,
                level / COARSE,
            )?;
            let fine_pixels: Vec<u32> = (0..level * level)
                .filter(|&i| up_mask[i] > 0.0)
                .map(|i| i as u32)
                .collect();
            let fine_plane = level * level;
            let fine_colors: Vec<Vec3> = fine_pixels
                .iter()
                .map(|&p| {
                    let p = p as usize;
                    Vec3::new(
                        up_colors[p],
                        up_colors[fine_plane + p],
                        up_colors[2 * fine_plane + p],
                    )
                })
                .collect();
            let level = Level::new(gpu, level, &fine_pixels, &fine_colors)?;
            let count = level.count.max(1) as u64;
            Some(Fine {
                index: gpu.storage_buffer_init(
                    "splat.index",
                    bytemuck::cast_slice(&index),
                    none,
                )?,
                points: gpu.storage_buffer("splat.fine_points", 12 * count, none)?,
                residuals: gpu.storage_buffer(
                    "splat.fine_residuals",
                    4 * RESIDUALS as u64 * count,
                    none,
                )?,
                level,
            })
        } else {
            None
        };
        let count = fine.as_ref().map_or(n, |f| f.level.count);
        Ok(Self {
            scale,
            waist: gpu.storage_buffer_init("splat.waist", bytemuck::cast_slice(waist), none)?,
            waist_count: waist.len(),
            unit: gpu.storage_buffer(
                "splat.unit",
                12 * n.max(1) as u64,
                wgpu::BufferUsages::COPY_SRC,
            )?,
            splats: gpu.storage_buffer(
                "splats",
                (count.max(1) * std::mem::size_of::<GpuSplat>()) as u64,
                wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            )?,
            coarse,
            refining,
            fine,
        })
    }

    /// Splats per frame.
    pub fn count(&self) -> usize {
        self.fine
            .as_ref()
            .map_or(self.coarse.count, |f| f.level.count)
    }

    /// The splat level (map size).
    pub fn level(&self) -> usize {
        self.fine.as_ref().map_or(COARSE, |f| f.level.size)
    }

    /// Whether the refiner's inputs are made (and its residuals expected).
    pub fn refines(&self) -> bool {
        self.refining.is_some()
    }

    /// Records the 128² stage from the frame's world points (3N f32): root, normalised
    /// points, median spacing, base splats and, when refining, the refiner's features and
    /// serialisation orders (returned for the refiner).
    pub fn record_coarse(
        &self,
        b: &mut Builder,
        points: &wgpu::Buffer,
    ) -> Option<RefinerInputs<'_>> {
        let c = &self.coarse;
        let mut p = c.params();
        p.waist = self.waist_count as u32;
        p.scale = self.scale;
        b.dispatch(
            &ROOT,
            &p,
            &[points, &self.waist, &c.frame],
            Grid { x: 1, y: 1 },
        );
        let grid = b.grid(3 * c.count);
        b.dispatch(&UNIT, &p, &[points, &c.frame, &self.unit], grid);
        let r = self.refining.as_ref();
        c.record_base(b, points, &self.unit, r.map(|r| &r.features));
        let r = r?;
        let n = c.count;
        let pooled = n.div_ceil(r.stride);
        p.stride = r.stride as u32;
        let grid = b.grid(n);
        b.dispatch(&CODES, &p, &[&self.unit, &r.codes], grid);
        for (curve, order) in r.orders.fine.iter().enumerate() {
            p.curve = curve as u32;
            p.features = u32::from(curve == 0);
            r.record_rank(b, &p, &r.codes, order, grid);
        }
        let grid = b.grid(pooled);
        b.dispatch(
            &POOLED,
            &p,
            &[&self.unit, r.orders.fine[0].sort.buffer(), &r.pooled],
            grid,
        );
        let mut q = p;
        q.points = pooled as u32;
        q.features = 0;
        b.dispatch(&CODES, &q, &[&r.pooled, &r.pooled_codes], grid);
        for (curve, order) in r.orders.coarse.iter().enumerate() {
            q.curve = curve as u32;
            r.record_rank(b, &q, &r.pooled_codes, order, grid);
        }
        Some(RefinerInputs {
            features: &r.features,
            orders: &r.orders,
            points: n,
        })
    }

    /// Records the drawn splats into [`SplatFrame::splats`]: the refined 128² splats, or
    /// the upscale to the splat level and its splats; `residuals` is the refiner's [N, 14]
    /// output (stored in the engine's precision) when refining.
    pub fn record_finish(
        &self,
        b: &mut Builder,
        points: &wgpu::Buffer,
        residuals: Option<&wgpu::Buffer>,
    ) {
        let c = &self.coarse;
        let mut p = c.params();
        let rows = match (residuals, &self.refining) {
            (Some(raw), Some(r)) => {
                p.bound = r.bound;
                p.channels = RESIDUALS as u32;
                let grid = b.grid(RESIDUALS * c.count);
                b.dispatch(&ROWS_TO_F32, &p, &[raw, &r.residuals], grid);
                Some(&r.residuals)
            }
            _ => None,
        };
        let Some(f) = &self.fine else {
            p.residuals = u32::from(rows.is_some());
            let grid = b.grid(c.count);
            b.dispatch(
                &REFINE,
                &p,
                &[&c.base, rows.unwrap_or(&c.distances), &self.splats],
                grid,
            );
            return;
        };
        // Positions, then the residuals, at the fine points' pixels.
        let mut fp = f.level.params();
        fp.factor = (f.level.size / COARSE) as u32;
        let fine_grid = b.grid(f.level.count);
        b.dispatch(
            &UPSCALE_POINTS,
            &fp,
            &[points, &f.index, &f.level.pixels, &f.points],
            fine_grid,
        );
        if let Some(rows) = rows {
            fp.channels = RESIDUALS as u32;
            b.dispatch(
                &UPSCALE_POINTS,
                &fp,
                &[rows, &f.index, &f.level.pixels, &f.residuals],
                fine_grid,
            );
        }
        f.level.record_base(b, &f.points, &self.unit, None);
        let mut p = f.level.params();
        p.residuals = u32::from(rows.is_some());
        p.bound = self.refining.as_ref().map_or(0.0, |r| r.bound);
        p.widen = super::base::widen(f.level.size);
        b.dispatch(
            &REFINE,
            &p,
            &[&f.level.base, &f.residuals, &self.splats],
            fine_grid,
        );
    }
}
