//! Ops that move values: nearest upsampling, permutes (with an add), concatenation,
//! row gathers and segment means.

use super::norm::GroupNormParams;
use super::{Indices, Kernels, Recorder};
use crate::gpu::shaders::Shader;
use crate::gpu::texels::Texels;
use crate::gpu::{Bound, GpuError};
use crate::gpu_struct;
use crate::nn::Tensor;
use crate::wgsl_shader as shader;

pub const UPSAMPLE_NEAREST: Shader =
    shader!("nn/layout/upsample_nearest.wgsl", [UpsampleParams], elem);
pub const PERMUTE: Shader = shader!("nn/layout/permute.wgsl", [PermuteParams], elem);
/// `a + permute(x)`: the attention layers' residual.
pub const CONCAT: Shader = shader!("nn/layout/concat.wgsl", [ConcatParams], elem);
pub const GATHER: Shader = shader!("nn/layout/gather.wgsl", [GatherParams], elem);
/// `GATHER` for CPU drivers: four values a texel.
pub const GATHER_CPU: Shader = shader!("nn/layout/gather_cpu.wgsl", [GatherParams], elem);
pub const SEGMENT_MEAN: Shader = shader!("nn/layout/segment_mean.wgsl", [SegmentParams], elem);

/// Every shader of this file (see [`super::shaders`]).
pub const SHADERS: &[Shader] = &[
    UPSAMPLE_NEAREST,
    PERMUTE,
    CONCAT,
    GATHER,
    GATHER_CPU,
    SEGMENT_MEAN,
];

gpu_struct! {
    /// Shapes of a nearest ×2 upsampling: `planes` = batch × channels.
    pub struct UpsampleParams {
        pub planes: u32,
        pub h_in: u32,
        pub w_in: u32,
        pub reserved: u32,
    }
}

gpu_struct! {
    /// A 4-D permutation (output axis k is input axis `perm[k]` of `shape`) and what is
    /// added to it, each sum rounded to Elem as add.wgsl rounds: with `has_a`, `a + `
    /// the permuted value; with `has_rows`, plus `rows[rows_offset + i % rows_len]` (a
    /// trailing broadcast, e.g. frame positions); with `has_bias`, plus a row of an
    /// action table as [`ActionBiasParams`] lays it over NCHW images (`hw`, `channels`,
    /// `frames` images per sample).
    pub struct PermuteParams {
        pub shape: [u32; 4],
        pub perm: [u32; 4],
        pub has_a: u32,
        pub has_rows: u32,
        pub rows_offset: u32,
        pub rows_len: u32,
        pub has_bias: u32,
        pub hw: u32,
        pub channels: u32,
        pub frames: u32,
    }
}

gpu_struct! {
    /// Concatenation of [outer, a_inner] and [outer, b_inner] rows.
    pub struct ConcatParams {
        pub outer: u32,
        pub a_inner: u32,
        pub b_inner: u32,
        pub reserved: u32,
    }
}

gpu_struct! {
    pub struct GatherParams {
        pub rows: u32,
        pub width: u32,
        pub reserved0: u32,
        pub reserved1: u32,
    }
}

gpu_struct! {
    pub struct SegmentParams {
        pub rows: u32,
        pub width: u32,
        pub stride: u32,
        pub reserved: u32,
    }
}

impl Recorder<'_> {
    /// Nearest-neighbour ×2 upsampling of an NCHW tensor.
    pub fn upsample_nearest2x(&mut self, x: &Tensor) -> Result<Tensor, GpuError> {
        let [n, c, h, w] = x.shape[..] else {
            panic!("upsample input must be NCHW, got {:?}", x.shape)
        };
        let y = self.output("upsample.y", &[n, c, 2 * h, 2 * w])?;
        let params = UpsampleParams {
            planes: (n * c) as u32,
            h_in: h as u32,
            w_in: w as u32,
            reserved: 0,
        };
        let grid = self.grid(y.len());
        self.launch(&UPSAMPLE_NEAREST, &params, &[x, &y], grid);
        Ok(y)
    }

    /// A permutation of the axes of `x` seen as 4-D `shape` (output axis k is input axis
    /// `perm[k]`).
    pub fn permute(
        &mut self,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, None, None, None)
    }

    /// The permutation of `x` plus the values `part` of `rows` repeated over the leading
    /// axes (as [`Recorder::add_part`] with [`Broadcast::Trailing`] after the permute),
    /// in one dispatch.
    pub fn permute_add_rows(
        &mut self,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
        rows: &Tensor,
        part: std::ops::Range<usize>,
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, None, Some((rows, part)), None)
    }

    /// `a + permute(x)` in one dispatch: `x` viewed as `shape`, permuted as
    /// [`Recorder::permute`] does, must have `a`'s size; the result has `a`'s shape.
    pub fn add_permuted(
        &mut self,
        a: &Tensor,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, Some(a), None, None)
    }

    /// [`Recorder::add_permuted`] onto NCHW images `a`, then plus `table[ids[sample]]`
    /// per channel as [`Recorder::add_action_bias`] adds it (`frames` images per sample)
    /// — one pass, the same two roundings as the two ops.
    pub fn add_permuted_bias(
        &mut self,
        a: &Tensor,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
        bias: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        self.permute_plus(x, shape, perm, Some(a), None, bias)
    }

    /// permute.wgsl with what is added to the permuted values (see [`PermuteParams`]).
    pub(super) fn permute_plus(
        &mut self,
        x: &Tensor,
        shape: [usize; 4],
        perm: [usize; 4],
        a: Option<&Tensor>,
        rows: Option<(&Tensor, std::ops::Range<usize>)>,
        bias: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        assert_eq!(
            shape.iter().product::<usize>(),
            x.len(),
            "permute shape {shape:?} for {:?}",
            x.shape
        );
        let out_shape = match a {
            Some(a) => {
                assert_eq!(
                    a.len(),
                    x.len(),
                    "add_permuted: {:?} onto {:?}",
                    x.shape,
                    a.shape
                );
                a.shape.clone()
            }
            None => perm.map(|k| shape[k]).to_vec(),
        };
        if let Some((rows, part)) = &rows {
            assert!(
                !part.is_empty() && part.end <= rows.len() && x.len().is_multiple_of(part.len()),
                "cannot broadcast values {part:?} of {:?} onto {out_shape:?}",
                rows.shape
            );
        }
        let (hw, channels, frames) = match bias {
            Some((table, ids, frames)) => {
                let [nf, c, h, w] = out_shape[..] else {
                    panic!("NCHW expected, got {out_shape:?}")
                };
                assert_eq!(table.shape[1], c, "action bias table {:?}", table.shape);
                assert_eq!(nf, ids.len * frames, "{} ids for {nf} images", ids.len);
                (h * w, c, frames)
            }
            None => (1, 1, 1),
        };
        let y = self.output("permute.y", &out_shape)?;
        let part = rows.as_ref().map_or(0..1, |(_, part)| part.clone());
        let params = PermuteParams {
            shape: shape.map(|s| s as u32),
            perm: perm.map(|k| k as u32),
            has_a: u32::from(a.is_some()),
            has_rows: u32::from(rows.is_some()),
            rows_offset: part.start as u32,
            rows_len: part.len() as u32,
            has_bias: u32::from(bias.is_some()),
            hw: hw as u32,
            channels: channels as u32,
            frames: frames as u32,
        };
        // Absent addends keep their bindings; `x` stands in (unread).
        let a = a.unwrap_or(x);
        let rows = rows.map_or(x, |(rows, _)| rows);
        let (table, ids) = match bias {
            Some((table, ids, _)) => (table, &ids.buffer),
            None => (x, &x.buffer),
        };
        self.check(&[x, a, rows, table, &y]);
        let grid = self.grid(y.len());
        let buffers = [
            &x.buffer,
            &a.buffer,
            &rows.buffer,
            &table.buffer,
            ids,
            &y.buffer,
        ];
        self.steps.dispatch(&PERMUTE, &params, &buffers, grid);
        Ok(y)
    }

    /// `a` and `b` joined along `axis`; all other axes must agree. For GPUs two buffer
    /// copies per outer index (a copy command, not a dispatch) where the byte ranges are
    /// aligned, else `concat.wgsl`.
    pub fn concat(&mut self, a: &Tensor, b: &Tensor, axis: usize) -> Result<Tensor, GpuError> {
        assert!(
            a.shape.len() == b.shape.len()
                && a.shape
                    .iter()
                    .zip(&b.shape)
                    .enumerate()
                    .all(|(k, (x, y))| k == axis || x == y),
            "cannot concatenate {:?} and {:?} along axis {axis}",
            a.shape,
            b.shape
        );
        let outer: usize = a.shape[..axis].iter().product();
        let mut shape = a.shape.clone();
        shape[axis] += b.shape[axis];
        let y = self.output("concat.y", &shape)?;
        let params = ConcatParams {
            outer: outer as u32,
            a_inner: (a.len() / outer) as u32,
            b_inner: (b.len() / outer) as u32,
            reserved: 0,
        };
        // For GPUs two buffer copies per outer index where the byte ranges allow
        // (copies are aligned to 4 bytes): a copy command, not a dispatch.
        let bytes = self.precision().bytes();
        let (a_bytes, b_bytes) = (a.len() / outer * bytes, b.len() / outer * bytes);
        if self.kernels == Kernels::Gpu && a_bytes % 4 == 0 && b_bytes % 4 == 0 {
            self.check(&[a, b, &y]);
            for o in 0..outer {
                let at = (o * (a_bytes + b_bytes)) as u64;
                let (a_from, b_from) = ((o * a_bytes) as u64, (o * b_bytes) as u64);
                let steps = &mut self.steps;
                steps.copy(&a.buffer, a_from, &y.buffer, at, a_bytes as u64);
                steps.copy(
                    &b.buffer,
                    b_from,
                    &y.buffer,
                    at + a_bytes as u64,
                    b_bytes as u64,
                );
            }
            return Ok(y);
        }
        let grid = self.grid(y.len());
        self.launch(&CONCAT, &params, &[a, b, &y], grid);
        Ok(y)
    }

    /// The concatenation of NCHW `a` and `b` along the channels held only as texels,
    /// copied from the two (no kernel), for a ResBlock that reads it only through its
    /// first group norm (`groups`) and its 1×1 skip ([`Recorder::group_norm_of_texels`],
    /// [`Recorder::conv1x1_of_texels`]). None where those would not read texels: other
    /// kernel variants, planes of pixels not a multiple of 4, groups too large for the
    /// serial norm.
    pub fn concat_texels(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        groups: usize,
    ) -> Result<Option<(Texels, [usize; 4])>, GpuError> {
        let (&[n, ca, h, w], &[nb, cb, hb, wb]) = (&a.shape[..], &b.shape[..]) else {
            panic!("NCHW concatenation of {:?} and {:?}", a.shape, b.shape)
        };
        assert_eq!(
            (n, h, w),
            (nb, hb, wb),
            "concatenating {:?} and {:?}",
            a.shape,
            b.shape
        );
        let c = ca + cb;
        let norm = GroupNormParams::nchw([n, c, h, w], groups, true);
        if !(self.kernels == Kernels::Cpu && (h * w).is_multiple_of(4) && norm.serial()) {
            return Ok(None);
        }
        self.check(&[a, b]);
        let texels = Texels::new(self.gpu, "concat texels", n * c * h * w, self.precision())?;
        let (a_texels, b_texels) = ((ca * h * w / 4) as u32, (cb * h * w / 4) as u32);
        let texel_bytes = u64::from(texels.texel_bytes());
        for image in 0..n as u32 {
            let first = image * (a_texels + b_texels);
            let a_offset = u64::from(image * a_texels) * texel_bytes;
            let b_offset = u64::from(image * b_texels) * texel_bytes;
            self.steps
                .copy_range_to_texels(&a.buffer, a_offset, &texels, first, a_texels);
            self.steps.copy_range_to_texels(
                &b.buffer,
                b_offset,
                &texels,
                first + a_texels,
                b_texels,
            );
        }
        Ok(Some((texels, [n, c, h, w])))
    }

    /// Host row indices uploaded for [`Recorder::gather`].
    pub fn indices(&self, label: &str, values: &[u32]) -> Result<Indices, GpuError> {
        Indices::upload(self.gpu, label, values)
    }

    /// `y[i, :] = x[index[i], :]` for a [R, D] `x`; the caller keeps indices below R.
    pub fn gather(&mut self, x: &Tensor, index: &Indices) -> Result<Tensor, GpuError> {
        let [_, width] = x.shape[..] else {
            panic!("gather needs a [rows, width] tensor, got {:?}", x.shape)
        };
        self.check(&[x]);
        let y = self.output("gather.y", &[index.len, width])?;
        let params = GatherParams {
            rows: index.len as u32,
            width: width as u32,
            reserved0: 0,
            reserved1: 0,
        };
        if self.kernels == Kernels::Cpu && width.is_multiple_of(4) {
            // Four values a texel of x.
            let input = self.texels(x)?;
            let grid = self.grid(y.len() / 4);
            let bound = [
                Bound::Buffer(&index.buffer),
                Bound::Texels(&input),
                Bound::Buffer(&y.buffer),
            ];
            self.steps
                .dispatch_bound(&GATHER_CPU, &params, &bound, grid);
            return Ok(y);
        }
        let grid = self.grid(y.len());
        self.dispatch(
            &GATHER,
            &params,
            &[&index.buffer, &x.buffer, &y.buffer],
            grid,
        );
        Ok(y)
    }

    /// The mean of each run of `stride` consecutive rows of a [R, D] `x` (the last run
    /// may be shorter): [ceil(R / stride), D].
    pub fn segment_mean(&mut self, x: &Tensor, stride: usize) -> Result<Tensor, GpuError> {
        let [rows, width] = x.shape[..] else {
            panic!(
                "segment mean needs a [rows, width] tensor, got {:?}",
                x.shape
            )
        };
        let y = self.output("segment_mean.y", &[rows.div_ceil(stride), width])?;
        let params = SegmentParams {
            rows: rows as u32,
            width: width as u32,
            stride: stride as u32,
            reserved: 0,
        };
        let grid = self.grid(y.len());
        self.launch(&SEGMENT_MEAN, &params, &[x, &y], grid);
        Ok(y)
    }
}
