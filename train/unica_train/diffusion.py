"""The diffusion process (docs/architecture.md, The geometry model): scaled-linear DDPM betas 0.00085-0.012 over 1000
steps, epsilon prediction, Min-SNR weights, noise offset; the DDIM sampler with real
classifier-free guidance (conditional and null action in one batch), optionally only over
the first `guided_steps` DDIM steps (a guidance interval: measured, it keeps generated
poses closer but loses the keys, so the engine guides every step;
docs/records/witch/README.md). Two more sampler settings: `guide_idle` false samples Idle
frames from the conditional prediction alone (guidance away from the null action's
average motion pushed a standing avatar backwards: she crept), and `noise_scale` draws
the starting noise at that temperature (less jitter at rest). `idle_cfg_scale`, where
set, is the guidance scale of Idle samples in guided steps instead (1.5 for the Witch:
with the window re-encoded, unguided she glided on for 20 frames, guided at 4.5 she
stopped in two frames and then crept). The live loop also brakes: the first
`idle_brake_frames` Idle frames after a key are guided at `idle_brake_cfg_scale`
(`frame_idle_scales`; the Witch at 1.5 glided 1.2 m after A and never stopped, braked at
2.0 for 10 frames she stops as the teacher does)."""

from __future__ import annotations

import torch

from .dataset import ACTIONS

STEPS = 1000
IDLE = ACTIONS.index("Idle")
FORWARD = ACTIONS.index("Forward")


class Schedule:
    def __init__(self, steps: int = STEPS, beta_start: float = 0.00085, beta_end: float = 0.012):
        self.steps = steps
        betas = torch.linspace(beta_start**0.5, beta_end**0.5, steps, dtype=torch.float64) ** 2
        self.alphas_cumprod = torch.cumprod(1 - betas, 0).float()

    def alpha_bar(self, t: torch.Tensor) -> torch.Tensor:
        """ᾱ_t for integer timesteps; t = -1 means no noise (ᾱ = 1)."""
        a = self.alphas_cumprod.to(t.device)[t.clamp(min=0)]
        return torch.where(t < 0, torch.ones_like(a), a)

    def add_noise(self, x0, noise, t):
        a = self.alpha_bar(t)
        while a.dim() < x0.dim():
            a = a[..., None]
        return a.sqrt() * x0 + (1 - a).sqrt() * noise

    def min_snr_weight(self, t, gamma: float = 5.0):
        """Min-SNR-γ loss weight for epsilon prediction: min(SNR, γ) / SNR."""
        a = self.alpha_bar(t)
        snr = a / (1 - a)
        return snr.clamp(max=gamma) / snr

    def ddim_timesteps(self, count: int) -> list[int]:
        """`count` evenly spaced timesteps from high to low (as the reference's DDIM)."""
        stride = self.steps // count
        return list(range(self.steps - 1, -1, -stride))[:count]


def ddim_step(schedule: Schedule, x_t, eps, t: int, t_prev: int):
    """One deterministic DDIM step from t to t_prev (t_prev = -1: to the clean sample)."""
    a_t = schedule.alpha_bar(torch.tensor(t))
    a_prev = schedule.alpha_bar(torch.tensor(t_prev))
    x0 = (x_t - (1 - a_t).sqrt() * eps) / a_t.sqrt()
    return a_prev.sqrt() * x0 + (1 - a_prev).sqrt() * eps


def idle_scale(cfg_scale: float, guide_idle: bool = True, idle_cfg_scale: float | None = None) -> float:
    """The guidance scale of an Idle sample in a step guided by `cfg_scale`: 1 in an
    unguided step; else `idle_cfg_scale` where set, else `cfg_scale`, or 1 with
    `guide_idle` false."""
    if cfg_scale == 1.0:
        return 1.0
    if idle_cfg_scale is not None:
        return float(idle_cfg_scale)
    return float(cfg_scale) if guide_idle else 1.0


def guided_eps(model, latents, t_frames, action, cfg_scale: float, guide_idle: bool = True,
               idle_cfg_scale: float | None = None):
    """The target frame's noise prediction with classifier-free guidance: the conditional
    and the null action run in one batch; eps = null + s (cond - null), s = `cfg_scale`,
    for Idle samples `idle_scale(...)` (s = 1: the conditional prediction alone)."""
    b = latents.shape[0]
    if cfg_scale == 1.0:
        return model(latents, t_frames, action)[:, -1]
    null = torch.full_like(action, model.cfg.actions)
    eps = model(latents.repeat(2, 1, 1, 1, 1), t_frames.repeat(2, 1), torch.cat([action, null]))[:, -1]
    cond, uncond = eps[:b], eps[b:]
    scale = torch.full((b,), float(cfg_scale), dtype=eps.dtype, device=eps.device)
    scale[action == IDLE] = idle_scale(cfg_scale, guide_idle, idle_cfg_scale)
    return uncond + scale.view(b, *[1] * (eps.dim() - 1)) * (cond - uncond)


def step_scales(steps: int, cfg_scale: float, guided_steps: int | None = None) -> list[float]:
    """The guidance scale of each DDIM step: `cfg_scale` for the first `guided_steps`
    (None: all), 1 (the conditional prediction alone) after them."""
    guided = steps if guided_steps is None else min(guided_steps, steps)
    return [cfg_scale] * guided + [1.0] * (steps - guided)


@torch.no_grad()
def sample_next(model, schedule: Schedule, context, action, steps: int = 10, cfg_scale: float = 1.0, noise=None, generator=None,
                guided_steps: int | None = None, guide_idle: bool = True, noise_scale: float = 1.0,
                idle_cfg_scale: float | None = None):
    """Generates the 4th latent frame from 3 clean context latents [B, 3, C, H, W]; guided
    by `cfg_scale` over the first `guided_steps` steps (None: all), Idle samples at
    `idle_scale(...)`; from `noise`, else from standard normal noise times
    `noise_scale`."""
    b, device = context.shape[0], context.device
    x = noise if noise is not None else noise_scale * torch.randn(context[:, :1].shape, generator=generator)[:, 0]
    x, action = x.to(device), action.to(device)
    times = schedule.ddim_timesteps(steps)
    scales = step_scales(steps, cfg_scale, guided_steps)
    for i, t in enumerate(times):
        t_prev = times[i + 1] if i + 1 < len(times) else -1
        latents = torch.cat([context, x[:, None]], 1)
        t_frames = torch.tensor([[0, 0, 0, t]] * b, device=device)
        eps = guided_eps(model, latents, t_frames, action, scales[i], guide_idle, idle_cfg_scale)
        x = ddim_step(schedule, x, eps, t, t_prev)
    return x


def sampler_options(sampler: dict) -> dict:
    """The keyword arguments of `sample_next` a bundle manifest's `sampler` entry sets
    beyond its steps and CFG scale (older bundles: guide Idle, noise scale 1, no Idle
    scale of its own)."""
    idle = sampler.get("idle_cfg_scale")
    return {"guide_idle": bool(sampler.get("guide_idle", True)), "noise_scale": float(sampler.get("noise_scale", 1.0)),
            "idle_cfg_scale": None if idle is None else float(idle)}


def brake_options(sampler: dict) -> dict:
    """The live loop's braking settings of a bundle manifest's `sampler` entry (none in
    older bundles): the first `idle_brake_frames` Idle frames after a key are guided at
    `idle_brake_cfg_scale`."""
    brake = sampler.get("idle_brake_cfg_scale")
    return {"idle_brake_cfg_scale": None if brake is None else float(brake),
            "idle_brake_frames": int(sampler.get("idle_brake_frames", 0))}


def frame_idle_scales(actions: list[int], idle_cfg_scale: float | None, idle_brake_cfg_scale: float | None = None,
                      idle_brake_frames: int = 0) -> list[float | None]:
    """The Idle guidance scale (`sample_next`'s `idle_cfg_scale`) each frame of a key
    sequence samples with: `idle_brake_cfg_scale` for the first `idle_brake_frames` Idle
    frames after a key, else `idle_cfg_scale`. Idle before the first key (a standing
    start) is not braked. The engine's `Sampling::for_frame`."""
    out, since = [], None  # Idle frames since the last key; None before any key
    for a in actions:
        if a != IDLE:
            since = 0
        elif since is not None:
            since += 1
        braking = a == IDLE and idle_brake_cfg_scale is not None and since is not None and since <= idle_brake_frames
        out.append(idle_brake_cfg_scale if braking else idle_cfg_scale)
    return out


def turn_brake_options(sampler: dict) -> dict:
    """The live loop's turn-braking settings of a bundle manifest's `sampler` entry (none
    in older bundles): the first `turn_brake_frames` frames of a turn are guided at
    `turn_brake_cfg_scale`."""
    turn = sampler.get("turn_brake_cfg_scale")
    return {"turn_brake_cfg_scale": None if turn is None else float(turn),
            "turn_brake_frames": int(sampler.get("turn_brake_frames", 0))}


def turn_runs(actions: list[int]) -> list[int | None]:
    """The frames of the turn each frame of a key sequence is in, that frame counted: 1
    under a movement key of another direction than the last one (W before any key: a
    standing start faces W's way), one more under the same key, None under Idle and
    under the same key again after Idle. The engine's `sampler::turn_run`."""
    out, run, last = [], None, FORWARD
    for a in actions:
        if a == IDLE:
            run = None
        elif a != last:
            run, last = 1, a
        elif run is not None:
            run += 1
        out.append(run)
    return out


def frame_cfg_scales(actions: list[int], cfg_scale: float, turn_brake_cfg_scale: float | None = None,
                     turn_brake_frames: int = 0) -> list[float]:
    """The guidance scale (`sample_next`'s `cfg_scale`) each frame of a key sequence
    samples with: `turn_brake_cfg_scale` for the first `turn_brake_frames` frames of a
    turn (`turn_runs`), else `cfg_scale` (Idle frames take their own scale from
    `frame_idle_scales`). The engine's `Sampling::for_frame`: no turn braking in an
    unguided sampler."""
    if turn_brake_cfg_scale is None or cfg_scale == 1.0:
        return [cfg_scale] * len(actions)
    return [turn_brake_cfg_scale if run is not None and run <= turn_brake_frames else cfg_scale
            for run in turn_runs(actions)]


def frame_options(options: dict, brake: dict, history: list[int]) -> dict:
    """`sample_next`'s keyword arguments (`sampler_options`) for the last frame of a key
    sequence `history` that starts at rest, its Idle scale braked as the live loop would
    (`frame_idle_scales` with `brake_options`): a teacher-forced frame sampled as the
    engine would sample it after the same keys."""
    return dict(options, idle_cfg_scale=frame_idle_scales(history, options["idle_cfg_scale"], **brake)[-1])
