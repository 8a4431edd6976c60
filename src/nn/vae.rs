//! The position-map VAE (train/unica_train/vae.py): 3×128² maps ↔ 4×16² latents. The
//! encoder gives the latent mean (what inference uses; the log-variance half of its last
//! convolution is not loaded).

use serde::Deserialize;

use super::Tensor;
use super::layers::{Conv, Norm, ResBlock, Up};
use super::ops::Recorder;
use super::weights::{LoadError, Weights};
use crate::gpu::GpuError;

/// The VAE's shape, as the bundle manifest's `vae` entry.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct VaeConfig {
    /// Channels at 16, 32, 64 and 128 pixels.
    pub channels: [usize; 4],
    pub latent: usize,
}

impl VaeConfig {
    /// The trainer's default (`VaeConfig()` in train/unica_train/vae.py).
    pub const DEFAULT: Self = Self {
        channels: [64, 48, 24, 12],
        latent: 4,
    };

    /// The parity fixtures' tiny VAE (`TINY_VAE` in train/unica_train/fixtures.py).
    pub const TINY: Self = Self {
        channels: [16, 12, 8, 8],
        latent: 4,
    };
}

pub struct Encoder {
    conv_in: Conv,
    down: Vec<Conv>,
    res: Vec<ResBlock>,
    norm_out: Norm,
    conv_out_mean: Conv,
}

impl Encoder {
    pub fn load(w: &Weights, cfg: &VaeConfig) -> Result<Self, LoadError> {
        let [c16, c32, c64, c128] = cfg.channels;
        let steps = [(c128, c64), (c64, c32), (c32, c16)];
        Ok(Self {
            conv_in: Conv::load(&w.at("conv_in"), 3, c128, 3, 1)?,
            down: steps
                .iter()
                .enumerate()
                .map(|(i, &(a, b))| Conv::load(&w.at(&format!("down.{i}.conv")), a, b, 3, 2))
                .collect::<Result<_, _>>()?,
            res: steps
                .iter()
                .enumerate()
                .map(|(i, &(_, b))| ResBlock::load(&w.at(&format!("res.{i}")), b, b, None))
                .collect::<Result<_, _>>()?,
            norm_out: Norm::load(&w.at("norm_out"), c16)?,
            conv_out_mean: Conv::load_first(&w.at("conv_out"), c16, 2 * cfg.latent, cfg.latent)?,
        })
    }

    /// Maps [N, 3, 128, 128] → latent means [N, latent, 16, 16].
    pub fn forward(&self, r: &mut Recorder, x: &Tensor) -> Result<Tensor, GpuError> {
        let mut h = self.conv_in.forward(r, x)?;
        for (down, res) in self.down.iter().zip(&self.res) {
            let d = down.forward(r, &h)?;
            h = res.forward(r, &d, None)?;
        }
        let h = self.norm_out.forward(r, &h, true)?;
        self.conv_out_mean.forward(r, &h)
    }
}

/// The largest plane (pixels) whose block folds its norms into its convolutions.
const FOLDED_NORM_PIXELS: usize = 32 * 32;

pub struct Decoder {
    conv_in: Conv,
    res: Vec<ResBlock>,
    up: Vec<Up>,
    norm_out: Norm,
    conv_out: Conv,
}

impl Decoder {
    pub fn load(w: &Weights, cfg: &VaeConfig) -> Result<Self, LoadError> {
        let [c16, c32, c64, c128] = cfg.channels;
        let steps = [(c16, c32), (c32, c64), (c64, c128)];
        Ok(Self {
            conv_in: Conv::load(&w.at("conv_in"), cfg.latent, c16, 3, 1)?,
            res: steps
                .iter()
                .enumerate()
                .map(|(i, &(a, _))| ResBlock::load(&w.at(&format!("res.{i}")), a, a, None))
                .collect::<Result<_, _>>()?,
            up: steps
                .iter()
                .enumerate()
                .map(|(i, &(a, b))| Up::load(&w.at(&format!("up.{i}")), a, b))
                .collect::<Result<_, _>>()?,
            norm_out: Norm::load(&w.at("norm_out"), c128)?,
            conv_out: Conv::load(&w.at("conv_out"), c128, 3, 3, 1)?,
        })
    }

    /// Latents [N, latent, 16, 16] → maps [N, 3, 128, 128].
    ///
    /// The blocks at 16² and 32² fold their norms into their convolutions for CPU drivers
    /// ([`ResBlock::forward_folded`]): 4 dispatches fewer (the Witch's decode is 15
    /// instead of 19) for about 4 ms on lavapipe, where the folded norm is recomputed
    /// for every tile that reads a value. At 64² the fold would cost about 5 ms more
    /// for 2 more dispatches, so that block, and the 128² output norm, stay separate
    /// (`unica bench`, session 10).
    pub fn forward(&self, r: &mut Recorder, z: &Tensor) -> Result<Tensor, GpuError> {
        let mut h = self.conv_in.forward(r, z)?;
        for (res, up) in self.res.iter().zip(&self.up) {
            let h1 = if h.shape[2] * h.shape[3] <= FOLDED_NORM_PIXELS {
                res.forward_folded(r, &h)?
            } else {
                res.forward(r, &h, None)?
            };
            h = up.forward(r, &h1)?;
        }
        let h = self.norm_out.forward(r, &h, true)?;
        self.conv_out.forward(r, &h)
    }
}
