//! Bundles (docs/architecture.md, Files), the trainer's output: `manifest.json` (format,
//! version, model configs, sampler defaults, normalisation) and `weights.safetensors`.
//! Loading refuses another format or version and names the first tensor whose name, dtype
//! or shape is not what the manifest's configs imply.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::action::Action;
use crate::files::HeldFolder;
use crate::gpu::kernel::Precision;
use crate::gpu::{GpuContext, GpuError};
use crate::nn::Tensor;
use crate::nn::ops::{MAX_HEAD_SIZE, Recorder};
use crate::nn::refiner::{Refiner, RefinerConfig};
use crate::nn::sampler::{self, DiffusionConfig, SamplerKind, Sampling, Schedule};
use crate::nn::unet::{ActionIds, UNet, UNetConfig};
use crate::nn::vae::{Decoder, Encoder, VaeConfig};
use crate::nn::weights::{self, LoadError, Weights};
use crate::splat::base::RESIDUALS;
use crate::splat::frame::FEATURES;
use crate::tensors::{TensorError, TensorFile};

pub const FORMAT: &str = "unica-bundle";
pub const VERSION: u64 = 1;
/// The most training noise steps a bundle may declare (the shipped one has 1,000).
pub const MAX_DIFFUSION_STEPS: usize = 100_000;

/// What the manifest says (unknown fields are ignored; `tensors` is checked through the
/// weights themselves).
#[derive(Clone, Debug, Deserialize)]
pub struct Manifest {
    pub avatar: String,
    pub actions: Vec<String>,
    pub vae: VaeConfig,
    pub unet: UNetConfig,
    pub diffusion: DiffusionConfig,
    pub sampler: Sampling,
    /// Latents the UNet sees are the VAE means times this.
    pub latent_scale: f32,
    pub frame_rate: f32,
    pub map_size: usize,
    pub normalisation: Normalisation,
    pub pca: PcaConfig,
    /// The splat refiner's config; bundles without one draw base splats only.
    #[serde(default)]
    pub refiner: Option<RefinerConfig>,
    /// What a live frame's root motion is measured from (older bundles: the centre).
    #[serde(default)]
    pub root_motion: RootMotion,
    /// Which way the live loop shows the model its window (older bundles: as it is).
    #[serde(default)]
    pub heading: Heading,
    /// The live loop's world root height: false (older bundles) integrates the root
    /// motion's height like its horizontal part; true puts each frame's lowest point on
    /// the floor (y = 0, where the standing start's lowest point is) instead. The window
    /// is root-centred in height too, so integrated heights carry the model's errors:
    /// integrated, the Witch measured sinking 0.15-0.17 m over each 270-frame key script
    /// (at 180° turns and starts), about 1 m in 2,000 frames; grounded, the height has
    /// nothing to accumulate.
    #[serde(default)]
    pub grounded: bool,
    /// The stand latch (m/s; older bundles: none): under Idle, once the horizontal root
    /// motion the loop measures is slower than this, the world root holds still until a
    /// movement key is pressed, as the teacher's controller brakes to exactly 0 and stays
    /// there. The frames are still generated and drawn; only their placement holds.
    /// Without it the Witch drifted 0.16-0.51 m over 300 idle frames (about 0.5-1.7 mm a
    /// frame, mostly backwards: a bias of the generated waist against the decoded
    /// context's), where her teacher moves 0.3 mm (docs/experiments/motion.md).
    #[serde(default)]
    pub stand_speed: Option<f32>,
}

impl Manifest {
    /// The stand latch's speed as a horizontal root motion per frame in normalised
    /// units (`PostParams::stand`); 0 where the bundle has none.
    pub fn stand_per_frame(&self) -> f32 {
        self.stand_speed
            .map_or(0.0, |s| s * self.normalisation.scale / self.frame_rate)
    }
}

/// What the live loop measures a new frame's root motion from. The window puts the last
/// context frame's root at 0.5, so `Centre` moves the world root by root(new) − 0.5.
/// `Decoded` moves it by root(new) − root(the last context latent decoded): a bias of
/// the decoder's root common to both frames cancels (measured under Idle, that bias was
/// a creep of 1.7-4 mm a frame that kept the root above 0.05 m/s). The window is
/// recentred on root(new) either way.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RootMotion {
    #[default]
    Centre,
    Decoded,
}

/// Which way the live loop turns the window before the model sees it. `World`: as it
/// is. `Canonical`: turned about the vertical by the quarter turns that take the last
/// movement key's direction to W's (+Z), the key turned with it (W for any held key; the
/// trainer's `dataset.quarter_turn`, the symmetry the UNet is trained with), and the new
/// frame turned back. The model then always walks, stops and starts facing +Z, the
/// direction it does best: shown the world as it is, the Witch measured creeping
/// 0.07-0.08 m/s after A on two of three seeds; turned, she stopped within 10-11 frames
/// after every key.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Heading {
    #[default]
    World,
    Canonical,
}

/// Group normalisation (docs/architecture.md, Position maps): normalised = (world - root)
/// · scale + 0.5.
#[derive(Clone, Debug, Deserialize)]
pub struct Normalisation {
    pub scale: f32,
}

#[derive(Clone, Debug, Deserialize)]
pub struct PcaConfig {
    pub components: usize,
}

/// A loaded bundle: the models on the GPU and what the sampler needs.
pub struct Bundle {
    pub dir: PathBuf,
    pub manifest: Manifest,
    pub encoder: Encoder,
    pub decoder: Decoder,
    pub unet: UNet,
    /// The student distilled from `unet`'s sampler (`student.*`), where the manifest's
    /// sampler kind is `one_pass`: it makes a frame in one pass.
    pub student: Option<UNet>,
    pub schedule: Schedule,
    /// The standing start's context, [frames - 1, latent, h, w], already scaled.
    pub context: Tensor,
    /// The map's foreground pixels (row-major indices) and the waist pixels among them
    /// (indices into `pixels`), whose mean is the root.
    pub pixels: Vec<u32>,
    pub waist: Vec<u32>,
    /// The PCA of root-centred normalised frames: mean [3·pixels], basis [components,
    /// 3·pixels] (orthonormal rows), point-major xyz.
    pub pca_mean: Vec<f32>,
    pub pca_basis: Vec<f32>,
    /// Each foreground pixel's linear RGB (`map.colors`; bundles from before the trainer
    /// wrote it have none).
    pub colors: Option<Vec<glam::Vec3>>,
    pub refiner: Option<Refiner>,
}

impl Bundle {
    pub fn load(dir: &Path, gpu: &GpuContext, precision: Precision) -> Result<Self, LoadError> {
        // Both files from one held folder: a bundle replaced whole while it loads gives
        // the old or the new one, never the manifest of one and the weights of the other.
        let folder = HeldFolder::open(dir).map_err(|e| LoadError::Manifest {
            path: dir.display().to_string(),
            problem: e.to_string(),
        })?;
        let manifest_path = folder.path("manifest.json");
        let manifest = folder
            .read("manifest.json")
            .map_err(|e| e.to_string())
            .and_then(|bytes| String::from_utf8(bytes).map_err(|e| e.to_string()))
            .map_err(|problem| LoadError::Manifest {
                path: manifest_path.display().to_string(),
                problem,
            })
            .and_then(|text| parse_manifest(&text, &manifest_path))?;
        let weights_path = folder.path("weights.safetensors");
        let bytes = folder
            .read("weights.safetensors")
            .map_err(|e| TensorError {
                path: weights_path.clone(),
                problem: e.to_string(),
            })?;
        let file = TensorFile::from_bytes(&weights_path, bytes)?;
        let w = Weights::new(&file, gpu, precision);
        let (vae, unet) = (&manifest.vae, &manifest.unet);
        let side = manifest.map_size / 8;
        let pixels = indices(&file, "map.pixels", manifest.map_size * manifest.map_size)?;
        let waist = indices(&file, "map.waist", pixels.len())?;
        let values = 3 * pixels.len();
        let pca_mean = w.host("pca.mean", &[values])?;
        let pca_basis = w.host("pca.basis", &[manifest.pca.components, values])?;
        let colors = if file.contains("map.colors") {
            let rgb = w.host("map.colors", &[pixels.len(), 3])?;
            Some(rgb.chunks_exact(3).map(glam::Vec3::from_slice).collect())
        } else {
            None
        };
        if let Some(rows) = manifest
            .refiner
            .as_ref()
            .map(|cfg| cfg.pixel_residuals)
            .filter(|&rows| rows != 0 && rows != pixels.len())
        {
            return Err(LoadError::Manifest {
                path: file.path().display().to_string(),
                problem: format!(
                    "the refiner's pixel_residuals ({rows}) are not the map's {} foreground pixels",
                    pixels.len()
                ),
            });
        }
        let refiner = manifest
            .refiner
            .as_ref()
            .map(|cfg| Refiner::load(&w.at("refiner"), cfg, FEATURES, RESIDUALS))
            .transpose()?;
        let decoder = Decoder::load(&w.at("vae.decoder"), vae)?;
        if decoder.pixels().is_some_and(|p| p != pixels) {
            return Err(LoadError::Manifest {
                path: file.path().display().to_string(),
                problem: "the VAE decoder's pixels ('vae.decoder.pixels') are not the map's ('map.pixels')".into(),
            });
        }
        Ok(Self {
            colors,
            refiner,
            pixels,
            waist,
            pca_mean,
            pca_basis,
            encoder: Encoder::load(&w.at("vae.encoder"), vae)?,
            decoder,
            unet: UNet::load(&w.at("unet"), unet)?,
            student: match manifest.sampler.kind {
                SamplerKind::OnePass => Some(UNet::load(&w.at("student"), unet)?),
                SamplerKind::Ddim => None,
            },
            schedule: Schedule::scaled_linear(
                manifest.diffusion.steps,
                manifest.diffusion.beta_start,
                manifest.diffusion.beta_end,
            ),
            context: w.tensor(
                "context.latents",
                &[unet.frames - 1, unet.latent, side, side],
            )?,
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// Records the generation of the frame after `context` [1, F-1, C, h, w] under
    /// `action` from `noise` [1, C, h, w] with `sampling` (as it applies to that action,
    /// [`Sampling::for_action`]); returns its latent.
    pub fn generate(
        &self,
        r: &mut Recorder,
        context: &Tensor,
        action: usize,
        noise: &Tensor,
        sampling: Sampling,
    ) -> Result<Tensor, GpuError> {
        let sampling = if action == Action::Idle.id() as usize {
            sampling.for_action(Action::Idle)
        } else {
            sampling
        };
        self.generate_with(r, context, &[action], noise, sampling)
    }

    /// [`Bundle::generate`] with the batch's action ids given as they are: on the host,
    /// or on the GPU (the action, then the null action when `sampling` is guided) so that
    /// a captured plan takes new actions.
    pub fn generate_with<'a>(
        &self,
        r: &mut Recorder,
        context: &Tensor,
        actions: impl Into<ActionIds<'a>>,
        noise: &Tensor,
        sampling: Sampling,
    ) -> Result<Tensor, GpuError> {
        sampler::sample_next(
            r,
            self.unet_for(sampling)?,
            &self.schedule,
            context,
            actions,
            noise,
            sampling,
        )
    }

    /// The sampler a live loop runs by default: the student's one pass where the bundle
    /// has one, else the manifest's DDIM sampler.
    pub fn live_sampling(&self) -> Sampling {
        self.manifest.sampler.live()
    }

    /// The UNet that runs `sampling`: the student for the one-pass kind, else the
    /// teacher. A one-pass sampling on a bundle without a student is refused.
    pub fn unet_for(&self, sampling: Sampling) -> Result<&UNet, GpuError> {
        match (sampling.kind, &self.student) {
            (SamplerKind::Ddim, _) => Ok(&self.unet),
            (SamplerKind::OnePass, Some(student)) => Ok(student),
            (SamplerKind::OnePass, None) => Err(GpuError::Invalid(format!(
                "{}: the one-pass sampler needs a distilled student ('student.*'), and this bundle has none",
                self.dir.display()
            ))),
        }
    }

    /// Records the decoding of UNet latents [N, C, h, w] into position maps.
    pub fn decode(&self, r: &mut Recorder, z: &Tensor) -> Result<Tensor, GpuError> {
        self.decode_at(r, z, 0, &z.shape)
    }

    /// Records the decoding of latent `frame` of a window [.., F, C, h, w] into one
    /// position map [1, 3, S, S].
    pub fn decode_frame(
        &self,
        r: &mut Recorder,
        window: &Tensor,
        frame: usize,
    ) -> Result<Tensor, GpuError> {
        let dims = &window.shape[window.shape.len() - 3..];
        let len: usize = dims.iter().product();
        self.decode_at(r, window, frame * len, &[1, dims[0], dims[1], dims[2]])
    }

    /// The latents of `shape` read from `z` at value `offset`, unscaled and decoded.
    fn decode_at(
        &self,
        r: &mut Recorder,
        z: &Tensor,
        offset: usize,
        shape: &[usize],
    ) -> Result<Tensor, GpuError> {
        let s = 1.0 / self.manifest.latent_scale;
        let unscaled = r.axpby(s, z, offset, 0.0, z, offset, shape)?;
        self.decoder.forward(r, &unscaled)
    }
}

/// A 1-D int32 tensor of indices, each below `bound`.
fn indices(file: &TensorFile, name: &str, bound: usize) -> Result<Vec<u32>, LoadError> {
    let (values, _) = file.i32(name, &[None])?;
    if values.is_empty() {
        return Err(LoadError::Manifest {
            path: file.path().display().to_string(),
            problem: format!("'{name}' is empty"),
        });
    }
    weights::below(values, bound).map_err(|problem| LoadError::Manifest {
        path: file.path().display().to_string(),
        problem: format!("'{name}' {problem}"),
    })
}

/// Reads and checks a manifest: format and version first (so a future version gets that
/// message, not a field error), then the fields and what this engine supports.
pub fn read_manifest(path: &Path) -> Result<Manifest, LoadError> {
    let text = std::fs::read_to_string(path).map_err(|e| LoadError::Manifest {
        path: path.display().to_string(),
        problem: e.to_string(),
    })?;
    parse_manifest(&text, path)
}

/// `read_manifest` on text already read from `path`.
pub fn parse_manifest(text: &str, path: &Path) -> Result<Manifest, LoadError> {
    let fail = |problem: String| LoadError::Manifest {
        path: path.display().to_string(),
        problem,
    };
    let value: serde_json::Value =
        serde_json::from_str(text).map_err(|e| fail(format!("not JSON: {e}")))?;
    let format = value.get("format").and_then(|f| f.as_str()).unwrap_or("");
    if format != FORMAT {
        return Err(fail(format!(
            "not a unica bundle (format '{format}', expected '{FORMAT}')"
        )));
    }
    match value.get("version").and_then(|v| v.as_u64()) {
        Some(VERSION) => {}
        Some(v) => {
            return Err(fail(format!(
                "bundle version {v}, this build reads version {VERSION}"
            )));
        }
        None => {
            return Err(fail(match value.get("version") {
                Some(v) => format!("bundle version {v} is not a whole number (expected {VERSION})"),
                None => "no bundle version".into(),
            }));
        }
    }
    let manifest: Manifest = serde_json::from_value(value).map_err(|e| fail(e.to_string()))?;
    let (unet, diffusion) = (&manifest.unet, &manifest.diffusion);
    let names: Vec<String> = crate::action::Action::ALL
        .iter()
        .map(|a| a.to_string())
        .collect();
    let positive = |x: f64| x.is_finite() && x > 0.0;
    let problem = if !(2..=MAX_DIFFUSION_STEPS).contains(&diffusion.steps) {
        Some(format!(
            "diffusion.steps {}: between 2 and {MAX_DIFFUSION_STEPS} are possible",
            diffusion.steps
        ))
    } else if !(positive(diffusion.beta_start)
        && positive(diffusion.beta_end)
        && diffusion.beta_start <= diffusion.beta_end
        && diffusion.beta_end < 1.0)
    {
        Some(format!(
            "diffusion betas {} to {}: 0 < beta_start <= beta_end < 1 is needed",
            diffusion.beta_start, diffusion.beta_end
        ))
    } else if !positive(manifest.latent_scale as f64) {
        Some(format!(
            "latent_scale {} is not a positive number",
            manifest.latent_scale
        ))
    } else if !positive(manifest.normalisation.scale as f64) {
        Some(format!(
            "normalisation.scale {} is not a positive number",
            manifest.normalisation.scale
        ))
    } else if !positive(manifest.frame_rate as f64) {
        Some(format!(
            "frame_rate {} is not a positive number",
            manifest.frame_rate
        ))
    } else if let Some(s) = manifest.stand_speed
        && !positive(s as f64)
    {
        Some(format!("stand_speed {s} is not a positive number"))
    } else if diffusion.schedule != "scaled_linear" || diffusion.prediction != "epsilon" {
        Some(format!(
            "diffusion '{}' with '{}' prediction; this engine runs scaled_linear with epsilon",
            diffusion.schedule, diffusion.prediction
        ))
    } else if manifest.actions != names || unet.actions != names.len() {
        Some(format!(
            "actions {:?} ({} in the UNet); this engine drives {names:?}",
            manifest.actions, unet.actions
        ))
    } else if unet.frames < 2 {
        Some(format!(
            "groups of {} frames; at least 2 are needed",
            unet.frames
        ))
    } else if unet.heads == 0 || unet.embed == 0 || unet.embed % 2 != 0 {
        Some(format!(
            "{} heads and a {}-value embedding: at least one head and an even embedding are needed",
            unet.heads, unet.embed
        ))
    } else if unet
        .channels
        .iter()
        .any(|c| c % unet.heads != 0 || c / unet.heads > MAX_HEAD_SIZE)
    {
        Some(format!(
            "channels {:?} in {} heads: each head must be a whole number of at most {MAX_HEAD_SIZE} channels",
            unet.channels, unet.heads
        ))
    } else if manifest.map_size != 128 {
        Some(format!(
            "position maps of {} pixels; this engine's VAE layout is 128",
            manifest.map_size
        ))
    } else if let Some(Err(problem)) = manifest.refiner.as_ref().map(RefinerConfig::check) {
        Some(problem)
    } else {
        manifest.sampler.check(diffusion.steps).err()
    };
    match problem {
        Some(p) => Err(fail(p)),
        None => Ok(manifest),
    }
}
