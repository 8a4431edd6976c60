"""A refiner run's config (`--config`: JSON over the defaults) and the held-out frames it
picks."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from .model import RefinerConfig

if TYPE_CHECKING:
    from .frames import Frames


@dataclass
class RefinerTrainConfig:
    model: dict = field(default_factory=lambda: RefinerConfig().to_dict())
    steps: int = 1500
    lr: float = 2e-3
    # Give the model a learned residual per map pixel (`pixel_residuals`, sized to the
    # dataset's map) when its config does not set one; learned at `pixel_lr`.
    pixel_table: bool = True
    pixel_lr: float = 1e-2
    views_per_step: int = 2
    image_size: int = 128
    ssim_weight: float = 0.2
    # The splat level the refined splats are drawn at in training: 128 draws the map's own
    # points; a finer level (256: what the app draws on a CPU driver) upscales the points
    # and the residuals to it, as the app and the evaluation do (issue #17).
    splat_level: int = 128
    # Weight of an L1 between the drawn alpha and the render's: keeps the body opaque
    # where the teacher is (issue #17: a see-through avatar).
    alpha_weight: float = 0.0
    # Fraction of steps whose input is the bundle's own generated frame instead of the
    # VAE's reconstruction: the UNet's next frame from the three ground-truth frames before
    # it and the true action, sampled as `unica eval` does (fresh noise each time; 0.25 s),
    # so the refiner learns to draw what the live loop makes, model error included.
    generated_fraction: float = 0.0
    held_out_clips: list = field(default_factory=lambda: [4, 13])
    eval_frames: int = 24
    checkpoint_every: int = 100
    seed: int = 0
    # > 0: the schedule in frames seen rather than steps: each step sees one frame on each
    # of the data-parallel processes, so N processes take samples / N steps.
    samples: int = 0

    def total_steps(self, world: int) -> int:
        return math.ceil(self.samples / world) if self.samples > 0 else self.steps


def train_config(path: Path | None) -> RefinerTrainConfig:
    """The run's config: the JSON at `path` over the defaults."""
    cfg = RefinerTrainConfig(**json.loads(path.read_text())) if path else RefinerTrainConfig()
    if not 0 <= cfg.generated_fraction <= 1:
        raise ValueError(f"{path}: generated_fraction {cfg.generated_fraction} is not in [0, 1]")
    return cfg


def held_out_keys(frames: Frames, cfg: RefinerTrainConfig) -> list:
    """The evaluation's frames: `eval_frames` spread over the held-out clips."""
    keys = [k for k in frames.keys if k[0] in cfg.held_out_clips]
    if not keys:
        raise ValueError(f"{frames.dir}: no rendered frame of the held-out clips {cfg.held_out_clips} (set held_out_clips in the config)")
    return keys[:: max(1, len(keys) // cfg.eval_frames)][: cfg.eval_frames]
