//! Element-wise ops: broadcast adds, the action bias, `alpha x + beta z`, and the
//! timestep embedding.

use super::{Indices, Recorder};
use crate::gpu::GpuError;
use crate::gpu::shaders::Shader;
use crate::gpu_struct;
use crate::nn::Tensor;
use crate::wgsl_shader as shader;

pub const ADD: Shader = shader!("nn/arith/add.wgsl", [AddParams], elem);
/// The cross-attention to one action token, as a per-action bias.
pub const ADD_ACTION_BIAS: Shader =
    shader!("nn/arith/add_action_bias.wgsl", [ActionBiasParams], elem);
pub const AXPBY: Shader = shader!("nn/arith/axpby.wgsl", [AxpbyParams], elem);
pub const TIMESTEP_EMBEDDING: Shader =
    shader!("nn/arith/timestep_embedding.wgsl", [EmbeddingParams], elem);

/// Every shader of this file (see [`super::shaders`]).
pub const SHADERS: &[Shader] = &[ADD, ADD_ACTION_BIAS, AXPBY, TIMESTEP_EMBEDDING];

gpu_struct! {
    /// `y[i] = a[i] + b[b_offset + (i / per_value) % b_len]` over `len` values.
    pub struct AddParams {
        pub len: u32,
        pub per_value: u32,
        pub b_len: u32,
        pub b_offset: u32,
    }
}

gpu_struct! {
    /// `y = alpha · x[x_offset..] + beta · z[z_offset..]` over `len` values.
    pub struct AxpbyParams {
        pub len: u32,
        pub x_offset: u32,
        pub z_offset: u32,
        pub reserved: u32,
        pub alpha: f32,
        pub beta: f32,
        pub reserved1: u32,
        pub reserved2: u32,
    }
}

gpu_struct! {
    /// `y = x + table[ids[sample], channel]` over `len` NCHW values (`frames` images per
    /// sample, planes of `hw`).
    pub struct ActionBiasParams {
        pub len: u32,
        pub hw: u32,
        pub channels: u32,
        pub frames: u32,
    }
}

gpu_struct! {
    /// `count` timesteps embedded in `dim` values each.
    pub struct EmbeddingParams {
        pub count: u32,
        pub dim: u32,
        pub reserved0: u32,
        pub reserved1: u32,
    }
}

/// How `b` lines up with `a` in [`Recorder::add`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Broadcast {
    /// `b` holds one value per leading index (e.g. [N, C] over each H×W plane of NCHW).
    Leading,
    /// `b` repeats over the leading axes (e.g. [F, C] over [B, HW, F, C]).
    Trailing,
}

impl Recorder<'_> {
    /// `x` [N·F, C, H, W] plus row `ids[n]` of `table` [A, C] on every pixel of sample
    /// n's `frames` (F) images.
    pub fn add_action_bias(
        &mut self,
        x: &Tensor,
        table: &Tensor,
        ids: &Indices,
        frames: usize,
    ) -> Result<Tensor, GpuError> {
        let [nf, c, h, w] = x.shape[..] else {
            panic!("NCHW expected, got {:?}", x.shape)
        };
        assert_eq!(table.shape[1], c, "action bias table {:?}", table.shape);
        assert_eq!(nf, ids.len * frames, "{} ids for {nf} images", ids.len);
        self.check(&[x, table]);
        let y = self.output("action_bias.y", &x.shape)?;
        let params = ActionBiasParams {
            len: x.len() as u32,
            hw: (h * w) as u32,
            channels: c as u32,
            frames: frames as u32,
        };
        let grid = self.grid(y.len());
        let buffers = [&x.buffer, &table.buffer, &ids.buffer, &y.buffer];
        self.steps
            .dispatch(&ADD_ACTION_BIAS, &params, &buffers, grid);
        Ok(y)
    }

    /// `a + b`, where `b` is shaped like `a` or broadcast as `broadcast` says.
    pub fn add(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        broadcast: Broadcast,
    ) -> Result<Tensor, GpuError> {
        self.add_part(a, b, 0..b.len(), broadcast)
    }

    /// `a + b[part]`, the values `part` of `b` broadcast as `broadcast` says (e.g. some
    /// rows of a table of frame positions).
    pub fn add_part(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        part: std::ops::Range<usize>,
        broadcast: Broadcast,
    ) -> Result<Tensor, GpuError> {
        assert!(
            !part.is_empty() && part.end <= b.len() && a.len().is_multiple_of(part.len()),
            "cannot broadcast values {part:?} of {:?} onto {:?}",
            b.shape,
            a.shape
        );
        let y = self.output("add.y", &a.shape)?;
        let params = AddParams {
            len: a.len() as u32,
            per_value: match broadcast {
                Broadcast::Leading => (a.len() / part.len()) as u32,
                Broadcast::Trailing => 1,
            },
            b_len: part.len() as u32,
            b_offset: part.start as u32,
        };
        let grid = self.grid(y.len());
        self.launch(&ADD, &params, &[a, b, &y], grid);
        Ok(y)
    }

    /// `alpha · x + beta · z` of shape `shape`, read from `x` and `z` at value offsets
    /// (e.g. the halves of a batch).
    #[allow(clippy::too_many_arguments)]
    pub fn axpby(
        &mut self,
        alpha: f32,
        x: &Tensor,
        x_offset: usize,
        beta: f32,
        z: &Tensor,
        z_offset: usize,
        shape: &[usize],
    ) -> Result<Tensor, GpuError> {
        let y = self.output("axpby.y", shape)?;
        assert!(
            x_offset + y.len() <= x.len() && z_offset + y.len() <= z.len(),
            "axpby out of range"
        );
        let params = AxpbyParams {
            len: y.len() as u32,
            x_offset: x_offset as u32,
            z_offset: z_offset as u32,
            reserved: 0,
            alpha,
            beta,
            reserved1: 0,
            reserved2: 0,
        };
        let grid = self.grid(y.len());
        self.launch(&AXPBY, &params, &[x, z, &y], grid);
        Ok(y)
    }

    /// The sinusoidal embedding of the timesteps in `t` (any shape) into `dim` values.
    pub fn timestep_embedding(&mut self, t: &Tensor, dim: usize) -> Result<Tensor, GpuError> {
        assert!(dim.is_multiple_of(2), "embedding size {dim} must be even");
        let y = self.output("timestep_embedding.y", &[t.len(), dim])?;
        let params = EmbeddingParams {
            count: t.len() as u32,
            dim: dim as u32,
            reserved0: 0,
            reserved1: 0,
        };
        let grid = self.grid(t.len() * dim / 2);
        self.launch(&TIMESTEP_EMBEDDING, &params, &[t, &y], grid);
        Ok(y)
    }
}
