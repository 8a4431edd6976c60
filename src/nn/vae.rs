//! The position-map VAE (train/unica_train/vae.py): 3×128² maps ↔ 4×16² latents. The
//! encoder gives the latent mean (what inference uses; the log-variance half of its last
//! convolution is not loaded). Two decoders, as the manifest's `vae.decoder` says: the
//! upsampling convolutions (`ConvDecoder`), or a linear head onto a fixed PCA basis of
//! the character's maps (`PcaDecoder`).

use serde::Deserialize;

use super::Tensor;
use super::layers::{Conv, Linear, Norm, ResBlock, UpBlock};
use super::ops::Recorder;
use super::weights::{LoadError, Weights};
use crate::gpu::GpuError;

/// Which decoder a VAE has (`VaeConfig.decoder` in train/unica_train/vae.py).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DecoderKind {
    /// Upsampling convolutions.
    #[default]
    Conv,
    /// `mean + (W z + b) @ basis` over the map's foreground.
    Pca,
}

/// The VAE's shape, as the bundle manifest's `vae` entry.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct VaeConfig {
    /// Channels at 16, 32, 64 and 128 pixels.
    pub channels: [usize; 4],
    pub latent: usize,
    #[serde(default)]
    pub decoder: DecoderKind,
    /// The PCA head's basis size (unused by the conv decoder).
    #[serde(default)]
    pub components: usize,
    /// The foreground pixels the PCA head writes (unused by the conv decoder).
    #[serde(default)]
    pub pixels: usize,
    #[serde(default = "default_map_size")]
    pub map_size: usize,
}

fn default_map_size() -> usize {
    128
}

impl VaeConfig {
    /// The trainer's default (`VaeConfig()` in train/unica_train/vae.py).
    pub const DEFAULT: Self = Self {
        channels: [64, 48, 24, 12],
        latent: 4,
        decoder: DecoderKind::Conv,
        components: 200,
        pixels: 0,
        map_size: 128,
    };

    /// The parity fixtures' tiny VAE (`TINY_VAE` in train/unica_train/fixtures.py).
    pub const TINY: Self = Self {
        channels: [16, 12, 8, 8],
        ..Self::DEFAULT
    };

    /// The parity fixtures' tiny PCA-head VAE (`TINY_PCA_VAE` in fixtures.py).
    pub const TINY_PCA: Self = Self {
        decoder: DecoderKind::Pca,
        components: 24,
        pixels: 300,
        ..Self::TINY
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

/// A VAE decoder of either kind: latents [N, latent, 16, 16] → maps [N, 3, 128, 128].
pub enum Decoder {
    Conv(Box<ConvDecoder>),
    Pca(Box<PcaDecoder>),
}

impl Decoder {
    pub fn load(w: &Weights, cfg: &VaeConfig) -> Result<Self, LoadError> {
        Ok(match cfg.decoder {
            DecoderKind::Conv => Self::Conv(Box::new(ConvDecoder::load(w, cfg)?)),
            DecoderKind::Pca => Self::Pca(Box::new(PcaDecoder::load(w, cfg)?)),
        })
    }

    pub fn forward(&self, r: &mut Recorder, z: &Tensor) -> Result<Tensor, GpuError> {
        match self {
            Self::Conv(d) => d.forward(r, z),
            Self::Pca(d) => d.forward(r, z),
        }
    }

    /// The map pixels a PCA head writes (none for the conv decoder, which writes all).
    pub fn pixels(&self) -> Option<&[u32]> {
        match self {
            Self::Conv(_) => None,
            Self::Pca(d) => Some(&d.pixels),
        }
    }
}

/// `map foreground = mean + (W z + b) @ basis`, background 0 (train/unica_train/vae.py's
/// `PcaDecoder`): three dispatches — the head (a linear layer on the flattened latent),
/// the basis product (a linear layer whose weight is the basis transposed and whose bias
/// is the mean, padded with zero outputs), and a gather that places each value at its
/// pixel and a zero everywhere else.
pub struct PcaDecoder {
    head: Linear,
    /// [values + padding, components]: the basis transposed, zero rows past the values.
    basis: Tensor,
    /// [values + padding]: the mean, then zeros.
    mean: Tensor,
    /// The foreground pixels, increasing.
    pixels: Vec<u32>,
    /// Each map element's row in one sample's padded values (c·P + slot, or a zero row).
    table: Vec<u32>,
    size: usize,
}

impl PcaDecoder {
    pub fn load(w: &Weights, cfg: &VaeConfig) -> Result<Self, LoadError> {
        let (k, p, size) = (cfg.components, cfg.pixels, cfg.map_size);
        let values = 3 * p;
        let padded = (values + 1).next_multiple_of(4);
        let side = size / 8;
        let pixels = w.indices("pixels", p, size * size)?;
        let basis = w.host("basis", &[k, values])?;
        let mut transposed = vec![0.0; padded * k];
        for (c, row) in basis.chunks_exact(values).enumerate() {
            for (v, &b) in row.iter().enumerate() {
                transposed[v * k + c] = b;
            }
        }
        let mut mean = w.host("mean", &[values])?;
        mean.resize(padded, 0.0);
        // Background elements read the first zero row past the values.
        let plane = size * size;
        let mut table = vec![values as u32; 3 * plane];
        for (i, &pixel) in pixels.iter().enumerate() {
            for c in 0..3 {
                table[c * plane + pixel as usize] = (c * p + i) as u32;
            }
        }
        let (gpu, precision) = (w.gpu(), w.precision());
        Ok(Self {
            head: Linear::load(&w.at("head"), cfg.latent * side * side, k)?,
            basis: Tensor::upload(
                gpu,
                "vae.decoder.basis",
                &[padded, k],
                &transposed,
                precision,
            )?,
            mean: Tensor::upload(gpu, "vae.decoder.mean", &[padded], &mean, precision)?,
            pixels,
            table,
            size,
        })
    }

    /// Latents [N, latent, side, side] → maps [N, 3, size, size].
    pub fn forward(&self, r: &mut Recorder, z: &Tensor) -> Result<Tensor, GpuError> {
        let n = z.shape[0];
        let flat = z.reshaped(&[n, z.len() / n]);
        let h = self.head.forward(r, &flat, false)?;
        let values = r.linear(&h, &self.basis, &self.mean, false)?;
        let padded = self.mean.len();
        let index: Vec<u32> = (0..n)
            .flat_map(|s| self.table.iter().map(move |&t| (s * padded) as u32 + t))
            .collect();
        let index = r.indices("vae.decoder.map", &index)?;
        let map = r.gather(&values.reshaped(&[n * padded, 1]), &index)?;
        Ok(map.reshaped(&[n, 3, self.size, self.size]))
    }
}

pub struct ConvDecoder {
    conv_in: Conv,
    res: Vec<ResBlock>,
    up: Vec<UpBlock>,
    norm_out: Norm,
    conv_out: Conv,
}

impl ConvDecoder {
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
                .map(|(i, &(a, b))| UpBlock::load(&w.at(&format!("up.{i}")), a, b))
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
    /// (measured with `unica bench`).
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
