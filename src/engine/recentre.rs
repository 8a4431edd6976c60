//! Recentring the window without re-encoding: when the window slides, every context frame
//! is translated by -δ (the new frame's root shift). A uniform shift of the foreground
//! along axis k moves the encoder's latents along J_k = ∂E/∂δ_k, measured once per
//! bundle by central differences at the standing start's context frames (averaged; as
//! `train/unica_train/recentre.py`'s `bundle_basis`, whose rollouts validated it against
//! re-encoding); the window then moves by -Σ δ_k J_k in latent space (`slide.wgsl`).

use crate::gpu::GpuContext;
use crate::gpu::kernel::{PipelineCache, Precision};
use crate::nn::{Bundle, LoadError, Recorder};

/// The half-width of the central difference, in normalised units: about the root shift
/// of one running frame, so J is the secant over the shifts the loop meets.
const STEP: f32 = 0.03;

pub struct ShiftBasis {
    /// J_x, J_y, J_z one after the other, each one latent frame's values: [3, C·h·w].
    pub jacobian: Vec<f32>,
    /// The standing start's last frame decoded: its foreground points, normalised.
    pub standing: Vec<glam::Vec3>,
}

impl ShiftBasis {
    pub fn measure(
        gpu: &GpuContext,
        pipelines: &mut PipelineCache,
        precision: Precision,
        bundle: &Bundle,
    ) -> Result<Self, LoadError> {
        let cfg = &bundle.unet.cfg;
        let size = bundle.manifest.map_size;
        let plane = size * size;
        let context_frames = cfg.frames - 1;
        // The standing start's last frame, decoded.
        let mut r = Recorder::new(gpu, pipelines, precision);
        let maps = bundle.decode(&mut r, &bundle.context)?;
        r.submit();
        let maps = maps.read(gpu)?;
        let last = &maps[(context_frames - 1) * 3 * plane..context_frames * 3 * plane];
        let standing = bundle
            .pixels
            .iter()
            .map(|&p| {
                glam::Vec3::new(
                    last[p as usize],
                    last[plane + p as usize],
                    last[2 * plane + p as usize],
                )
            })
            .collect();
        // Every context frame's foreground shifted by ±STEP along each axis, background 0:
        // batch entry (frame · 3 + k) · 2 + (0: +, 1: −).
        let mut shifted = Vec::with_capacity(context_frames * 6 * 3 * plane);
        for frame in maps.chunks_exact(3 * plane) {
            for k in 0..3 {
                for sign in [1.0, -1.0] {
                    let mut map = vec![0.0; 3 * plane];
                    for &p in &bundle.pixels {
                        for c in 0..3 {
                            let i = c * plane + p as usize;
                            map[i] = frame[i] + if c == k { sign * STEP } else { 0.0 };
                        }
                    }
                    shifted.extend(map);
                }
            }
        }
        let batch = 6 * context_frames;
        let mut r = Recorder::new(gpu, pipelines, precision);
        let input = r.upload("recentre.maps", &[batch, 3, size, size], &shifted)?;
        let means = bundle.encoder.forward(&mut r, &input)?;
        r.submit();
        let means = means.read(gpu)?;
        let latent = means.len() / batch;
        let factor = bundle.manifest.latent_scale / (2.0 * STEP * context_frames as f32);
        let mut jacobian = vec![0.0; 3 * latent];
        for (k, j) in jacobian.chunks_exact_mut(latent).enumerate() {
            for frame in 0..context_frames {
                let entry = |sign: usize| &means[((frame * 3 + k) * 2 + sign) * latent..][..latent];
                for (v, (a, b)) in j.iter_mut().zip(entry(0).iter().zip(entry(1))) {
                    *v += (a - b) * factor;
                }
            }
        }
        Ok(Self { jacobian, standing })
    }
}
