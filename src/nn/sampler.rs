//! The diffusion schedule and the DDIM sampler with classifier-free guidance
//! (train/unica_train/diffusion.py), recorded on the GPU: one generated frame is the
//! context pass plus `steps` target passes and updates, with no readback in between.

use serde::Deserialize;

use super::Tensor;
use super::ops::Recorder;
use super::unet::{ActionIds, UNet};
use crate::action::Action;
use crate::gpu::GpuError;

/// The training noise schedule, as the bundle manifest's `diffusion` entry.
#[derive(Clone, Debug, Deserialize, PartialEq)]
pub struct DiffusionConfig {
    pub steps: usize,
    pub beta_start: f64,
    pub beta_end: f64,
    pub schedule: String,
    pub prediction: String,
}

/// ᾱ_t of a scaled-linear DDPM schedule.
#[derive(Clone, Debug)]
pub struct Schedule {
    alphas_cumprod: Vec<f32>,
}

impl Schedule {
    /// β_t = (√β₀ + t/(T-1)·(√β₁ - √β₀))² in f64, ᾱ_t = Π(1 - β) stored as f32 (as the
    /// trainer).
    pub fn scaled_linear(steps: usize, beta_start: f64, beta_end: f64) -> Self {
        let (a, b) = (beta_start.sqrt(), beta_end.sqrt());
        let mut product = 1.0f64;
        let alphas_cumprod = (0..steps)
            .map(|t| {
                let root = a + (b - a) * t as f64 / (steps - 1) as f64;
                product *= 1.0 - root * root;
                product as f32
            })
            .collect();
        Self { alphas_cumprod }
    }

    pub fn steps(&self) -> usize {
        self.alphas_cumprod.len()
    }

    /// ᾱ_t; t = -1 means no noise (ᾱ = 1).
    pub fn alpha_bar(&self, t: i64) -> f64 {
        if t < 0 {
            1.0
        } else {
            self.alphas_cumprod[t as usize] as f64
        }
    }

    /// `count` evenly spaced timesteps from high to low, as the trainer's DDIM.
    pub fn ddim_timesteps(&self, count: usize) -> Vec<i64> {
        let stride = self.steps() / count;
        (0..count)
            .map(|i| (self.steps() - 1 - i * stride) as i64)
            .collect()
    }

    /// (a, b) of the deterministic DDIM step x_prev = a·x_t + b·ε from t to t_prev:
    /// x₀ = (x_t - √(1-ᾱ_t) ε)/√ᾱ_t, x_prev = √ᾱ_prev x₀ + √(1-ᾱ_prev) ε.
    pub fn ddim_coefficients(&self, t: i64, t_prev: i64) -> (f32, f32) {
        let (a_t, a_prev) = (self.alpha_bar(t), self.alpha_bar(t_prev));
        let a = (a_prev / a_t).sqrt();
        let b = (1.0 - a_prev).sqrt() - (a_prev * (1.0 - a_t) / a_t).sqrt();
        (a as f32, b as f32)
    }
}

/// How a frame is sampled: DDIM steps and the guidance scale (1 = no guidance, one
/// batch; otherwise the conditional and the null action run in one batch of two).
/// With `guide_idle` false an Idle frame takes the conditional prediction alone: its
/// second half runs Idle instead of the null action, so null + s·(cond − null) = cond
/// (guidance away from the null action's average motion made a standing avatar creep).
/// `idle_cfg_scale`, where set, is Idle's own guidance scale when the sampler guides,
/// and overrides `guide_idle` (1.5 brings the Witch to rest as the teacher does; see
/// [`Sampling::for_action`]). The starting noise is standard normal times
/// `noise_scale`. Bundles without these settings guide Idle as the keys and use noise
/// scale 1. A live loop brakes where `idle_brake_cfg_scale` is set: the first
/// `idle_brake_frames` Idle frames after a key are guided at that scale (at 1.5 alone
/// the Witch glided 1.2 m after A; see [`Sampling::for_frame`]). It brakes turns where
/// `turn_brake_cfg_scale` is set: the first `turn_brake_frames` frames under a movement
/// key of another direction than the last one ([`turn_run`]) are guided at that scale
/// (guidance speeds a turn up: the Witch's 90° turn took 3 frames at CFG 2 and 10 at 1,
/// 4 DDIM steps, against her teacher's 7).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
pub struct Sampling {
    #[serde(rename = "ddim_steps")]
    pub steps: usize,
    pub cfg_scale: f32,
    #[serde(default = "yes")]
    pub guide_idle: bool,
    #[serde(default = "one")]
    pub noise_scale: f32,
    #[serde(default)]
    pub idle_cfg_scale: Option<f32>,
    #[serde(default)]
    pub idle_brake_cfg_scale: Option<f32>,
    #[serde(default)]
    pub idle_brake_frames: u32,
    #[serde(default)]
    pub turn_brake_cfg_scale: Option<f32>,
    #[serde(default)]
    pub turn_brake_frames: u32,
    /// Which model runs the frame: the DDIM sampler above, or the student distilled from
    /// it (`one_pass`), which makes a frame in one conditional pass.
    #[serde(default)]
    pub kind: SamplerKind,
}

/// The sampler a bundle runs by default (its manifest's `sampler.kind`). `OnePass`: the
/// student UNet (`student.*`, train/unica_train/distil.py) makes the frame in one DDIM
/// step from t = 999, conditional only, from the same starting noise; the manifest's
/// steps and guidance settings are the teacher's, which `--steps N` runs instead.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SamplerKind {
    #[default]
    Ddim,
    OnePass,
}

fn yes() -> bool {
    true
}

fn one() -> f32 {
    1.0
}

impl Sampling {
    /// `steps` DDIM steps at guidance `cfg_scale`, Idle guided, noise scale 1.
    pub fn new(steps: usize, cfg_scale: f32) -> Self {
        Self {
            steps,
            cfg_scale,
            guide_idle: true,
            noise_scale: 1.0,
            idle_cfg_scale: None,
            idle_brake_cfg_scale: None,
            idle_brake_frames: 0,
            turn_brake_cfg_scale: None,
            turn_brake_frames: 0,
            kind: SamplerKind::Ddim,
        }
    }

    /// What a live loop runs by default: the distilled student's one conditional pass
    /// where the kind is `OnePass`, else this DDIM sampler as it is.
    pub fn live(&self) -> Sampling {
        match self.kind {
            SamplerKind::OnePass => Sampling {
                steps: 1,
                cfg_scale: 1.0,
                ..*self
            },
            SamplerKind::Ddim => *self,
        }
    }

    /// The teacher's DDIM sampler at `steps` steps with its own guidance settings.
    pub fn ddim(&self, steps: usize) -> Sampling {
        Sampling {
            kind: SamplerKind::Ddim,
            steps,
            ..*self
        }
    }

    /// The sampling a command line asks for: the live default where neither `steps` nor
    /// `cfg_scale` is given, else the teacher's DDIM sampler with those overrides.
    pub fn chosen(&self, steps: Option<usize>, cfg_scale: Option<f32>) -> Sampling {
        if steps.is_none() && cfg_scale.is_none() {
            return self.live();
        }
        Sampling {
            cfg_scale: cfg_scale.unwrap_or(self.cfg_scale),
            ..self.ddim(steps.unwrap_or(self.steps))
        }
    }

    /// UNet target passes per generated frame: one per step, two where the step is
    /// guided (the conditional and the null action as a batch of two). The context pass,
    /// once a frame, is not counted.
    pub fn unet_passes(&self) -> usize {
        self.steps * if self.cfg_scale != 1.0 { 2 } else { 1 }
    }

    /// The sampling a frame under `action` runs: an Idle frame of a guided sampler at
    /// `idle_cfg_scale` where set (guided against the null action), else unguided where
    /// `guide_idle` is false; every other frame as `self`. (The trainer's
    /// `diffusion.idle_scale`.)
    pub fn for_action(&self, action: Action) -> Sampling {
        if action != Action::Idle || self.cfg_scale == 1.0 {
            return *self;
        }
        match (self.idle_cfg_scale, self.guide_idle) {
            (Some(scale), _) => Sampling {
                cfg_scale: scale,
                guide_idle: true,
                idle_cfg_scale: None,
                ..*self
            },
            (None, false) => Sampling {
                cfg_scale: 1.0,
                guide_idle: true,
                ..*self
            },
            (None, true) => *self,
        }
    }

    /// The sampling Idle frames run where it differs in guidance from every other frame's
    /// (so a live loop needs a second plan for them); None where Idle frames run as the
    /// keys do.
    pub fn idle_plan(&self) -> Option<Sampling> {
        let idle = self.for_action(Action::Idle);
        (idle.cfg_scale != self.cfg_scale).then_some(idle)
    }

    /// This sampling at guidance `scale` with neither brake: the plan a braking frame
    /// runs.
    fn braked_at(&self, scale: f32) -> Sampling {
        Sampling {
            cfg_scale: scale,
            idle_brake_cfg_scale: None,
            idle_brake_frames: 0,
            turn_brake_cfg_scale: None,
            turn_brake_frames: 0,
            ..*self
        }
    }

    /// The sampling a braking Idle frame runs (guided at `idle_brake_cfg_scale` against
    /// the null action), where this sampler guides and brakes; else None.
    pub fn brake(&self) -> Option<Sampling> {
        match self.idle_brake_cfg_scale {
            Some(scale) if self.cfg_scale != 1.0 && self.idle_brake_frames > 0 => Some(Sampling {
                guide_idle: true,
                idle_cfg_scale: None,
                ..self.braked_at(scale)
            }),
            _ => None,
        }
    }

    /// The sampling a turning frame runs (guided at `turn_brake_cfg_scale` against the
    /// null action), where this sampler guides and brakes turns; else None.
    pub fn turn_brake(&self) -> Option<Sampling> {
        match self.turn_brake_cfg_scale {
            Some(scale) if self.cfg_scale != 1.0 && self.turn_brake_frames > 0 => {
                Some(self.braked_at(scale))
            }
            _ => None,
        }
    }

    /// Whether a movement frame at `run` (its [`turn_run`]) is among the first
    /// `turn_brake_frames` of a turn.
    pub fn turn_brakes(&self, run: KeyRun) -> bool {
        run.after_turn
            .is_some_and(|n| n >= 1 && n <= self.turn_brake_frames)
    }

    /// The sampling the frame under `action` at `run` (the run with this frame added)
    /// runs in a live loop: the first `idle_brake_frames` Idle frames after a key brake
    /// ([`Sampling::brake`]), the first `turn_brake_frames` frames of a turn brake it
    /// ([`Sampling::turn_brake`]), the others run as [`Sampling::for_action`]. (The
    /// trainer's `diffusion.frame_idle_scales` and `diffusion.frame_cfg_scales`.)
    pub fn for_frame(&self, action: Action, run: KeyRun) -> Sampling {
        match (self.brake(), self.turn_brake()) {
            (Some(brake), _) if action == Action::Idle && self.brakes(run) => brake,
            (_, Some(turn)) if action != Action::Idle && self.turn_brakes(run) => turn,
            _ => self.for_action(action),
        }
    }

    /// Whether an Idle frame at `run` (its [`idle_run`]: Idle frames after a key, this
    /// one counted) is among the first `idle_brake_frames`.
    pub fn brakes(&self, run: KeyRun) -> bool {
        run.after_key
            .is_some_and(|n| n >= 1 && n <= self.idle_brake_frames)
    }

    /// Whether this sampling fits a schedule of `schedule_steps` steps.
    pub fn check(&self, schedule_steps: usize) -> Result<(), String> {
        if self.steps == 0 || self.steps > schedule_steps {
            Err(format!(
                "{} DDIM steps: between 1 and {schedule_steps} are possible",
                self.steps
            ))
        } else if !self.cfg_scale.is_finite() {
            Err(format!("CFG scale {} is not a number", self.cfg_scale))
        } else if self.idle_cfg_scale.is_some_and(|s| !s.is_finite()) {
            Err(format!(
                "Idle CFG scale {} is not a number",
                self.idle_cfg_scale.unwrap_or_default()
            ))
        } else if self.idle_brake_cfg_scale.is_some_and(|s| !s.is_finite()) {
            Err(format!(
                "Idle braking CFG scale {} is not a number",
                self.idle_brake_cfg_scale.unwrap_or_default()
            ))
        } else if self.turn_brake_cfg_scale.is_some_and(|s| !s.is_finite()) {
            Err(format!(
                "turn braking CFG scale {} is not a number",
                self.turn_brake_cfg_scale.unwrap_or_default()
            ))
        } else if !(self.noise_scale.is_finite() && self.noise_scale > 0.0) {
            Err(format!(
                "noise scale {}: a positive number is needed",
                self.noise_scale
            ))
        } else {
            Ok(())
        }
    }

    /// The action id that pairs with `id` in a guided batch's second half: the null
    /// action, or Idle itself for Idle when Idle frames are unguided
    /// ([`Sampling::for_action`]).
    pub fn partner(&self, id: usize, null: usize) -> usize {
        if id == Action::Idle.id() as usize && self.for_action(Action::Idle).cfg_scale == 1.0 {
            id
        } else {
            null
        }
    }
}

/// The Idle frames since the last key, this one counted, for a frame under `action` after
/// a frame with `previous` (None before any key: a standing start never brakes; a key
/// gives Some(0)).
pub fn idle_run(previous: Option<u32>, action: Action) -> Option<u32> {
    match action {
        Action::Idle => previous.map(|n| n.saturating_add(1)),
        _ => Some(0),
    }
}

/// The frames of a turn, this one counted, for a frame under `action` after a frame
/// with `previous`, `last_key` being the last movement key before this frame (W before
/// any key: a standing start faces W's way): Some(1) under a movement key of another
/// direction, one more under the same key, None under Idle (and under the same key
/// again after Idle: no turn).
pub fn turn_run(previous: Option<u32>, last_key: Action, action: Action) -> Option<u32> {
    match action {
        Action::Idle => None,
        key if key != last_key => Some(1),
        _ => previous.map(|n| n.saturating_add(1)),
    }
}

/// Where a frame stands in the keys: Idle frames since the last key ([`idle_run`]),
/// frames of the turn under way ([`turn_run`]) and the last movement key.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KeyRun {
    pub after_key: Option<u32>,
    pub after_turn: Option<u32>,
    pub last_key: Action,
}

impl Default for KeyRun {
    /// A standing start: no key yet, facing W's way.
    fn default() -> Self {
        Self {
            after_key: None,
            after_turn: None,
            last_key: Action::Forward,
        }
    }
}

impl KeyRun {
    /// The run with a frame under `action` added.
    pub fn then(self, action: Action) -> Self {
        Self {
            after_key: idle_run(self.after_key, action),
            after_turn: turn_run(self.after_turn, self.last_key, action),
            last_key: if action == Action::Idle {
                self.last_key
            } else {
                action
            },
        }
    }
}

/// Records the generation of the frame after `context` [N, F-1, C, H, W] under `actions`
/// (N ids) from `noise` [N, C, H, W]; returns its clean latents [N, C, H, W]. With
/// guidance, host ids get the null action appended; ids on the GPU must already hold
/// the whole batch (the N conditional ids, then N null ids).
pub fn sample_next<'a>(
    r: &mut Recorder,
    unet: &UNet,
    schedule: &Schedule,
    context: &Tensor,
    actions: impl Into<ActionIds<'a>>,
    noise: &Tensor,
    sampling: Sampling,
) -> Result<Tensor, GpuError> {
    let guided = sampling.cfg_scale != 1.0;
    let actions = actions.into();
    r.stage("unet-context");
    let context = if guided {
        r.concat(context, context, 0)?
    } else {
        context.clone()
    };
    let cache = match actions {
        ActionIds::Host(ids) if guided => {
            let null = unet.cfg.null_action();
            let second: Vec<usize> = ids.iter().map(|&id| sampling.partner(id, null)).collect();
            unet.context(r, &context, &[ids, &second].concat())?
        }
        _ => {
            assert_eq!(actions.len(), context.shape[0], "action ids for the batch");
            unet.context(r, &context, actions)?
        }
    };
    r.boundary();
    let times = schedule.ddim_timesteps(sampling.steps);
    let mut x = noise.clone();
    for (i, &t) in times.iter().enumerate() {
        let t_prev = times.get(i + 1).copied().unwrap_or(-1);
        r.stage("unet-target");
        let eps = guided_eps(r, unet, &x, t, &cache, sampling.cfg_scale)?;
        let (a, b) = schedule.ddim_coefficients(t, t_prev);
        x = r.axpby(a, &x, 0, b, &eps, 0, &noise.shape)?;
        r.boundary();
    }
    Ok(x)
}

/// The target frame's noise prediction at `t`; with guidance, null + s·(cond - null)
/// from the two halves of one batch.
pub fn guided_eps(
    r: &mut Recorder,
    unet: &UNet,
    x: &Tensor,
    t: i64,
    cache: &super::unet::ContextCache,
    cfg_scale: f32,
) -> Result<Tensor, GpuError> {
    if cfg_scale == 1.0 {
        return unet.next(r, x, t as f32, cache);
    }
    let doubled = r.concat(x, x, 0)?;
    let eps = unet.next(r, &doubled, t as f32, cache)?;
    r.axpby(cfg_scale, &eps, 0, 1.0 - cfg_scale, &eps, x.len(), &x.shape)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule() -> Schedule {
        Schedule::scaled_linear(1000, 0.00085, 0.012)
    }

    #[test]
    fn the_schedule_starts_and_ends_where_the_betas_say() {
        let s = schedule();
        assert!((s.alpha_bar(0) - (1.0 - 0.00085)).abs() < 1e-7);
        assert_eq!(s.alpha_bar(-1), 1.0);
        // ᾱ_999 of SD's schedule: 0.00466.
        assert!(
            (s.alpha_bar(999) - 0.004_660_5).abs() < 1e-6,
            "{}",
            s.alpha_bar(999)
        );
    }

    #[test]
    fn an_unguided_idle_runs_idle_in_the_null_half_and_old_manifests_guide_it() {
        let guided = Sampling::new(10, 4.0);
        let partners = |s: Sampling, ids: &[usize]| -> Vec<usize> {
            ids.iter().map(|&id| s.partner(id, 5)).collect()
        };
        assert_eq!(partners(guided, &[0, 1, 4]), [5, 5, 5]);
        let unguided = Sampling {
            guide_idle: false,
            ..guided
        };
        assert_eq!(partners(unguided, &[0, 1, 4, 0]), [0, 5, 5, 0]);
        let old: Sampling =
            serde_json::from_str(r#"{"ddim_steps": 10, "cfg_scale": 4.0}"#).unwrap();
        assert_eq!(old, guided);
        let new: Sampling = serde_json::from_str(
            r#"{"ddim_steps": 10, "cfg_scale": 4.0, "guide_idle": false, "noise_scale": 0.5}"#,
        )
        .unwrap();
        assert!(!new.guide_idle && new.noise_scale == 0.5);
        assert!(new.check(1000).is_ok());
        for bad in [0.0, -1.0, f32::NAN] {
            let e = Sampling {
                noise_scale: bad,
                ..new
            }
            .check(1000)
            .unwrap_err();
            assert!(e.contains("noise scale"), "{e}");
        }
    }

    #[test]
    fn idle_frames_take_their_own_scale_where_the_sampler_guides() {
        let keys = Sampling::new(10, 4.5);
        let at = |s: Sampling, a: Action| s.for_action(a).cfg_scale;
        // Guided Idle (older bundles): as the keys.
        assert_eq!(at(keys, Action::Idle), 4.5);
        // Unguided Idle: 1; an Idle scale overrides guide_idle; the keys keep theirs.
        let unguided = Sampling {
            guide_idle: false,
            ..keys
        };
        assert_eq!(at(unguided, Action::Idle), 1.0);
        let own = Sampling {
            idle_cfg_scale: Some(1.5),
            ..unguided
        };
        assert_eq!(at(own, Action::Idle), 1.5);
        assert_eq!(own.for_action(Action::Forward), own);
        // The Idle sampling pairs Idle with the null action (it is guided).
        assert_eq!(own.for_action(Action::Idle).partner(0, 5), 5);
        assert_eq!(unguided.partner(0, 5), 0);
        // An unguided sampler leaves Idle unguided whatever its scale.
        let plain = Sampling {
            cfg_scale: 1.0,
            ..own
        };
        assert_eq!(at(plain, Action::Idle), 1.0);
        // A second plan only where Idle's guidance differs from the keys'.
        assert_eq!(keys.idle_plan(), None);
        assert_eq!(plain.idle_plan(), None);
        assert_eq!(unguided.idle_plan().map(|s| s.cfg_scale), Some(1.0));
        assert_eq!(own.idle_plan(), Some(own.for_action(Action::Idle)));
        let same = Sampling {
            idle_cfg_scale: Some(4.5),
            ..own
        };
        assert_eq!(same.idle_plan(), None);
        let parsed: Sampling = serde_json::from_str(
            r#"{"ddim_steps": 10, "cfg_scale": 4.5, "guide_idle": false, "noise_scale": 0.5, "idle_cfg_scale": 1.5}"#,
        )
        .unwrap();
        assert_eq!(parsed.idle_cfg_scale, Some(1.5));
        let bad = Sampling {
            idle_cfg_scale: Some(f32::NAN),
            ..own
        };
        assert!(bad.check(1000).unwrap_err().contains("Idle CFG scale"));
    }

    #[test]
    fn the_first_idle_frames_after_a_key_brake() {
        let brakes = Sampling {
            guide_idle: false,
            idle_cfg_scale: Some(1.5),
            idle_brake_cfg_scale: Some(2.0),
            idle_brake_frames: 2,
            ..Sampling::new(10, 4.7)
        };
        // The trainer's test_the_first_idle_frames_after_a_key_brake: two Idle frames
        // before any key (not braked), W, three Idle (two braked), S, one Idle.
        use Action::{Backward as S, Forward as W, Idle as I};
        let mut run = KeyRun::default();
        let scales: Vec<f32> = [I, I, W, I, I, I, S, I]
            .iter()
            .map(|&a| {
                run = run.then(a);
                brakes.for_frame(a, run).cfg_scale
            })
            .collect();
        assert_eq!(scales, [1.5, 1.5, 4.7, 2.0, 2.0, 1.5, 4.7, 2.0]);
        // A braking frame is guided against the null action at the braking scale.
        let brake = brakes.brake().unwrap();
        assert_eq!(brake.cfg_scale, 2.0);
        assert_eq!(brake.partner(Action::Idle.id() as usize, 5), 5);
        // No braking without the setting, with no frames, or in an unguided sampler.
        for none in [
            Sampling {
                idle_brake_cfg_scale: None,
                ..brakes
            },
            Sampling {
                idle_brake_frames: 0,
                ..brakes
            },
            Sampling {
                cfg_scale: 1.0,
                ..brakes
            },
        ] {
            assert_eq!(none.brake(), None);
            let after_w = KeyRun::default().then(W).then(I);
            assert_eq!(none.for_frame(I, after_w), none.for_action(I));
        }
        let parsed: Sampling = serde_json::from_str(
            r#"{"ddim_steps": 10, "cfg_scale": 4.7, "idle_brake_cfg_scale": 2.0, "idle_brake_frames": 10}"#,
        )
        .unwrap();
        assert_eq!(
            (parsed.idle_brake_cfg_scale, parsed.idle_brake_frames),
            (Some(2.0), 10)
        );
        let bad = Sampling {
            idle_brake_cfg_scale: Some(f32::INFINITY),
            ..brakes
        };
        assert!(bad.check(1000).unwrap_err().contains("braking"));
    }

    #[test]
    fn the_first_frames_of_a_turn_brake() {
        let brakes = Sampling {
            guide_idle: false,
            idle_brake_cfg_scale: Some(0.75),
            idle_brake_frames: 1,
            turn_brake_cfg_scale: Some(1.25),
            turn_brake_frames: 2,
            ..Sampling::new(10, 2.0)
        };
        // The trainer's test_the_first_frames_of_a_turn_brake: W from rest (no turn), D
        // (a turn: two braked), Idle (one braked), D again (no turn), A, S after Idle.
        use Action::{Backward as S, Forward as W, Idle as I, Left as A, Right as D};
        let mut run = KeyRun::default();
        let scales: Vec<f32> = [W, W, D, D, D, I, I, D, A, A, A, I, S]
            .iter()
            .map(|&a| {
                run = run.then(a);
                brakes.for_frame(a, run).cfg_scale
            })
            .collect();
        assert_eq!(
            scales,
            [
                2.0, 2.0, 1.25, 1.25, 2.0, 0.75, 1.0, 2.0, 1.25, 1.25, 2.0, 0.75, 1.25
            ]
        );
        // A turning frame is guided against the null action at its own scale.
        let turn = brakes.turn_brake().unwrap();
        assert_eq!(turn.cfg_scale, 1.25);
        assert_eq!(turn.partner(Action::Right.id() as usize, 5), 5);
        // No braking without the setting, with no frames, or in an unguided sampler.
        for none in [
            Sampling {
                turn_brake_cfg_scale: None,
                ..brakes
            },
            Sampling {
                turn_brake_frames: 0,
                ..brakes
            },
            Sampling {
                cfg_scale: 1.0,
                ..brakes
            },
        ] {
            assert_eq!(none.turn_brake(), None);
            assert_eq!(
                none.for_frame(D, KeyRun::default().then(D)),
                none.for_action(D)
            );
        }
        let parsed: Sampling = serde_json::from_str(
            r#"{"ddim_steps": 10, "cfg_scale": 2.0, "turn_brake_cfg_scale": 1.25, "turn_brake_frames": 8}"#,
        )
        .unwrap();
        assert_eq!(
            (parsed.turn_brake_cfg_scale, parsed.turn_brake_frames),
            (Some(1.25), 8)
        );
        let bad = Sampling {
            turn_brake_cfg_scale: Some(f32::NAN),
            ..brakes
        };
        assert!(bad.check(1000).unwrap_err().contains("turn braking"));
    }

    #[test]
    fn a_one_pass_bundle_runs_one_unguided_pass_and_its_teacher_on_request() {
        let manifest: Sampling = serde_json::from_str(
            r#"{"ddim_steps": 10, "cfg_scale": 3.5, "idle_cfg_scale": 1.5,
                "idle_brake_cfg_scale": 5.0, "idle_brake_frames": 10,
                "turn_brake_cfg_scale": 1.5, "turn_brake_frames": 8, "kind": "one_pass"}"#,
        )
        .unwrap();
        assert_eq!(manifest.kind, SamplerKind::OnePass);
        let live = manifest.live();
        assert_eq!(
            (live.steps, live.cfg_scale, live.unet_passes()),
            (1, 1.0, 1)
        );
        // No Idle plan, no brakes: the student folded them in.
        assert_eq!(live.idle_plan(), None);
        assert_eq!(live.brake(), None);
        assert_eq!(live.turn_brake(), None);
        let released = KeyRun::default().then(Action::Forward).then(Action::Idle);
        assert_eq!(live.for_frame(Action::Idle, released), live);
        let turning = KeyRun::default().then(Action::Right);
        assert_eq!(live.for_frame(Action::Right, turning), live);
        // --steps N: the teacher's sampler with its guidance: 2 passes a step.
        let teacher = manifest.ddim(10);
        assert_eq!(teacher.kind, SamplerKind::Ddim);
        assert_eq!((teacher.unet_passes(), teacher.cfg_scale), (20, 3.5));
        assert_eq!(manifest.chosen(None, None), live);
        assert_eq!(manifest.chosen(Some(10), None), teacher);
        assert_eq!(manifest.chosen(None, Some(1.0)).unet_passes(), 10);
        assert_eq!(teacher.brake().map(|b| b.cfg_scale), Some(5.0));
        assert_eq!(teacher.turn_brake().map(|b| b.cfg_scale), Some(1.5));
        // Older manifests are DDIM and run as they are.
        let old: Sampling = serde_json::from_str(r#"{"ddim_steps": 2, "cfg_scale": 1.0}"#).unwrap();
        assert_eq!(
            (old.kind, old.live(), old.unet_passes()),
            (SamplerKind::Ddim, old, 2)
        );
        assert!(
            serde_json::from_str::<Sampling>(
                r#"{"ddim_steps": 2, "cfg_scale": 1.0, "kind": "two_pass"}"#
            )
            .is_err()
        );
    }

    #[test]
    fn ddim_timesteps_are_evenly_spaced_from_the_top() {
        let s = schedule();
        assert_eq!(s.ddim_timesteps(4), [999, 749, 499, 249]);
        assert_eq!(s.ddim_timesteps(10)[..3], [999, 899, 799]);
        assert_eq!(s.ddim_timesteps(1), [999]);
    }

    #[test]
    fn a_ddim_step_with_the_true_noise_lands_on_the_noised_sample() {
        // x_t = √ᾱ_t x0 + √(1-ᾱ_t) ε; given the true ε the step to t_prev must give
        // √ᾱ_prev x0 + √(1-ᾱ_prev) ε exactly, and to -1 the clean x0.
        let s = schedule();
        let (x0, eps) = (0.7f64, -1.3f64);
        for (t, t_prev) in [(999, 749), (700, 600), (249, -1), (0, -1)] {
            let x_t = s.alpha_bar(t).sqrt() * x0 + (1.0 - s.alpha_bar(t)).sqrt() * eps;
            let (a, b) = s.ddim_coefficients(t, t_prev);
            let got = a as f64 * x_t + b as f64 * eps;
            let want = s.alpha_bar(t_prev).sqrt() * x0 + (1.0 - s.alpha_bar(t_prev)).sqrt() * eps;
            assert!((got - want).abs() < 1e-5, "{t}->{t_prev}: {got} vs {want}");
        }
    }
}
