//! Multi-head softmax attention (causal or not, over a cached prefix, in runs of rows)
//! and a temporal layer's projection and attention for one new frame, in every
//! [`Kernels`] variant.

use super::{Kernels, Recorder};
use crate::gpu::shaders::Shader;
use crate::gpu::{Bound, GpuError};
use crate::gpu_struct;
use crate::nn::Tensor;
use crate::wgsl_shader as shader;

pub const ATTENTION: Shader = shader!("nn/attention/attention.wgsl", [AttentionParams], elem)
    .with_uints(&[("MAX_HEAD_SIZE", MAX_HEAD_SIZE as u32)]);
/// Attention for GPUs: a workgroup per query, its threads splitting the keys.
pub const ATTENTION_SPLIT: Shader =
    shader!("nn/attention/attention_split.wgsl", [AttentionParams], elem)
        .with_uints(&[("MAX_HEAD_SIZE", MAX_HEAD_SIZE as u32)]);
/// Attention for GPUs over sequences of many queries: a workgroup per block of
/// queries, keys and values loaded into workgroup memory a chunk at a time.
pub const ATTENTION_TILED: Shader =
    shader!("nn/attention/attention_tiled.wgsl", [AttentionParams], elem)
        .with_uints(&[("TILE_HEAD", TILE_HEAD_SIZE as u32)]);
/// Attention for CPU drivers: heads of at most 32 values in named vec4 registers.
pub const ATTENTION_CPU: Shader =
    shader!("nn/attention/attention_cpu.wgsl", [AttentionParams], elem);
/// A temporal layer's projection and attention for one new frame, for GPUs.
pub const TEMPORAL_NEXT_SPLIT: Shader = shader!(
    "nn/attention/temporal_next_split.wgsl",
    [AttentionParams],
    elem
)
.with_uints(&[("MAX_HEAD_SIZE", MAX_HEAD_SIZE as u32)]);
/// A temporal layer's projection and attention for one new frame, for CPU drivers.
pub const TEMPORAL_NEXT: Shader =
    shader!("nn/attention/temporal_next.wgsl", [AttentionParams], elem);

/// Every shader of this file (see [`super::shaders`]).
pub const SHADERS: &[Shader] = &[
    ATTENTION,
    ATTENTION_SPLIT,
    ATTENTION_TILED,
    ATTENTION_CPU,
    TEMPORAL_NEXT_SPLIT,
    TEMPORAL_NEXT,
];

gpu_struct! {
    /// Multi-head attention over `sequences` independent sequences (see attention.wgsl).
    pub struct AttentionParams {
        pub sequences: u32,
        pub heads: u32,
        pub queries: u32,
        pub keys: u32,
        pub channels: u32,
        pub q_stride: u32,
        pub q_offset: u32,
        pub kv_stride: u32,
        pub k_offset: u32,
        pub v_offset: u32,
        pub causal: u32,
        /// Consecutive sequences that read the same keys and values.
        pub kv_share: u32,
        /// The first `prefix_keys` of each sequence's `keys` come from a second buffer
        /// (rows [sequence, prefix_keys] of the same stride and offsets), the rest from
        /// `kv` (rows [sequence, keys - prefix_keys]): a cache and the new rows need no
        /// concatenation. 0: all from `kv`.
        pub prefix_keys: u32,
        /// Self-attention within consecutive runs of `queries` rows that stops at row
        /// `rows` (the last run shorter: its queries and keys end there) and writes
        /// [rows, channels]; 0: every run whole.
        pub rows: u32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

/// The largest attention head the attention kernel holds in registers.
pub const MAX_HEAD_SIZE: usize = 64;

/// The largest head `attention_tiled.wgsl` takes (its loops over a head are this long).
pub const TILE_HEAD_SIZE: usize = 32;

/// The fewest queries a sequence has for [`Recorder::attention_after`] to give GPUs
/// `attention_tiled.wgsl` (a thread per query, the keys loaded once per block of
/// queries) rather than `attention_split.wgsl` (a workgroup per query): the refiner's
/// patches and the UNet's spatial attention, not the temporal layers' few frames.
const TILED_QUERIES: u32 = 16;

impl Recorder<'_> {
    /// Multi-head attention; `q` rows and `kv` rows as `params` describes; the output is
    /// [sequences, queries, channels].
    pub fn attention(
        &mut self,
        q: &Tensor,
        kv: &Tensor,
        params: AttentionParams,
    ) -> Result<Tensor, GpuError> {
        self.attention_after(q, None, kv, params)
    }

    /// A temporal layer's qkv projection of `tokens` [S, C] (one new frame of S
    /// sequences) and its attention over the cached rows `cached` (`params.prefix_keys`
    /// a sequence) and the sequence's own key: [`Recorder::linear`] then
    /// [`Recorder::attention_after`] (`params` as that takes them, one query a
    /// sequence), which the simple kernels record. For CPU drivers one dispatch
    /// (`temporal_next.wgsl`: each invocation projects its own head's q, k and v), and
    /// for GPUs one (`temporal_next_split.wgsl`: a workgroup per sequence and head),
    /// each equal bit for bit to its variant's separate ops. `weight` is constant.
    pub fn temporal_next(
        &mut self,
        tokens: &Tensor,
        layer: (&Tensor, &Tensor),
        cached: &Tensor,
        params: AttentionParams,
    ) -> Result<Tensor, GpuError> {
        let (weight, bias) = layer;
        let c = params.channels as usize;
        let head = c / params.heads as usize;
        let fused = self.kernels == Kernels::Cpu
            && params.queries == 1
            && params.kv_share == 1
            && params.rows == 0
            && head <= 32
            && head.is_multiple_of(4)
            && [params.kv_stride, params.k_offset, params.v_offset]
                .iter()
                .all(|v| v % 4 == 0)
            && tokens.len() == params.sequences as usize * c
            && weight.shape == [3 * c, c];
        // For GPUs: the qkv rows as the separate linear stores them (q | k | v).
        let fused_gpu = self.kernels == Kernels::Gpu
            && params.queries == 1
            && params.kv_share == 1
            && params.rows == 0
            && params.keys == params.prefix_keys + 1
            && params.keys as usize <= crate::gpu::kernel::WORKGROUP_SIZE as usize
            && head <= MAX_HEAD_SIZE
            && (params.q_offset, params.k_offset, params.v_offset) == (0, c as u32, 2 * c as u32)
            && (params.q_stride, params.kv_stride) == (3 * c as u32, 3 * c as u32)
            && tokens.len() == params.sequences as usize * c
            && weight.shape == [3 * c, c];
        if fused_gpu {
            self.check(&[tokens, weight, bias, cached]);
            let sequences = params.sequences as usize;
            let y = self.output("temporal_next.y", &[sequences, 1, c])?;
            self.flops +=
                2 * (sequences * 3 * c * c) as u64 + 4 * (y.len() as u64) * u64::from(params.keys);
            let groups = sequences * params.heads as usize;
            let grid = self.workgroups(groups);
            self.launch(
                &TEMPORAL_NEXT_SPLIT,
                &params,
                &[tokens, weight, bias, cached, &y],
                grid,
            );
            return Ok(y);
        }
        if !fused {
            let qkv = self.linear(tokens, weight, bias, false)?;
            return self.attention_after(&qkv, Some(cached), &qkv, params);
        }
        self.check(&[tokens, weight, bias, cached]);
        let sequences = params.sequences as usize;
        let y = self.output("temporal_next.y", &[sequences, 1, c])?;
        // The FLOPs of the two ops it replaces.
        self.flops +=
            2 * (sequences * 3 * c * c) as u64 + 4 * (y.len() as u64) * u64::from(params.keys);
        let input = self.texels(tokens)?;
        let prefix = self.texels(cached)?;
        let weight = weight.constant_texels(self.gpu)?;
        let bound = [
            Bound::Texels(&input),
            Bound::Texels(weight),
            Bound::Buffer(&bias.buffer),
            Bound::Texels(&prefix),
            Bound::Buffer(&y.buffer),
        ];
        let grid = self.grid(sequences * params.heads as usize);
        self.steps
            .dispatch_bound(&TEMPORAL_NEXT, &params, &bound, grid);
        Ok(y)
    }

    /// [`Recorder::attention`] whose first `params.prefix_keys` keys of each sequence are
    /// the rows of `prefix` (e.g. a context cache) and the rest the rows of `kv`: the
    /// same keys in the same order as attention over their concatenation.
    pub fn attention_after(
        &mut self,
        q: &Tensor,
        prefix: Option<&Tensor>,
        kv: &Tensor,
        params: AttentionParams,
    ) -> Result<Tensor, GpuError> {
        assert_eq!(
            prefix.is_some(),
            params.prefix_keys > 0,
            "attention: a prefix buffer goes with prefix_keys"
        );
        assert!(
            params.prefix_keys <= params.keys,
            "attention prefix of {params:?}"
        );
        assert!(
            (params.channels / params.heads) as usize <= MAX_HEAD_SIZE,
            "attention heads of {} values (at most {MAX_HEAD_SIZE})",
            params.channels / params.heads
        );
        let shape = if params.rows > 0 {
            vec![params.rows as usize, params.channels as usize]
        } else {
            vec![
                params.sequences as usize,
                params.queries as usize,
                params.channels as usize,
            ]
        };
        let y = self.output("attention.y", &shape)?;
        // Each query row against its keys: a cut last run has fewer of both.
        let (run, c) = (params.queries as u64, params.channels as u64);
        self.flops += if params.rows > 0 {
            let (full, tail) = (params.rows as u64 / run, params.rows as u64 % run);
            4 * c * (full * run * run + tail * tail)
        } else {
            4 * (y.len() as u64) * params.keys as u64
        };
        let grid = self.grid((params.sequences * params.heads * params.queries) as usize);
        let head = params.channels / params.heads;
        let rows_in_vec4s = [
            head,
            params.q_stride,
            params.q_offset,
            params.kv_stride,
            params.k_offset,
            params.v_offset,
        ]
        .iter()
        .all(|v| v % 4 == 0);
        // The prefix binding must exist without a prefix; kv stands in (unread).
        let prefix = prefix.unwrap_or(kv);
        if self.kernels == Kernels::Cpu && head <= 32 && rows_in_vec4s {
            // q, the prefix and kv as texels (one copy of a buffer they share).
            self.check(&[q, prefix, kv]);
            let kv_texels = self.texels(kv)?;
            let same = |t: &Tensor| t.buffer == kv.buffer;
            let q_texels = if same(q) { None } else { Some(self.texels(q)?) };
            let prefix_texels = if same(prefix) {
                None
            } else {
                Some(self.texels(prefix)?)
            };
            let bound = [
                Bound::Texels(q_texels.as_ref().unwrap_or(&kv_texels)),
                Bound::Texels(prefix_texels.as_ref().unwrap_or(&kv_texels)),
                Bound::Texels(&kv_texels),
                Bound::Buffer(&y.buffer),
            ];
            // Two queries of a run per invocation (attention_cpu.wgsl).
            let pairs = params.queries.div_ceil(2);
            let grid = self.grid((params.sequences * params.heads * pairs) as usize);
            self.steps
                .dispatch_bound(&ATTENTION_CPU, &params, &bound, grid);
        } else if self.kernels == Kernels::Gpu
            && params.queries >= TILED_QUERIES
            && head as usize <= TILE_HEAD_SIZE
            && head.is_multiple_of(4)
        {
            let blocks = params.queries.div_ceil(crate::gpu::kernel::WORKGROUP_SIZE);
            let grid = self.workgroups((params.sequences * params.heads * blocks) as usize);
            self.launch(&ATTENTION_TILED, &params, &[q, prefix, kv, &y], grid);
        } else if self.kernels == Kernels::Gpu {
            // One workgroup per query (attention_split.wgsl), its threads splitting the
            // keys; a head's values are merged by its first head-size threads.
            const { assert!(MAX_HEAD_SIZE <= crate::gpu::kernel::WORKGROUP_SIZE as usize) };
            let queries = (params.sequences * params.heads * params.queries) as usize;
            let grid = self.workgroups(queries);
            self.launch(&ATTENTION_SPLIT, &params, &[q, prefix, kv, &y], grid);
        } else {
            self.launch(&ATTENTION, &params, &[q, prefix, kv, &y], grid);
        }
        Ok(y)
    }
}
