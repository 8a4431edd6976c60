"""PyTorch-eager benchmark of the models, the counterpart of the WGSL engine's table: the
median time of one UNet step (the CFG batch of 2 over a 4-frame group), one unet-target
step (batch 1 at CFG 1, the engine's `stage unet-target`; printed as
`pytorch stage unet-target: ms=X gflops=G` for the bundle, or the last config), one VAE decode
(one 4x16x16 latent to a 3x128x128 map) and one generated frame (a DDIM sample of `--steps`
guided UNet steps, then a decode), with the GFLOP of each (convolutions, linear layers and
attention products, as counted by unet.conv_and_linear_flops) and the achieved GFLOP/s.

    python -m unica_train.bench [--config tiny|default|both] [--bundle DIR] [--device cpu|cuda]
                                [--steps 10] [--cfg-scale 2.0] [--repeat 5] [--threads N] [--json FILE]

Weights are random (seeded) unless `--bundle` adds a trained bundle as the config "bundle":
the time does not depend on the values. Every timing runs under torch.no_grad() after 2
warm-up runs, with torch.cuda.synchronize() around it on CUDA."""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch

from . import checkpoint as checkpoint_file
from . import bundle, fixtures
from .diffusion import Schedule, sample_next
from .unet import NULL_ACTION, UNet, UNetConfig, conv_and_linear_flops, parameter_count
from .vae import PositionVae, VaeConfig

WARMUP = 2


def _models(config: str, bundle_dir: Path | None) -> tuple[PositionVae, UNet]:
    if config == "bundle":
        vae, unet, _, _ = bundle.load(bundle_dir)
        return vae, unet
    torch.manual_seed(0)
    if config == "tiny":
        return PositionVae(fixtures.TINY_VAE), UNet(fixtures.TINY_UNET)
    return PositionVae(VaeConfig()), UNet(UNetConfig())


def _median_ms(fn, device: torch.device, repeat: int) -> float:
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for _ in range(WARMUP):
        fn()
    times = []
    for _ in range(repeat):
        sync()
        start = time.perf_counter()
        fn()
        sync()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


@torch.no_grad()
def bench_config(config: str, vae: PositionVae, unet: UNet, device: torch.device, steps: int, cfg_scale: float, repeat: int) -> dict:
    """The three rows of one config, with the parameter counts."""
    vae, unet = vae.to(device).eval(), unet.to(device).eval()
    cfg = unet.cfg
    gen = torch.Generator().manual_seed(0)
    rand = lambda *shape: torch.randn(*shape, generator=gen).to(device)  # noqa: E731
    x = rand(2, cfg.frames, cfg.latent, 16, 16)
    t = torch.tensor([[0] * (cfg.frames - 1) + [700]] * 2, device=device)
    actions = torch.tensor([1, NULL_ACTION], device=device)
    z = rand(1, vae.cfg.latent, 16, 16)
    context, noise, action = rand(1, cfg.frames - 1, cfg.latent, 16, 16), rand(1, cfg.latent, 16, 16), torch.tensor([1], device=device)
    schedule = Schedule()

    unet_flops = conv_and_linear_flops(unet, x, t, actions)
    # guided_eps runs a batch of 2 unless the scale is exactly 1.
    frame_unet_flops = unet_flops if cfg_scale != 1.0 else conv_and_linear_flops(unet, x[:1], t[:1], actions[:1])
    decode_flops = conv_and_linear_flops(vae.decoder, z)

    def frame():
        return vae.decode(sample_next(unet, schedule, context, action, steps, cfg_scale, noise))

    # The engine's `stage unet-target`: one denoising step of the target frame at CFG 1.
    # PyTorch has no context cache, so its sampler runs the whole group of one sample.
    target_flops = conv_and_linear_flops(unet, x[:1], t[:1], actions[:1])

    rows = []
    for what, flops, fn in [
        ("unet step", unet_flops, lambda: unet(x, t, actions)),
        ("unet-target", target_flops, lambda: unet(x[:1], t[:1], actions[:1])),
        ("vae decode", decode_flops, lambda: vae.decode(z)),
        ("generated frame", steps * frame_unet_flops + decode_flops, frame),
    ]:
        ms = _median_ms(fn, device, repeat)
        rows.append({"config": config, "what": what, "gflop": flops / 1e9, "ms": ms, "gflops": flops / 1e9 / (ms / 1e3)})
    return {"config": config, "unet_parameters": parameter_count(unet), "vae_decoder_parameters": parameter_count(vae.decoder),
            "rows": rows}


def device_label(device: torch.device) -> str:
    if device.type == "cuda":
        return f"PyTorch {torch.__version__} eager on {torch.cuda.get_device_name(device)}"
    threads = torch.get_num_threads()
    return f"PyTorch {torch.__version__} eager on cpu ({threads} thread{'s' if threads > 1 else ''})"


def table(rows: list[dict]) -> str:
    header = ("config", "what", "GFLOP", "ms (median)", "GFLOP/s")
    cells = [header] + [(r["config"], r["what"], f"{r['gflop']:.3f}", f"{r['ms']:.3f}", f"{r['gflops']:.1f}") for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(header))]
    fmt = lambda c: "  ".join(s.ljust(w) if i < 2 else s.rjust(w) for i, (s, w) in enumerate(zip(c, widths)))  # noqa: E731
    return "\n".join(fmt(c).rstrip() for c in cells)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", choices=["tiny", "default", "both"], default="both",
                        help="tiny: the parity-fixture sizes (fixtures.TINY_*); default: VaeConfig() + UNetConfig() (default: both)")
    parser.add_argument("--bundle", type=Path, help="also bench the trained bundle in this directory, as config 'bundle'")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cuda" if torch.cuda.is_available() else "cpu",
                        help="default: cuda when available, else cpu")
    parser.add_argument("--steps", type=int, default=10, help="DDIM steps per generated frame (default 10)")
    parser.add_argument("--cfg-scale", type=float, default=2.0,
                        help="classifier-free guidance scale; other than 1, the conditional and null action run as one batch of 2 "
                             "(default 2.0)")
    parser.add_argument("--repeat", type=int, default=5,
                        help=f"timed repetitions after {WARMUP} warm-up runs; the median is reported (default 5)")
    parser.add_argument("--threads", type=int, help="torch.set_num_threads for the CPU")
    parser.add_argument("--json", type=Path, help="also write the numbers to this JSON file")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    configs = ["tiny", "default"] if args.config == "both" else [args.config]
    if args.bundle:
        configs.append("bundle")

    label = device_label(device)
    print(label, f"- {args.steps} DDIM steps, CFG scale {args.cfg_scale}, median of {args.repeat}", flush=True)
    results = []
    for config in configs:
        result = bench_config(config, *_models(config, args.bundle), device, args.steps, args.cfg_scale, args.repeat)
        print(f"{config}: UNet {result['unet_parameters']:,} parameters, VAE decoder {result['vae_decoder_parameters']:,}", flush=True)
        results.append(result)
    rows = [row for result in results for row in result["rows"]]
    print(table(rows))
    for row in rows:
        if row["config"] == ("bundle" if args.bundle else configs[-1]) and row["what"] == "unet-target":
            # The line the README's speed table reads beside `unica bench`'s stage lines.
            print(f"pytorch stage unet-target: ms={row['ms']:.1f} gflops={row['gflops']:.2f}")
    report = {"device": label, "torch": torch.__version__, "steps": args.steps, "cfg_scale": args.cfg_scale, "repeat": args.repeat,
              "configs": [{k: v for k, v in r.items() if k != "rows"} for r in results], "rows": rows}
    if args.json:
        checkpoint_file.write_text(args.json, json.dumps(report, indent=2) + "\n")
    return report


if __name__ == "__main__":
    main()
