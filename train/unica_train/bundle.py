"""Bundles (docs/architecture.md, Files): what the app loads to play an avatar — `weights.safetensors` and a
versioned `manifest.json` with the full model config, action names, normalisation, PCA,
the position-map layout, per-pixel colours and the initial context of a standing start.
Loading checks every tensor's name, shape and dtype and names the first that is wrong.
The network weights and the PCA basis are stored as float16 (`HALF`), and of them the
10-step UNet's weight arrays, the VAE decoder's basis and the PCA basis as 8-bit integers
with a float16 scale per group of 32 values (`QUANTISED`), and the one-pass student's
weight arrays as an 8-bit difference from the UNet's (`DELTA_OF`): the Witch's bundle is
43 MB in float32, 22 MB in float16, 12.2 MB so. The VAE's encoder stays float16: as int8
the Witch no longer stops (docs/experiments/int8-storage.md). Every reader widens them to
float32 before use; positions (`pca.mean`, `context.latents`) and colours stay float32.
Quantising is idempotent (reading and writing a bundle again stores the same bytes), so
the stages that rewrite a bundle lose nothing.

    python -m unica_train.bundle add-colors --bundle DIR --data DATASET

adds the per-pixel colours (`map.colors`, from the dataset's reference) to a bundle made
before the trainer wrote them; the models are untouched.

    python -m unica_train.bundle store --bundle DIR

rewrites a bundle's weights as this trainer stores them, printing how far its
standing-start frame moved."""

from __future__ import annotations

import json
from pathlib import Path

import torch
import torch.nn.functional as F
from safetensors.torch import load_file
from safetensors.torch import save as safetensors_bytes

from .checkpoint import write_folder_atomic
from .unet import UNet, UNetConfig
from .vae import PositionVae, VaeConfig

FORMAT = "unica-bundle"
VERSION = 1


class BundleError(ValueError):
    """A bundle that cannot be loaded; the message names the file and the problem."""


# Tensors stored as float16: names starting with one of these.
HALF = ("vae.", "unet.", "student.", "refiner.", "pca.basis")
# Of those, arrays of 2 or more dimensions stored as int8 with a float16 scale per group of
# QUANT_GROUP consecutive values, in the tensor `<name>:scale` (src/tensors.rs reads them).
# Not the VAE's encoder nor the one-pass student: as int8 the encoder makes the Witch
# creep after a release (2 seeds x 4 stops: 8 of 8 stops never came, slide 0.16 m, against
# 13 of 24 and 0.057 m in float16; docs/experiments/int8-storage.md), and the student's
# own values as int8 leave some of that (its difference from the UNet is stored instead:
# `DELTA_OF`). The decoder's basis (its linear head to the map), the PCA basis
# and the 10-step UNet as int8 stop as float16 does.
QUANTISED = ("unet.", "pca.basis", "vae.decoder.basis")
QUANT_GROUP = 32
SCALE = ":scale"
# The one-pass student is distilled from the 10-step UNet and differs from it by 1.5 % of
# its weights (the Witch), so its weight arrays are stored as int8 of their difference
# from the UNet's array of the same name as read back, with the scales in `NAME:delta`:
# that difference's int8 step is far finer than the student's own would be.
DELTA_OF = {"student.": "unet."}
DELTA = ":delta"


def delta_base(name: str) -> str | None:
    """The tensor a `DELTA_OF` tensor is stored as a difference from, else None."""
    for prefix, base in DELTA_OF.items():
        if name.startswith(prefix):
            return base + name[len(prefix):]
    return None


def _groups(flat: torch.Tensor) -> torch.Tensor:
    """Values [n] as rows of QUANT_GROUP, the last padded with zeros."""
    return F.pad(flat, (0, -len(flat) % QUANT_GROUP)).reshape(-1, QUANT_GROUP)


def quantise(v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(int8 values, float16 scale per group of QUANT_GROUP consecutive values, the last
    group shorter where the size is not a multiple): each group's largest magnitude maps
    to 127, or steps of 2^-14 for groups under 127 of them (7.8e-3)."""
    groups = _groups(v.detach().float().flatten())
    # At least float16's smallest normal number: a subnormal scale is too coarse for the
    # largest value to land on 127, and then reading and writing again would shrink it.
    scale = (groups.abs().amax(1) / 127).clamp_min(2.0**-14).half()
    q = (groups / scale.float()[:, None]).round().clamp(-127, 127).to(torch.int8)
    return q.flatten()[: v.numel()].reshape(v.shape), scale


def dequantise(q: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    groups = _groups(q.float().flatten()) * scale.float()[:, None]
    return groups.flatten()[: q.numel()].reshape(q.shape)


def quantised(name: str, v: torch.Tensor) -> bool:
    return name.startswith(QUANTISED) and v.is_floating_point() and v.dim() >= 2


def read_weights(path: str | Path) -> dict:
    """A bundle's tensors, float16 and int8 ones widened to float32 (a difference stored
    under `DELTA` added to its base)."""
    raw = load_file(str(path))
    out = {}

    def read(k: str) -> torch.Tensor:
        if k in out:
            return out[k]
        v = raw[k]
        if v.dtype == torch.int8 and k + DELTA in raw:
            base = delta_base(k)
            if base is None or base not in raw or raw[base].shape != v.shape:
                raise BundleError(f"{path}: tensor '{k}' is stored as a difference but has no base of its shape")
            v = read(base) + dequantise(v, raw[k + DELTA])
        elif v.dtype == torch.int8:
            if k + SCALE not in raw:
                raise BundleError(f"{path}: tensor '{k}{SCALE}' is missing")
            v = dequantise(v, raw[k + SCALE])
        out[k] = v.float() if v.dtype == torch.float16 else v
        return out[k]

    for k in raw:
        if not k.endswith((SCALE, DELTA)):
            read(k)
    return out


def write_weights(directory: str | Path, tensors: dict, manifest: dict) -> None:
    """Writes weights.safetensors (the `QUANTISED` tensors as int8 with scales, the other
    `HALF` ones as float16) and manifest.json with its `tensors` table of stored shapes
    and dtypes, the bundle folder replaced whole (`checkpoint.write_folder_atomic`)."""
    d = Path(directory)
    stored = {}
    for k, v in tensors.items():
        if quantised(k, v):
            stored[k], stored[k + SCALE] = quantise(v)
        elif k.startswith(HALF) and v.is_floating_point():
            stored[k] = v.half()
        else:
            stored[k] = v
    for k, v in tensors.items():
        base = delta_base(k)
        if base in stored and k + SCALE not in stored and v.dim() >= 2 and stored[base].shape == v.shape:
            stored[k], stored[k + DELTA] = quantise(v.float() - _read_back(base, stored))
    stored = {k: v.detach().contiguous().cpu() for k, v in stored.items()}
    manifest = dict(manifest)
    manifest["tensors"] = {k: {"shape": list(v.shape), "dtype": str(v.dtype).removeprefix("torch.")}
                           for k, v in sorted(stored.items())}
    write_folder_atomic(d, {
        "weights.safetensors": safetensors_bytes(stored),
        "manifest.json": _manifest_bytes(manifest),
    })


def write_manifest(directory: str | Path, manifest: dict) -> None:
    """Replaces a bundle's manifest.json alone, the folder swapped whole as `write_weights`
    does (the weights are kept as they are)."""
    write_folder_atomic(Path(directory), {"manifest.json": _manifest_bytes(manifest)})


def _manifest_bytes(manifest: dict) -> bytes:
    return (json.dumps(manifest, indent=2, sort_keys=True) + "\n").encode()


def _read_back(name: str, stored: dict) -> torch.Tensor:
    """A tensor as a reader will widen it from `stored` (no difference: bases are not)."""
    v = stored[name]
    return dequantise(v, stored[name + SCALE]) if v.dtype == torch.int8 else v.float()


def _tensors(vae: PositionVae, unet: UNet, extra: dict) -> dict:
    out = {f"vae.{k}": v for k, v in vae.state_dict().items()}
    out.update({f"unet.{k}": v for k, v in unet.state_dict().items()})
    out.update(extra)
    return {k: v.detach().contiguous().cpu() for k, v in out.items()}


def save(directory: str | Path, vae: PositionVae, unet: UNet, extra: dict, manifest: dict) -> None:
    """Writes the bundle. `extra` holds the non-model tensors (pca.mean, pca.basis,
    context.latents, map.pixels, map.waist); `manifest` the rest of the manifest."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    tensors = _tensors(vae, unet, extra)
    full = dict(manifest)
    full.update({
        "format": FORMAT,
        "version": VERSION,
        "vae": vae.cfg.to_dict(),
        "unet": unet.cfg.to_dict(),
    })
    write_weights(d, tensors, full)


def load(directory: str | Path):
    """(vae, unet, extra tensors, manifest), every tensor checked against the manifest's
    model config."""
    d = Path(directory)
    manifest_path = d / "manifest.json"
    try:
        manifest = json.loads(manifest_path.read_text())
    except (OSError, ValueError) as e:
        raise BundleError(f"{manifest_path}: {e}") from e
    if manifest.get("format") != FORMAT:
        raise BundleError(f"{manifest_path}: not a unica bundle (format {manifest.get('format')!r})")
    if manifest.get("version") != VERSION:
        raise BundleError(f"{manifest_path}: bundle version {manifest.get('version')}, this trainer reads {VERSION}")
    vae = PositionVae(VaeConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in manifest["vae"].items()}))
    unet = UNet(UNetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in manifest["unet"].items()}))
    weights_path = d / "weights.safetensors"
    try:
        tensors = read_weights(weights_path)
    except Exception as e:
        raise BundleError(f"{weights_path}: {e}") from e
    expected = _tensors(vae, unet, {})
    for name, want in sorted(expected.items()):
        found = tensors.get(name)
        if found is None:
            raise BundleError(f"{weights_path}: tensor '{name}' is missing")
        if found.shape != want.shape or found.dtype != want.dtype:
            raise BundleError(
                f"{weights_path}: tensor '{name}' is {found.dtype} {list(found.shape)}, expected {want.dtype} {list(want.shape)}"
            )
    vae.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("vae.")})
    unet.load_state_dict({k[5:]: v for k, v in tensors.items() if k.startswith("unet.")})
    extra = {k: v for k, v in tensors.items() if k not in expected}
    return vae, unet, extra, manifest


SAMPLER_KINDS = ("ddim", "one_pass")


def live_sampler(manifest: dict, unet: UNet, extra: dict, path: str | Path = "manifest.json") -> tuple[UNet, int, float]:
    """(model, DDIM steps, CFG scale) the live loop runs by default, as the engine's
    `Sampling::live`: for `sampler.kind` "one_pass" the distilled student (`student.*`)
    in one unguided step, else the UNet with the manifest's steps and scale."""
    sampler = manifest["sampler"]
    kind = sampler.get("kind", "ddim")
    if kind not in SAMPLER_KINDS:
        raise BundleError(f"{path}: sampler kind {kind!r}, expected one of {', '.join(SAMPLER_KINDS)}")
    if kind == "ddim":
        return unet, int(sampler["ddim_steps"]), float(sampler["cfg_scale"])
    weights = {k[len("student."):]: v for k, v in extra.items() if k.startswith("student.")}
    student = UNet(unet.cfg)
    try:
        student.load_state_dict(weights)
    except RuntimeError as e:
        raise BundleError(f"{path}: the one-pass sampler's student ('student.*') does not fit the UNet config: "
                          f"{str(e).splitlines()[0]}") from None
    return student.eval(), 1, 1.0


def add_colors(directory: str | Path, data: str | Path) -> None:
    """Writes `map.colors` from the dataset's reference into an existing bundle."""
    from .dataset import BakedDataset

    d = Path(directory)
    ds = BakedDataset(Path(data))
    tensors = read_weights(d / "weights.safetensors")
    if not torch.equal(tensors["map.pixels"].long(), ds.pixels):
        raise BundleError(f"{data}: its position-map pixels are not the bundle's (another character or table)")
    tensors["map.colors"] = ds.pixel_colors().contiguous()
    write_weights(d, tensors, json.loads((d / "manifest.json").read_text()))


def standing_start(directory: str | Path, seed: int = 0) -> dict[str, torch.Tensor]:
    """The bundle's first generated position map [6*3, H, W] from its standing start under
    Forward, with the teacher sampler (`ddim`) and, where it has one, the one-pass student
    (`one_pass`), from the noise of `seed`."""
    from .diffusion import Schedule, sample_next, sampler_options

    vae, unet, extra, manifest = load(directory)
    sampler, scale = manifest["sampler"], manifest["latent_scale"]
    context = extra["context.latents"][None]
    noise = torch.randn(context.shape[:1] + context.shape[2:], generator=torch.Generator().manual_seed(seed))
    samplers = {"ddim": (unet, sampler["ddim_steps"], sampler["cfg_scale"])}
    student = live_sampler(manifest, unet, extra, Path(directory) / "manifest.json")
    if student[0] is not unet:
        samplers["one_pass"] = student
    out = {}
    with torch.no_grad():
        for name, (model, steps, cfg) in samplers.items():
            z = sample_next(model, Schedule(), context, torch.tensor([1]), steps, cfg, noise, **sampler_options(sampler))
            out[name] = vae.decode(z / scale)[0]
    return out


def store(directory: str | Path) -> list[str]:
    """Rewrites the bundle's weights with this storage (`write_weights`) and returns, per
    sampler, how far its standing-start map moved: the largest and mean change over the
    map's foreground pixels, in map units and in millimetres."""
    d = Path(directory)
    before = standing_start(d)
    tensors = read_weights(d / "weights.safetensors")
    manifest = json.loads((d / "manifest.json").read_text())
    write_weights(d, tensors, manifest)
    after = standing_start(d)
    pixels = tensors["map.pixels"].long()
    mm = 1000 / manifest["normalisation"]["scale"]
    lines = []
    for name in before:
        change = (before[name] - after[name]).flatten(1)[:, pixels].abs()
        lines.append(f"{name}: standing-start map moved by at most {change.max():.2e} ({change.max() * mm:.2f} mm), "
                     f"mean {change.mean():.2e} ({change.mean() * mm:.3f} mm)")
    return lines


def main(argv=None):
    import argparse

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    colors = sub.add_parser("add-colors", help="add per-pixel colours from a dataset")
    colors.add_argument("--bundle", required=True, type=Path)
    colors.add_argument("--data", required=True, type=Path, help="dataset folder written by `unica bake`")
    restore = sub.add_parser("store", help="rewrite the weights as this trainer stores them (int8 and float16), "
                                          "printing how far the standing-start frame moved")
    restore.add_argument("--bundle", required=True, type=Path)
    args = parser.parse_args(argv)
    if args.command == "store":
        before = (args.bundle / "weights.safetensors").stat().st_size
        for line in store(args.bundle):
            print(line)
        after = (args.bundle / "weights.safetensors").stat().st_size
        print(f"{args.bundle / 'weights.safetensors'}: {before / 1e6:.1f} MB -> {after / 1e6:.1f} MB")
        return
    add_colors(args.bundle, args.data)
    print(f"added map.colors to {args.bundle}")


if __name__ == "__main__":
    main()
