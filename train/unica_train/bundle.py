"""Bundles (docs/architecture.md, Files): what the app loads to play an avatar — `weights.safetensors` and a
versioned `manifest.json` with the full model config, action names, normalisation, PCA,
the position-map layout, per-pixel colours and the initial context of a standing start.
Loading checks every tensor's name, shape and dtype and names the first that is wrong.
The network weights and the PCA basis are stored as float16 (`HALF`): it halves the
shipped bundle (43 to 22 MB) and every reader widens them to float32 before use; positions
(`pca.mean`, `context.latents`) and colours stay float32.

    python -m unica_train.bundle add-colors --bundle DIR --data DATASET

adds the per-pixel colours (`map.colors`, from the dataset's reference) to a bundle made
before the trainer wrote them; the models are untouched."""

from __future__ import annotations

import json
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from .unet import UNet, UNetConfig
from .vae import PositionVae, VaeConfig

FORMAT = "unica-bundle"
VERSION = 1


class BundleError(ValueError):
    """A bundle that cannot be loaded; the message names the file and the problem."""


# Tensors stored as float16: names starting with one of these.
HALF = ("vae.", "unet.", "student.", "refiner.", "pca.basis")


def read_weights(path: str | Path) -> dict:
    """A bundle's tensors, float16 ones widened to float32."""
    return {k: v.float() if v.dtype == torch.float16 else v for k, v in load_file(str(path)).items()}


def write_weights(directory: str | Path, tensors: dict, manifest: dict) -> None:
    """Writes weights.safetensors (the `HALF` tensors as float16) and manifest.json with
    its `tensors` table of stored shapes and dtypes."""
    d = Path(directory)
    stored = {k: (v.half() if k.startswith(HALF) and v.is_floating_point() else v).detach().contiguous().cpu()
              for k, v in tensors.items()}
    manifest = dict(manifest)
    manifest["tensors"] = {k: {"shape": list(v.shape), "dtype": str(v.dtype).removeprefix("torch.")}
                           for k, v in sorted(stored.items())}
    save_file(stored, str(d / "weights.safetensors"))
    (d / "manifest.json").write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")


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


def main(argv=None):
    import argparse

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    colors = sub.add_parser("add-colors", help="add per-pixel colours from a dataset")
    colors.add_argument("--bundle", required=True, type=Path)
    colors.add_argument("--data", required=True, type=Path, help="dataset folder written by `unica bake`")
    args = parser.parse_args(argv)
    add_colors(args.bundle, args.data)
    print(f"added map.colors to {args.bundle}")


if __name__ == "__main__":
    main()
