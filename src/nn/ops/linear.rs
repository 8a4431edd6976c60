//! Linear layers over rows: plain, with a residual, an action table or a layer norm
//! folded in, into NCHW images, in every [`Kernels`] variant.

use super::norm::GROUP_NORM_EPS;
use super::{Indices, Kernels, Recorder};
use crate::gpu::shaders::Shader;
use crate::gpu::{Bound, GpuError};
use crate::gpu_struct;
use crate::nn::Tensor;
use crate::wgsl_shader as shader;

pub const LINEAR: Shader = shader!("nn/linear/linear.wgsl", [LinearParams], elem);
/// The linear layer in 4 × 4 register tiles (for 4 rows or more).
pub const LINEAR_TILED: Shader = shader!("nn/linear/linear_tiled.wgsl", [LinearParams], elem);
/// The linear layer for GPUs: a workgroup per 4 × 4 tile, its threads splitting the inputs.
pub const LINEAR_SPLIT: Shader = shader!("nn/linear/linear_split.wgsl", [LinearParams], elem);
/// The tiled linear layer for CPU drivers: vec4 loads along the inputs.
pub const LINEAR_CPU: Shader = shader!("nn/linear/linear_cpu.wgsl", [LinearParams], elem)
    .with_uints(&[("NORMED_TILES", NORMED_TILES as u32)]);

/// Output tiles (of 8) one `linear_cpu.wgsl` invocation makes for its 8 rows when it
/// layer-norms them, so each row's statistics are computed once per this many tiles.
/// At the refiner's 32-64 inputs the statistics cost about as much as one tile's
/// product; a larger chunk leaves too few invocations to share among the cores for
/// the 1,104 pooled rows.
pub const NORMED_TILES: usize = 4;

/// `LINEAR_CPU` for plain rows whose outputs are a multiple of 4: four outputs a vec4
/// store (a storage store on lavapipe moves one value per loop over the lanes).
pub const LINEAR_ROWS_CPU: Shader = shader!("nn/linear/linear_rows_cpu.wgsl", [LinearParams], elem)
    .with_uints(&[("NORMED_TILES", NORMED_TILES as u32)]);

/// Every shader of this file (see [`super::shaders`]).
pub const SHADERS: &[Shader] = &[
    LINEAR,
    LINEAR_TILED,
    LINEAR_SPLIT,
    LINEAR_CPU,
    LINEAR_ROWS_CPU,
];

gpu_struct! {
    /// A fully connected layer over `rows` rows.
    pub struct LinearParams {
        pub rows: u32,
        pub inputs: u32,
        pub outputs: u32,
        pub input_silu: u32,
        /// Add a residual of the output's shape to the result rounded to Elem (the sum
        /// add.wgsl would make after the layer).
        pub has_residual: u32,
        /// 0: the output is [rows, outputs]. F > 0 (linear_cpu.wgsl only): the rows are
        /// tokens [N, HW, F] and each result goes to its NCHW image [N·F, outputs, H, W]
        /// (image n·F + f), as a permute after the layer would put it; the residual is
        /// then NCHW too.
        pub images: u32,
        /// Pixels per image (with `images`).
        pub hw: u32,
        /// With `images`: plus row ids[image / table_frames] of an action table
        /// [A, outputs], added last (as add_action_bias.wgsl).
        pub has_table: u32,
        pub table_frames: u32,
        /// linear_cpu.wgsl only: input row r is row ids[r] of x (a gather before the
        /// layer; `rows` counts the output rows).
        pub gather_rows: u32,
        /// linear_cpu.wgsl only: each input row layer-normed first (gamma, beta, `eps`),
        /// rounded to Elem as the layer norm stores it.
        pub norm_rows: u32,
        pub eps: f32,
    }
}

/// What `linear_cpu.wgsl` reads besides x, the weight and the bias: the residual buffer
/// (read where `has_residual` or `images` says), an action table and ids (or the row
/// index in the ids binding), and a layer norm's gamma and beta.
struct LinearExtras<'t> {
    residual: &'t wgpu::Buffer,
    table: Option<(&'t wgpu::Buffer, &'t wgpu::Buffer)>,
    norm: Option<(&'t Tensor, &'t Tensor)>,
}

impl Recorder<'_> {
    /// Whether a layer of `inputs` inputs runs in `linear_cpu.wgsl`'s texel tiles: on CPU
    /// drivers wherever its inputs fill whole texels, whatever its rows (a single row
    /// wastes seven eighths of a tile, yet beats one invocation per output: see
    /// [`Recorder::linear_plus`]).
    fn cpu_tiles(&self, inputs: usize) -> bool {
        self.kernels == Kernels::Cpu && inputs.is_multiple_of(4)
    }

    /// `y = act(x) Wᵀ + b` over the last axis of `x`, `weight` [outputs, inputs]; act is
    /// SiLU when `input_silu` is set.
    pub fn linear(
        &mut self,
        x: &Tensor,
        weight: &Tensor,
        bias: &Tensor,
        input_silu: bool,
    ) -> Result<Tensor, GpuError> {
        self.linear_plus(x, weight, bias, input_silu, None)
    }

    /// `residual + linear(x)` in one dispatch (`residual` of the output's shape), the
    /// sum add.wgsl would make after [`Recorder::linear`]. `weight` is constant: the
    /// CPU-driver kernel reads the texels copied from it on first use.
    pub fn linear_plus(
        &mut self,
        x: &Tensor,
        weight: &Tensor,
        bias: &Tensor,
        input_silu: bool,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let inputs = *x.shape.last().expect("a tensor has a shape");
        let [outputs, w_inputs] = weight.shape[..] else {
            panic!(
                "linear weight must be [outputs, inputs], got {:?}",
                weight.shape
            )
        };
        assert_eq!(inputs, w_inputs, "linear input size mismatch");
        let mut shape = x.shape.clone();
        *shape.last_mut().expect("non-empty") = outputs;
        let y = self.output("linear.y", &shape)?;
        self.flops += 2 * (y.len() * inputs) as u64;
        let params = LinearParams {
            rows: (x.len() / inputs) as u32,
            inputs: inputs as u32,
            outputs: outputs as u32,
            input_silu: u32::from(input_silu),
            has_residual: u32::from(residual.is_some()),
            images: 0,
            hw: 1,
            has_table: 0,
            table_frames: 1,
            gather_rows: 0,
            norm_rows: 0,
            eps: GROUP_NORM_EPS,
        };
        if let Some(res) = residual {
            assert_eq!(res.len(), y.len(), "linear residual {:?}", res.shape);
        }
        // Without a residual its binding still exists; x stands in (unread).
        let residual = residual.unwrap_or(x);
        // For GPUs, a workgroup per tile of 4 rows × 4 outputs whatever the rows
        // (linear_split.wgsl: every linear layer sums in the same order, so the action
        // table equals the cross-attention it replaces bit for bit). For CPU drivers
        // texel tiles of 8 rows × 8 outputs whatever the rows: a single row wastes
        // seven eighths of a tile's sums, yet the PCA head's basis product (1 row, 200
        // inputs, 13,244 outputs) took 26 ms as one invocation per output, whose
        // weight loads stride across lanes. Otherwise register tiles of 4 rows × 4
        // outputs where there are rows to share a tile, one invocation per output for
        // fewer rows (the timestep and action embeddings). All sum in the same order
        // and are parity-tested (tests/nn/).
        let rows = x.len() / inputs;
        if self.kernels == Kernels::Gpu {
            self.linear_split(&params, [x, weight, bias, residual], None, &y);
        } else if self.cpu_tiles(inputs) {
            self.check(&[x, weight, bias, residual]);
            let extras = LinearExtras {
                residual: &residual.buffer,
                table: None,
                norm: None,
            };
            self.linear_cpu(&params, x, (weight, bias), extras, &y)?;
        } else if rows >= 4 && self.kernels != Kernels::Simple {
            let grid = self.grid(rows.div_ceil(4) * outputs.div_ceil(4));
            self.launch(
                &LINEAR_TILED,
                &params,
                &[x, weight, bias, residual, &y],
                grid,
            );
        } else {
            let grid = self.grid(y.len());
            self.launch(&LINEAR, &params, &[x, weight, bias, residual, &y], grid);
        }
        Ok(y)
    }

    /// Records `linear_split.wgsl` over `inputs` (x, weight, bias, residual) and the
    /// optional action table (table, ids) into `y`: one workgroup per tile of 4 rows ×
    /// 4 outputs of `params`. Without a table the bias stands in for its bindings
    /// (unread).
    fn linear_split(
        &mut self,
        params: &LinearParams,
        inputs: [&Tensor; 4],
        table: Option<(&Tensor, &Indices)>,
        y: &Tensor,
    ) {
        let [x, weight, bias, residual] = inputs;
        self.check(&[x, weight, bias, residual, y]);
        let (table, ids) = table.map_or((&bias.buffer, &bias.buffer), |(t, i)| {
            (&t.buffer, &i.buffer)
        });
        let tiles = (params.rows as usize).div_ceil(4) * (params.outputs as usize).div_ceil(4);
        let grid = self.workgroups(tiles);
        let buffers = [
            &x.buffer,
            &weight.buffer,
            &bias.buffer,
            &residual.buffer,
            table,
            ids,
            &y.buffer,
        ];
        self.steps.dispatch(&LINEAR_SPLIT, params, &buffers, grid);
    }

    /// Records `linear_cpu.wgsl` over `x` into `y`: x and the constant weight as
    /// texels, then the bias, `extras` and the output, over tiles of 8 rows × 8 outputs
    /// of `params`. Absent extras keep their bindings: the bias and x stand in (unread).
    fn linear_cpu(
        &mut self,
        params: &LinearParams,
        x: &Tensor,
        layer: (&Tensor, &Tensor),
        extras: LinearExtras,
        y: &Tensor,
    ) -> Result<(), GpuError> {
        let (weight, bias) = layer;
        let input = self.texels(x)?;
        let weight = weight.constant_texels(self.gpu)?;
        let (table, ids) = extras.table.unwrap_or((&bias.buffer, &bias.buffer));
        let (gamma, beta) = match extras.norm {
            Some((gamma, beta)) => (
                gamma.constant_texels(self.gpu)?,
                beta.constant_texels(self.gpu)?,
            ),
            None => (&input, &input),
        };
        let chunk = if params.norm_rows != 0 {
            NORMED_TILES
        } else {
            1
        };
        let chunks = (params.outputs as usize).div_ceil(8).div_ceil(chunk);
        let grid = self.grid((params.rows as usize).div_ceil(8) * chunks);
        // Plain rows of whole vec4s store four outputs at a time (linear_rows_cpu.wgsl,
        // which has no action table).
        let rows = params.images == 0 && params.has_table == 0 && params.outputs.is_multiple_of(4);
        let mut bound = vec![
            Bound::Texels(&input),
            Bound::Texels(weight),
            Bound::Buffer(&bias.buffer),
            Bound::Buffer(extras.residual),
        ];
        if !rows {
            bound.push(Bound::Buffer(table));
        }
        bound.extend([
            Bound::Buffer(ids),
            Bound::Texels(gamma),
            Bound::Texels(beta),
            Bound::Buffer(&y.buffer),
        ]);
        let shader = if rows { &LINEAR_ROWS_CPU } else { &LINEAR_CPU };
        self.steps.dispatch_bound(shader, params, &bound, grid);
        Ok(())
    }

    /// `a + permute(linear(x))`, plus an action-table row per sample with `table`
    /// (table, ids, images per sample): token rows `x` [N, HW, F, inputs] projected and
    /// put back into the NCHW images `a` [N·F, outputs, H, W] (image n·F + f), the
    /// attention layers' output projection and residual. Equal bit for bit to
    /// [`Recorder::linear`] then [`Recorder::add_permuted_bias`] (shape [N, HW, F, C],
    /// permutation [0, 2, 3, 1]), which other kernel variants record; for CPU drivers
    /// one dispatch (the linear kernel stores into the images). `weight` is constant.
    pub fn linear_to_images(
        &mut self,
        x: &Tensor,
        layer: (&Tensor, &Tensor),
        a: &Tensor,
        frames: usize,
        table: Option<(&Tensor, &Indices, usize)>,
    ) -> Result<Tensor, GpuError> {
        let (weight, bias) = layer;
        let [nf, c, h, w] = a.shape[..] else {
            panic!("NCHW residual expected, got {:?}", a.shape)
        };
        let inputs = *x.shape.last().expect("a tensor has a shape");
        assert_eq!(weight.shape, [c, inputs], "linear_to_images weight");
        assert!(nf.is_multiple_of(frames), "{nf} images in runs of {frames}");
        let (n, hw) = (nf / frames, h * w);
        let rows = x.len() / inputs;
        assert_eq!(rows, n * hw * frames, "{rows} tokens for {:?}", a.shape);
        if let Some((table, ids, per_sample)) = table {
            assert_eq!(table.shape[1], c, "action bias table {:?}", table.shape);
            assert_eq!(nf, ids.len * per_sample, "{} ids for {nf} images", ids.len);
        }
        let fused = self.kernels == Kernels::Gpu || self.cpu_tiles(inputs);
        if !fused {
            let out = self.linear(x, weight, bias, false)?;
            return self.permute_plus(&out, [n, hw, frames, c], [0, 2, 3, 1], Some(a), None, table);
        }
        let y = self.output("linear.images", &a.shape)?;
        self.flops += 2 * (rows * c * inputs) as u64;
        let params = LinearParams {
            rows: rows as u32,
            inputs: inputs as u32,
            outputs: c as u32,
            input_silu: 0,
            has_residual: 1,
            images: frames as u32,
            hw: hw as u32,
            has_table: u32::from(table.is_some()),
            table_frames: table.map_or(1, |(_, _, per_sample)| per_sample as u32),
            gather_rows: 0,
            norm_rows: 0,
            eps: GROUP_NORM_EPS,
        };
        if self.kernels == Kernels::Gpu {
            let table = table.map(|(table, ids, _)| (table, ids));
            self.linear_split(&params, [x, weight, bias, a], table, &y);
            return Ok(y);
        }
        self.check(&[x, weight, bias, a]);
        if let Some((table, ..)) = table {
            self.check(&[table]);
        }
        let extras = LinearExtras {
            residual: &a.buffer,
            table: table.map(|(table, ids, _)| (&table.buffer, &ids.buffer)),
            norm: None,
        };
        self.linear_cpu(&params, x, (weight, bias), extras, &y)?;
        Ok(y)
    }

    /// `residual + linear(layer_norm(x[rows]))`: a linear layer over rows `rows` of x
    /// (all rows in order without it), each layer-normed first with `norm` (gamma,
    /// beta) when given, plus an optional residual of the output's shape: the
    /// refiner's norm, projection and serialisation gather. Equal bit for bit to
    /// [`Recorder::gather`], the layer norm ([`Recorder::group_norm`] with one group per
    /// row) and [`Recorder::linear_plus`] (other variants record them); for CPU drivers
    /// one dispatch. `weight`, gamma and beta are constant.
    pub fn linear_rows(
        &mut self,
        x: &Tensor,
        layer: (&Tensor, &Tensor),
        norm: Option<(&Tensor, &Tensor)>,
        rows: Option<&Indices>,
        residual: Option<&Tensor>,
    ) -> Result<Tensor, GpuError> {
        let (weight, bias) = layer;
        let [x_rows, inputs] = x.shape[..] else {
            panic!("linear rows of {:?}", x.shape)
        };
        let [outputs, w_inputs] = weight.shape[..] else {
            panic!("linear weight {:?}", weight.shape)
        };
        assert_eq!(inputs, w_inputs, "linear input size mismatch");
        let out_rows = rows.map_or(x_rows, |r| r.len);
        if let Some(res) = residual {
            assert_eq!(
                res.len(),
                out_rows * outputs,
                "linear residual {:?}",
                res.shape
            );
        }
        let fused = self.cpu_tiles(inputs);
        if !fused {
            let mut input = match rows {
                Some(rows) => self.gather(x, rows)?,
                None => x.clone(),
            };
            if let Some((gamma, beta)) = norm {
                let square = input.reshaped(&[out_rows, inputs, 1, 1]);
                input = self.group_norm(&square, gamma, beta, 1, false)?;
                input = input.reshaped(&[out_rows, inputs]);
            }
            return self.linear_plus(&input, weight, bias, false, residual);
        }
        let y = self.output("linear.rows", &[out_rows, outputs])?;
        self.flops += 2 * (out_rows * outputs * inputs) as u64;
        let params = LinearParams {
            rows: out_rows as u32,
            inputs: inputs as u32,
            outputs: outputs as u32,
            input_silu: 0,
            has_residual: u32::from(residual.is_some()),
            images: 0,
            hw: 1,
            has_table: 0,
            table_frames: 1,
            gather_rows: u32::from(rows.is_some()),
            norm_rows: u32::from(norm.is_some()),
            eps: GROUP_NORM_EPS,
        };
        let residual = residual.unwrap_or(x);
        self.check(&[x, weight, bias, residual]);
        if let Some((gamma, beta)) = norm {
            self.check(&[gamma, beta]);
        }
        // The row index rides in the ids binding (there is no action table).
        let extras = LinearExtras {
            residual: &residual.buffer,
            table: rows.map(|r| (&bias.buffer, &r.buffer)),
            norm,
        };
        self.linear_cpu(&params, x, (weight, bias), extras, &y)?;
        Ok(y)
    }
}
