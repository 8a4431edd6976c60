"""The refiner's evaluation: PSNR, SSIM and coverage of base and refined splats on
held-out rendered frames (`--eval-only` for a bundle's own refiner)."""

from __future__ import annotations

import json

import torch

from .. import bundle as bundle_io
from .. import checkpoint as checkpoint_file
from .. import splats
from .config import held_out_keys, train_config
from .frames import Frames, drawn_level, refined
from .model import Refiner, from_bundle


def composite(target: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    return target[..., :3] + (1 - target[..., 3:]) * background


@torch.no_grad()
def evaluate(model: Refiner, frames: Frames, keys: list, level: splats.Level | None = None) -> dict:
    """PSNR and SSIM (sRGB, black background) of base and refined splats, at the map's own
    level or at `level`, and their coverage: the drawn alpha averaged over the render's
    foreground (alpha > 0.5; 1 = opaque where the teacher is)."""
    bound = model.cfg.mean_bound / frames.scale
    sums = {"base": [0.0, 0.0, 0.0], "refined": [0.0, 0.0, 0.0]}
    count = 0
    for key in keys:
        base, feats, unit = frames.inputs(key)
        drawn = refined(base, model(feats, unit), bound, level, frames.world(key))
        if level is not None:
            base = level.splats(frames.world(key))[0]
        for view in frames.views[key]:
            cam, target = frames.target(view)
            want = splats.srgb(target[..., :3])
            inside = target[..., 3] > 0.5
            for name, s in (("base", base), ("refined", drawn)):
                image, alpha = splats.render(s, cam, torch.zeros(3))
                got = splats.srgb(image)
                sums[name][0] += splats.psnr(got, want)
                sums[name][1] += splats.ssim(got, want).item()
                sums[name][2] += alpha[inside].mean().item()
            count += 1
    return {name: {"psnr": v[0] / count, "ssim": v[1] / count, "coverage": v[2] / count} for name, v in sums.items()} | {"views": count}


def evaluate_bundle(args) -> dict:
    """`--eval-only`: the held-out metrics of the refiner already in `args.bundle`."""
    cfg = train_config(args.config)
    _, _, extra, manifest = bundle_io.load(args.bundle)
    model = from_bundle(manifest, extra)
    if model is None:
        raise bundle_io.BundleError(f"{args.bundle}: the bundle has no refiner")
    frames = Frames(args.data, args.bundle, cfg.image_size)
    metrics = evaluate(model, frames, held_out_keys(frames, cfg), drawn_level(frames, cfg)) | {"bundle": str(args.bundle), "image_size": cfg.image_size, "splat_level": cfg.splat_level}
    args.out.mkdir(parents=True, exist_ok=True)
    checkpoint_file.write_text(args.out / "refiner_eval.json", json.dumps(metrics, indent=2) + "\n")
    return metrics
