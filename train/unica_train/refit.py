"""Refits a bundle's PCA-head decoder in closed form (issue #17): the head `W z + b` onto
the fixed PCA basis is linear, so the best head for a set of latents is a ridge
regression, solved exactly instead of by the 3,000 Adam steps the trainer gave it.

It is fitted on two kinds of latents of the training clips (never the held-out ones):
- the encoder's latents of every frame, whose maps it must give back (the VAE's job);
- the UNet's own teacher-forced outputs (each group's 4th frame generated from its 3
  encoded context frames and the true action, with the bundle's sampler), whose maps
  are the frames the UNet was asked for. The play loop decodes only such latents, and
  they lie off the encoder's latents; a head fitted to the encoder's latents alone
  reconstructs them sharply but amplifies the UNet's errors.
`--generated-weight` sets the second kind's share and `--ridge` the penalty (relative
to the sample count); both were chosen on held-out clips (docs/records/witch/README.md).

    python -m unica_train.refit --bundle B --data DATA --out NEW [--generated-weight 0.5] [--ridge 1.0]

NEW is a copy of B with the head replaced, `metrics.vae_reconstruction_mm` measured
again, and `metrics.decoder_refit` recording the fit; `refit.json` beside it holds the
held-out errors before and after."""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import torch

from . import checkpoint as checkpoint_file
from . import bundle as bundle_io
from . import pca
from .diffusion import Schedule, brake_options, frame_options, sample_next, sampler_options
from .report import every
from .train import Run, TrainConfig

HEAD = ("vae.decoder.head.weight", "vae.decoder.head.bias")


def ridge(x: torch.Tensor, y: torch.Tensor, penalty: float, weights: torch.Tensor | None = None):
    """(W, b) minimising Σ wᵢ |W xᵢ + b - yᵢ|² + penalty·(n/1000)·|W|² over rows x [n, d],
    y [n, k] (b is not penalised; float64)."""
    x, y = x.double(), y.double()
    n = x.shape[0]
    w = torch.ones(n, dtype=torch.float64) if weights is None else weights.double()
    a = torch.cat([x, torch.ones(n, 1, dtype=torch.float64)], 1)
    reg = torch.eye(a.shape[1], dtype=torch.float64) * penalty * n / 1000
    reg[-1, -1] = 0
    sol = torch.linalg.solve(a.T @ (a * w[:, None]) + reg, a.T @ (y * w[:, None]))
    return sol[:-1].T.contiguous(), sol[-1].contiguous()


class Fit:
    """The bundle, the dataset's training and held-out groups, and the latents."""

    def __init__(self, bundle: Path, data: Path, out: Path, held_out: list[int]):
        self.vae, self.unet, self.extra, self.manifest = bundle_io.load(bundle)
        self.vae.eval()
        self.unet.eval()
        if self.vae.cfg.decoder != "pca":
            raise SystemExit(f"{bundle}: its VAE decoder is {self.vae.cfg.decoder!r}; only a PCA head can be refitted")
        self.scale = self.manifest["latent_scale"]
        self.sampler = self.manifest["sampler"]
        self.sampler_options = sampler_options(self.sampler)  # guide_idle, noise_scale, idle_cfg_scale
        self.brake_options = brake_options(self.sampler)  # the live loop's braking after a key
        self.run = Run(data, out, TrainConfig(held_out_clips=held_out), torch.device("cpu"))
        if not self.run.test_groups or not self.run.train_groups:
            raise SystemExit(f"{data}: held-out clips {held_out} leave no training or no held-out frames")
        dec = self.vae.decoder
        if not torch.equal(dec.pixels.long(), self.run.ds.pixels.long()):
            raise SystemExit(f"{data}: its position-map pixels are not the bundle's")
        self.pixels = dec.pixels.long()

    def coefficients(self, maps: torch.Tensor) -> torch.Tensor:
        """PCA coefficients of maps [n, 3, S, S] in the head's basis."""
        dec = self.vae.decoder
        return pca.coefficients(maps.flatten(2)[:, :, self.pixels].flatten(1), dec.mean, dec.basis)

    @torch.no_grad()
    def encoded(self, groups: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
        """Encoder latents [4n, d] of every frame of `groups` and their coefficients."""
        z, c = [], []
        for i in groups:
            maps = self.run.group_maps(i)
            z.append(self.vae.encoder(maps)[0].flatten(1))
            c.append(self.coefficients(maps))
        return torch.cat(z), torch.cat(c)

    @torch.no_grad()
    def generated(self, groups: list[int], seed: int, label: str) -> tuple[torch.Tensor, torch.Tensor]:
        """The UNet's teacher-forced latents [n, d] (unscaled) of each group's 4th frame
        (braked as the live loop would be after the clip's keys so far; baked clips start
        at rest) and that frame's true coefficients."""
        gen = torch.Generator().manual_seed(seed)
        schedule, z, c = Schedule(), [], []
        started = time.time()
        for k, i in enumerate(groups):
            maps = self.run.group_maps(i)
            context = self.vae.encoder(maps[:3])[0] * self.scale
            g = self.run.groups[i]
            history = [int(a) for a in self.run.ds.clips[g.clip]["actions"][: g.start + 3]]
            new = sample_next(self.unet, schedule, context[None], torch.tensor([g.action]), self.sampler["ddim_steps"],
                              self.sampler["cfg_scale"], generator=gen,
                              **frame_options(self.sampler_options, self.brake_options, history))
            z.append((new / self.scale).flatten(1))
            c.append(self.coefficients(maps[3:]))
            if (k + 1) % 100 == 0 or k + 1 == len(groups):
                print(f"  {label}: {k + 1}/{len(groups)} frames generated ({time.time() - started:.0f} s)", flush=True)
        return torch.cat(z), torch.cat(c)

    def error_mm(self, w: torch.Tensor, b: torch.Tensor, z: torch.Tensor, c: torch.Tensor) -> float:
        """Mean point error in mm between the head's maps of latents z and coefficients c
        (both in the basis: what lies outside it, 0.006 mm, is the same for any head)."""
        dec = self.vae.decoder
        diff = ((z.double() @ w.double().T + b.double()) - c.double()) @ dec.basis.double()
        return diff.view(z.shape[0], 3, -1).norm(dim=1).mean().item() / self.run.ds.scale * 1000

    @torch.no_grad()
    def reconstruction_mm(self, w: torch.Tensor, b: torch.Tensor) -> float:
        """The trainer's VAE reconstruction of held-out frames (`Run.reconstruction_mm`)
        with head (w, b); the bundle's own head is put back after."""
        head = self.vae.decoder.head
        saved = head.weight.clone(), head.bias.clone()
        head.weight.copy_(w.float())
        head.bias.copy_(b.float())
        error = self.run.reconstruction_mm(self.vae)
        head.weight.copy_(saved[0])
        head.bias.copy_(saved[1])
        return error


def main(argv=None):
    try:
        _main(argv)
    except (bundle_io.BundleError, OSError, ValueError) as e:
        raise SystemExit(f"unica_train.refit: {e}") from None


def _main(argv):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", required=True, type=Path, help="the bundle whose decoder head is refitted")
    parser.add_argument("--data", required=True, type=Path, help="the dataset baked from the bundle's character")
    parser.add_argument("--out", required=True, type=Path, help="the new bundle's folder (not the input's)")
    parser.add_argument("--generated-weight", type=float, default=0.5,
                        help="total weight of the UNet's latents against the encoder's (default 0.5)")
    parser.add_argument("--ridge", type=float, default=1.0, help="ridge penalty per 1,000 samples (default 1.0)")
    parser.add_argument("--encoder-stride", type=int, default=3, help="every Nth training group's 4 frames (default 3)")
    parser.add_argument("--generated-stride", type=int, default=4, help="every Nth training group generated (default 4)")
    parser.add_argument("--held-out", default="4,13", help="the clips the bundle's training held out (default 4,13)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    if args.out.resolve() == args.bundle.resolve():
        raise SystemExit(f"{args.out}: the new bundle must go to another folder than --bundle")
    if args.generated_weight < 0 or args.ridge < 0 or args.encoder_stride < 1 or args.generated_stride < 1:
        raise SystemExit("--generated-weight and --ridge must be ≥ 0, the strides ≥ 1")
    started = time.time()
    try:
        held_out = [int(c) for c in args.held_out.split(",")]
    except ValueError:
        raise SystemExit(f"--held-out {args.held_out!r}: expected clip numbers such as 4,13") from None
    fit = Fit(args.bundle, args.data, args.out, held_out)
    run = fit.run
    print(f"encoding {every(args.encoder_stride)} training group ...", flush=True)
    ze, ce = fit.encoded(run.train_groups[::args.encoder_stride])
    print(f"generating {every(args.generated_stride)} training group's 4th frame "
          f"({fit.sampler['ddim_steps']} DDIM steps, CFG {fit.sampler['cfg_scale']}) ...", flush=True)
    zg, cg = fit.generated(run.train_groups[::args.generated_stride], args.seed, "training")
    zt, ct = fit.generated(run.test_groups[::14], 0, "held out")
    share = args.generated_weight * ze.shape[0] / zg.shape[0]
    weights = torch.cat([torch.ones(ze.shape[0]), torch.full((zg.shape[0],), share)])
    w, b = ridge(torch.cat([ze, zg]), torch.cat([ce, cg]), args.ridge, weights)
    # Copies: reconstruction_mm writes the head in place while it measures.
    old = fit.vae.decoder.head.weight.detach().clone(), fit.vae.decoder.head.bias.detach().clone()
    report = {
        "bundle": str(args.bundle),
        "generated_weight": args.generated_weight,
        "ridge": args.ridge,
        "encoder_samples": ze.shape[0],
        "generated_samples": zg.shape[0],
        "held_out_clips": run.cfg.held_out_clips,
        "before": {"vae_reconstruction_mm": fit.reconstruction_mm(*old), "generated_mm": fit.error_mm(*old, zt, ct)},
        "after": {"vae_reconstruction_mm": fit.reconstruction_mm(w, b), "generated_mm": fit.error_mm(w, b, zt, ct)},
        "held_out_generated_frames": zt.shape[0],
    }
    print(f"held out: VAE reconstruction {report['before']['vae_reconstruction_mm']:.2f} -> "
          f"{report['after']['vae_reconstruction_mm']:.2f} mm; teacher-forced generated frames "
          f"{report['before']['generated_mm']:.2f} -> {report['after']['generated_mm']:.2f} mm", flush=True)
    tensors = bundle_io.read_weights(args.bundle / "weights.safetensors")
    tensors[HEAD[0]], tensors[HEAD[1]] = w.float().contiguous(), b.float().contiguous()
    manifest = json.loads((args.bundle / "manifest.json").read_text())
    manifest["metrics"]["vae_reconstruction_mm"] = report["after"]["vae_reconstruction_mm"]
    manifest["metrics"]["decoder_refit"] = {k: report[k] for k in ("generated_weight", "ridge", "encoder_samples", "generated_samples")}
    args.out.mkdir(parents=True, exist_ok=True)
    for extra in args.bundle.iterdir():
        if extra.name not in ("weights.safetensors", "manifest.json") and extra.is_file():
            shutil.copy2(extra, args.out / extra.name)
    bundle_io.write_weights(args.out, tensors, manifest)
    report["minutes"] = (time.time() - started) / 60
    checkpoint_file.write_text(args.out / "refit.json", json.dumps(report, indent=2) + "\n")
    bundle_io.load(args.out)  # the written bundle loads and checks
    print(f"wrote {args.out} in {report['minutes']:.1f} min", flush=True)


if __name__ == "__main__":
    main()
