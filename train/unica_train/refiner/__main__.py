"""Trains the splat refiner (the network: model.py) on a baked dataset's renders:

    python -m unica_train.refiner --bundle B --data DATA --out RUN [--steps N] [--resume]

which writes RUN/refiner.safetensors, losses, eval.json (PSNR/SSIM of base vs refined
splats on the held-out clips) and adds `refiner.*` to the bundle with --write-bundle."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .evaluation import evaluate_bundle
from .training import train


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m unica_train.refiner", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", required=True, type=Path, help="the bundle whose VAE and PCA make the inputs")
    parser.add_argument("--data", required=True, type=Path, help="dataset folder written by `unica bake` (with renders)")
    parser.add_argument("--out", required=True, type=Path, help="run folder (checkpoint, losses, eval)")
    parser.add_argument("--config", type=Path, help="JSON with RefinerTrainConfig fields")
    parser.add_argument("--steps", type=int, help="optimizer steps (overrides the config's steps and samples)")
    parser.add_argument("--samples", type=int,
                        help="frames to train on in all: each step sees one frame on each process, so N processes take samples / N steps")
    parser.add_argument("--device", default="auto", help="auto (CUDA when PyTorch sees a GPU), cpu or cuda")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--init", type=Path, help="start from the refiner in this bundle (same refiner config)")
    parser.add_argument("--write-bundle", action="store_true", help="add the trained refiner to --bundle")
    parser.add_argument("--eval-only", action="store_true",
                        help="no training: evaluate --bundle's own refiner on the held-out frames at the config's image size and splat level (OUT/refiner_eval.json)")
    args = parser.parse_args(argv)
    metrics = evaluate_bundle(args) if args.eval_only else train(args)
    print(json.dumps(metrics, indent=2))


if __name__ == "__main__":
    main()
