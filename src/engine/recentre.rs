//! Recentring the window by re-encoding it: the engine keeps the window's three context
//! frames as position maps beside their latents. When the window slides, frames 1 and 2
//! and the new frame (its clamped points) are translated by -δ, the new frame's root
//! shift, written as maps with background 0 (`slide.wgsl`), and encoded again: the
//! context latents are the encoder's means of those maps times the latent scale, as in
//! the trainer's reference loop (`train/unica_train/recentre.py`, mode "reencode").
//!
//! The window is re-encoded rather than slid in latent space as -Σ δ_k J_k (J the
//! encoder's response to a uniform shift, measured once per bundle): the PyTorch loop
//! measured that approximation as the cause of a short stride, 2.11 m/s on W against
//! 2.42 re-encoded and the teacher's 2.39. Re-encoding three 128² maps costs 0.8 GFLOP a
//! frame. This module makes the window's starting maps: the standing-start context
//! decoded, background 0.

use super::bundle::Bundle;
use crate::gpu::GpuContext;
use crate::gpu::kernel::{PipelineCache, Precision};
use crate::nn::{LoadError, Recorder};

/// Marks a background pixel in [`Start::point_of`].
pub const BACKGROUND: u32 = u32::MAX;

pub struct Start {
    /// The standing start's context frames decoded, foreground kept and background 0:
    /// [F-1, 3, S, S], the window's maps before the first frame.
    pub maps: Vec<f32>,
    /// The standing start's last frame: its foreground points, normalised.
    pub standing: Vec<glam::Vec3>,
    /// For every map pixel the index of its foreground point, or [`BACKGROUND`].
    pub point_of: Vec<u32>,
}

impl Start {
    pub fn decode(
        gpu: &GpuContext,
        pipelines: &mut PipelineCache,
        precision: Precision,
        bundle: &Bundle,
    ) -> Result<Self, LoadError> {
        let cfg = &bundle.unet.cfg;
        let size = bundle.manifest.map_size;
        let plane = size * size;
        let context_frames = cfg.frames - 1;
        let mut r = Recorder::new(gpu, pipelines, precision);
        let decoded = bundle.decode(&mut r, &bundle.context)?;
        r.submit();
        let decoded = decoded.read(gpu)?;
        let point_of = point_of(&bundle.pixels, plane);
        let maps: Vec<f32> = decoded
            .iter()
            .enumerate()
            .map(|(i, &v)| {
                if point_of[i % plane] == BACKGROUND {
                    0.0
                } else {
                    v
                }
            })
            .collect();
        let last = &maps[(context_frames - 1) * 3 * plane..context_frames * 3 * plane];
        let standing = bundle
            .pixels
            .iter()
            .map(|&p| {
                let p = p as usize;
                glam::Vec3::new(last[p], last[plane + p], last[2 * plane + p])
            })
            .collect();
        Ok(Self {
            maps,
            standing,
            point_of,
        })
    }
}

/// Each of `plane` pixels' index in `pixels` (the foreground list), or [`BACKGROUND`].
pub fn point_of(pixels: &[u32], plane: usize) -> Vec<u32> {
    crate::gpu::indices::places(pixels, plane, BACKGROUND)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_of_inverts_the_foreground_list() {
        // Pixels 3, 0 and 5 of a 2×3 map are foreground, in that order.
        let out = point_of(&[3, 0, 5], 6);
        assert_eq!(out, vec![1, BACKGROUND, BACKGROUND, 0, BACKGROUND, 2]);
    }
}
