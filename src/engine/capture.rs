//! Recording a frame's plan ([`Engine::capture`]): the turn and encode of the context
//! window, the UNet's context pass and denoising steps, the decode, the frame state and
//! points, the splats with the refiner ([`record_splats`], also run alone on the standing
//! start), and the slide of the window — one captured [`Plan`](crate::gpu::plan::Plan)
//! per sampler setting.

use super::bundle::RootMotion;
use super::kernels::{self, PostParams};
use super::live::Live;
use super::{Engine, FramePlan, SPLIT_STEPS};
use crate::gpu::kernel::Precision;
use crate::gpu::{Bound, GpuError};
use crate::nn::refiner::Refiner;
use crate::nn::sampler::Sampling;
use crate::nn::{Recorder, Tensor};
use crate::splat::frame::SplatFrame;

impl Engine {
    pub(super) fn capture(&mut self, sampling: Sampling) -> Result<FramePlan, GpuError> {
        let live = &self.live;
        let bundle = &self.bundle;
        let guided = sampling.cfg_scale != 1.0;
        let mut r = Recorder::capture(&self.gpu, &mut self.pipelines, self.precision);
        r.set_kernels(self.kernels);
        if self.split {
            r.steps().limit_parts(SPLIT_STEPS);
        }
        let cfg = &bundle.unet.cfg;
        let points = bundle.pixels.len();
        let decoded_reference = bundle.manifest.root_motion == RootMotion::Decoded;
        let params = PostParams {
            points: points as u32,
            plane: (bundle.manifest.map_size * bundle.manifest.map_size) as u32,
            waist: bundle.waist.len() as u32,
            components: if self.pca { live.components as u32 } else { 0 },
            scale: bundle.manifest.normalisation.scale,
            frames: (cfg.frames - 1) as u32,
            decoded_reference: u32::from(decoded_reference),
            grounded: u32::from(bundle.manifest.grounded),
            stand: bundle.manifest.stand_per_frame(),
            reserved: 0,
        };
        // The context: the window's maps turned to the model's heading, encoded, scaled.
        r.stage("vae-encode");
        let grid = r.grid(live.maps.len());
        r.dispatch(
            &kernels::TURN,
            &params,
            &[
                &live.maps.buffer,
                &live.point_of,
                &live.heading,
                &live.next_maps.buffer,
            ],
            grid,
        );
        let means = bundle.encoder.forward(&mut r, &live.next_maps)?;
        let scale = bundle.manifest.latent_scale;
        let scaled = r.axpby(scale, &means, 0, 0.0, &means, 0, &means.shape)?;
        r.copy(
            &scaled.buffer,
            &live.context.buffer,
            live.context.buffer.size(),
        );
        r.boundary();
        let actions = r.indices("engine.actions", &vec![0; if guided { 2 } else { 1 }])?;
        let latent =
            bundle.generate_with(&mut r, &live.context, &actions, &live.noise, sampling)?;
        r.boundary();
        r.stage("vae-decode");
        let map = bundle.decode(&mut r, &latent)?;
        // The root motion's reference: the last context latent decoded (or, measured
        // from the centre, the map itself, bound and unread).
        let reference = if decoded_reference {
            Some(bundle.decode_frame(&mut r, &live.context, cfg.frames - 2)?)
        } else {
            None
        };
        r.stage("geometry");
        let one = crate::gpu::kernel::Grid { x: 1, y: 1 };
        r.dispatch(
            &kernels::FRAME_UNIT,
            &params,
            &[
                &map.buffer,
                &live.pixels,
                &live.waist,
                &live.unit,
                &live.state,
                &reference.as_ref().unwrap_or(&map).buffer,
                &live.heading,
            ],
            one,
        );
        r.steps().copy_to_texels(&live.unit, &live.unit_texels);
        if self.pca {
            // For GPUs a workgroup per component (its threads split the sum), else a
            // thread per component.
            let (kernel, grid) = if r.kernels() == crate::nn::Kernels::Gpu {
                (
                    &kernels::PCA_COEFFICIENTS_SPLIT,
                    r.workgroups(live.components),
                )
            } else {
                (&kernels::PCA_COEFFICIENTS, r.grid(live.components))
            };
            r.steps().dispatch_bound(
                kernel,
                &params,
                &[
                    Bound::Texels(&live.unit_texels),
                    Bound::Texels(&live.mean),
                    Bound::Texels(&live.basis),
                    Bound::Buffer(&live.state),
                    Bound::Buffer(&live.coefficients),
                ],
                grid,
            );
            r.steps()
                .copy_to_texels(&live.coefficients, &live.coefficient_texels);
        }
        let grid = r.grid((3 * points).div_ceil(4));
        r.steps().dispatch_bound(
            &kernels::FRAME_POINTS,
            &params,
            &[
                Bound::Texels(&live.unit_texels),
                Bound::Texels(&live.mean),
                Bound::Texels(&live.basis),
                Bound::Buffer(&live.state),
                Bound::Texels(&live.coefficient_texels),
                Bound::Buffer(&live.points),
            ],
            grid,
        );
        if let Some(splats) = &self.splats {
            r.boundary();
            record_splats(
                &mut r,
                splats,
                bundle.refiner.as_ref(),
                live,
                self.precision,
            )?;
        }
        r.stage("geometry");
        let grid = r.grid(live.maps.len());
        r.dispatch(
            &kernels::SLIDE,
            &params,
            &[
                &live.maps.buffer,
                &live.unit,
                &live.point_of,
                &live.state,
                &live.next_maps.buffer,
            ],
            grid,
        );
        r.copy(
            &live.next_maps.buffer,
            &live.maps.buffer,
            live.maps.buffer.size(),
        );
        Ok(FramePlan {
            plan: r.finish(),
            actions,
            guided,
            sampling,
            pca: self.pca,
            look: self.splats.as_ref().map(|s| (s.level(), s.refines())),
        })
    }
}

/// Records the splats of the frame's drawn points (`live.points`) into `splats`' buffer:
/// the 128² stage, the refiner on the inputs it makes where it refines, and the splats at
/// its level. The frame plan records it after the decode; [`Engine::draw_standing`] alone.
pub(super) fn record_splats(
    r: &mut Recorder,
    splats: &SplatFrame,
    refiner: Option<&Refiner>,
    live: &Live,
    precision: Precision,
) -> Result<(), GpuError> {
    r.stage("splats");
    let residuals = match (splats.record_coarse(r.steps(), &live.points), refiner) {
        (Some(inputs), Some(refiner)) => {
            let features = Tensor::from_buffer(
                inputs.features.clone(),
                &[inputs.points, crate::splat::frame::FEATURES],
                precision,
            );
            r.stage("refiner");
            let o = inputs.orders;
            let residuals = refiner.forward(r, &features, &o.fine, &o.coarse, &o.groups)?;
            r.stage("splats");
            Some(residuals)
        }
        _ => None,
    };
    splats.record_finish(
        r.steps(),
        &live.points,
        residuals.as_ref().map(|t| &t.buffer),
    );
    Ok(())
}
