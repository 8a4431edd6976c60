//! The geometry model's kernels: each shader (WGSL in `shaders/nn/`) with the parameter
//! struct it shares with Rust (declared in `ops`); `Recorder` dispatches them.

use super::ops::{
    ActionBiasParams, AddParams, AttentionParams, AxpbyParams, ConcatParams, Conv2dParams,
    EmbeddingParams, GatherParams, GroupNormParams, LinearParams, PermuteParams, SegmentParams,
    UpsampleParams,
};
use crate::gpu::shaders::{Shader, Snippet};
use crate::wgsl_shader as shader;
use crate::wgsl_snippet as snippet;

/// `pick`: a run of values read as texels that starts anywhere in a texel.
pub const PICK: Snippet = snippet!("nn/snippets/pick.wgsl");
/// `bias_lanes`: a convolution tile's starting sums.
pub const CONV_BIAS: Snippet = snippet!("nn/snippets/conv_bias.wgsl");
/// `finish` and `store`: the 3×3 convolutions' epilogue.
pub const CONV_STORE: Snippet = snippet!("nn/snippets/conv_store.wgsl");
/// The 1×1 convolution's tile (its entry point), for the buffer and the texel forms.
pub const CONV1X1_TILE: Snippet = snippet!("nn/snippets/conv1x1_tile.wgsl");
/// `Online`, `take`, `store_online`: the CPU-driver attention's running softmax.
pub const ONLINE_SOFTMAX: Snippet = snippet!("nn/snippets/online_softmax.wgsl");

/// `texel_stats`: every CPU-driver norm's (mean, 1 / std), one summation order.
pub const TEXEL_STATS: Snippet = snippet!("nn/snippets/texel_stats.wgsl");

/// Every snippet of the model's shaders.
pub const SNIPPETS: &[Snippet] = &[
    PICK,
    CONV_BIAS,
    CONV_STORE,
    CONV1X1_TILE,
    ONLINE_SOFTMAX,
    TEXEL_STATS,
];

pub const CONV2D: Shader = shader!("nn/conv2d.wgsl", [Conv2dParams], elem);
/// The convolution in register tiles of 4 output pixels × 8 channels.
pub const CONV2D_TILED: Shader = shader!("nn/conv2d_tiled.wgsl", [Conv2dParams], elem);
/// The convolution for GPUs: a workgroup per tile of 4 pixels × 8 channels.
pub const CONV2D_SPLIT: Shader = shader!("nn/conv2d_split.wgsl", [Conv2dParams], elem);
/// The 3×3 stride-1 convolution in register tiles of 8 pixels × 8 channels, from
/// repacked f32 weights (`ops::PackedConv`).
pub const CONV3X3: Shader =
    shader!("nn/conv3x3.wgsl", [Conv2dParams], elem).with_snippets(&[CONV_BIAS, CONV_STORE]);
/// `CONV3X3` for CPU drivers: the input and the weights read as texels.
pub const CONV3X3_CPU: Shader = shader!("nn/conv3x3_cpu.wgsl", [Conv2dParams], elem)
    .with_snippets(&[PICK, CONV_BIAS, CONV_STORE, TEXEL_STATS])
    .with_uints(&[("NORM_STATS", super::ops::NORM_STATS as u32), ("NORMED", 0)]);
/// `CONV3X3_CPU` that group-normalises its input as it loads it (`Recorder::normed_conv3x3`):
/// the same file built with `NORMED` set, so the plain form carries none of it.
pub const CONV3X3_NORMED_CPU: Shader = shader!("nn/conv3x3_cpu.wgsl", [Conv2dParams], elem)
    .with_snippets(&[PICK, CONV_BIAS, CONV_STORE, TEXEL_STATS])
    .with_uints(&[("NORM_STATS", super::ops::NORM_STATS as u32), ("NORMED", 1)]);
/// The 1×1 convolution in register tiles of 8 pixels × 8 channels, from repacked f32
/// weights (`ops::PackedConv`).
/// The 3×3 stride-2 convolution for CPU drivers: input and packed weights as texels.
pub const CONV3X3_S2_CPU: Shader = shader!("nn/conv3x3_s2_cpu.wgsl", [Conv2dParams], elem)
    .with_snippets(&[PICK, CONV_BIAS, CONV_STORE]);
pub const CONV1X1: Shader =
    shader!("nn/conv1x1.wgsl", [Conv2dParams], elem).with_snippets(&[CONV_BIAS, CONV1X1_TILE]);
/// `CONV1X1` for CPU drivers: the input and the weights read as texels.
pub const CONV1X1_CPU: Shader =
    shader!("nn/conv1x1_cpu.wgsl", [Conv2dParams], elem).with_snippets(&[CONV_BIAS, CONV1X1_TILE]);
pub const UPSAMPLE_NEAREST: Shader = shader!("nn/upsample_nearest.wgsl", [UpsampleParams], elem);
pub const GROUP_NORM: Shader =
    shader!("nn/group_norm.wgsl", [GroupNormParams], elem).with_uints(&[("THREADS", 64)]);
/// `GROUP_NORM` with workgroups of 256 threads, for GPUs and large groups.
pub const GROUP_NORM_WIDE: Shader =
    shader!("nn/group_norm.wgsl", [GroupNormParams], elem).with_uints(&[("THREADS", 256)]);
/// Group norm for CPU drivers: one invocation per (sample, group), no barriers.
pub const GROUP_NORM_SERIAL: Shader =
    shader!("nn/group_norm_serial.wgsl", [GroupNormParams], elem).with_snippets(&[TEXEL_STATS]);
pub const LINEAR: Shader = shader!("nn/linear.wgsl", [LinearParams], elem);
/// The linear layer in 4 × 4 register tiles (for 4 rows or more).
pub const LINEAR_TILED: Shader = shader!("nn/linear_tiled.wgsl", [LinearParams], elem);
/// The linear layer for GPUs: a workgroup per 4 × 4 tile, its threads splitting the inputs.
pub const LINEAR_SPLIT: Shader = shader!("nn/linear_split.wgsl", [LinearParams], elem);
/// The tiled linear layer for CPU drivers: vec4 loads along the inputs.
pub const LINEAR_CPU: Shader =
    shader!("nn/linear_cpu.wgsl", [LinearParams], elem).with_snippets(&[TEXEL_STATS]);
pub const ADD: Shader = shader!("nn/add.wgsl", [AddParams], elem);
/// The cross-attention to one action token, as a per-action bias.
pub const ADD_ACTION_BIAS: Shader = shader!("nn/add_action_bias.wgsl", [ActionBiasParams], elem);
pub const PERMUTE: Shader = shader!("nn/permute.wgsl", [PermuteParams], elem);
/// `a + permute(x)`: the attention layers' residual.
pub const CONCAT: Shader = shader!("nn/concat.wgsl", [ConcatParams], elem);
pub const AXPBY: Shader = shader!("nn/axpby.wgsl", [AxpbyParams], elem);
pub const ATTENTION: Shader = shader!("nn/attention.wgsl", [AttentionParams], elem)
    .with_uints(&[("MAX_HEAD_SIZE", super::ops::MAX_HEAD_SIZE as u32)]);
/// Attention for GPUs: a workgroup per query, its threads splitting the keys.
pub const ATTENTION_SPLIT: Shader = shader!("nn/attention_split.wgsl", [AttentionParams], elem)
    .with_uints(&[("MAX_HEAD_SIZE", super::ops::MAX_HEAD_SIZE as u32)]);
/// Attention for GPUs over sequences of many queries: a workgroup per block of
/// queries, keys and values loaded into workgroup memory a chunk at a time.
pub const ATTENTION_TILED: Shader = shader!("nn/attention_tiled.wgsl", [AttentionParams], elem)
    .with_uints(&[("TILE_HEAD", super::ops::TILE_HEAD_SIZE as u32)]);
/// Attention for CPU drivers: heads of at most 32 values in named vec4 registers.
pub const ATTENTION_CPU: Shader =
    shader!("nn/attention_cpu.wgsl", [AttentionParams], elem).with_snippets(&[ONLINE_SOFTMAX]);
/// A temporal layer's projection and attention for one new frame, for GPUs.
pub const TEMPORAL_NEXT_SPLIT: Shader =
    shader!("nn/temporal_next_split.wgsl", [AttentionParams], elem)
        .with_uints(&[("MAX_HEAD_SIZE", super::ops::MAX_HEAD_SIZE as u32)]);
/// A temporal layer's projection and attention for one new frame, for CPU drivers.
pub const TEMPORAL_NEXT: Shader =
    shader!("nn/temporal_next.wgsl", [AttentionParams], elem).with_snippets(&[ONLINE_SOFTMAX]);
pub const TIMESTEP_EMBEDDING: Shader =
    shader!("nn/timestep_embedding.wgsl", [EmbeddingParams], elem);
pub const GATHER: Shader = shader!("nn/gather.wgsl", [GatherParams], elem);
/// `GATHER` for CPU drivers: four values a texel.
pub const GATHER_CPU: Shader = shader!("nn/gather_cpu.wgsl", [GatherParams], elem);
pub const SEGMENT_MEAN: Shader = shader!("nn/segment_mean.wgsl", [SegmentParams], elem);

/// Every shader of the model.
pub const ALL: &[Shader] = &[
    CONV2D,
    CONV2D_TILED,
    CONV2D_SPLIT,
    CONV3X3,
    CONV3X3_CPU,
    CONV3X3_NORMED_CPU,
    CONV3X3_S2_CPU,
    CONV1X1,
    CONV1X1_CPU,
    UPSAMPLE_NEAREST,
    GROUP_NORM,
    GROUP_NORM_WIDE,
    GROUP_NORM_SERIAL,
    LINEAR,
    LINEAR_TILED,
    LINEAR_SPLIT,
    LINEAR_CPU,
    ADD,
    ADD_ACTION_BIAS,
    PERMUTE,
    CONCAT,
    AXPBY,
    ATTENTION,
    ATTENTION_SPLIT,
    ATTENTION_TILED,
    ATTENTION_CPU,
    TEMPORAL_NEXT,
    TEMPORAL_NEXT_SPLIT,
    TIMESTEP_EMBEDDING,
    GATHER,
    GATHER_CPU,
    SEGMENT_MEAN,
];
