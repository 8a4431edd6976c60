"""What the refiner sees and makes of a frame: its input features from the base splats,
its residuals applied to them (at the map's level or upscaled to a splat level), and the
dataset's rendered frames as it sees them at run time."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .. import bundle as bundle_io
from .. import pca, splats
from ..dataset import BakedDataset
from .config import RefinerTrainConfig


def features(unit: torch.Tensor, base: splats.Splats, normals: torch.Tensor, median: torch.Tensor) -> torch.Tensor:
    """[N, 11]: position about the root (unit − 0.5), linear colour, normal, and the log
    of the two footprints over the median spacing."""
    footprint = (base.scales[:, :2] / splats.SPREAD / median).clamp_min(1e-6).log()
    return torch.cat([unit - 0.5, base.colors, normals, footprint], 1)


def apply(base: splats.Splats, raw: torch.Tensor, mean_bound_world: float) -> splats.Splats:
    """Base splats + the refiner's residuals (the heads' activations)."""
    logit = math.log(splats.OPACITY / (1 - splats.OPACITY))
    return splats.Splats(
        means=base.means + torch.tanh(raw[:, 0:3]) * mean_bound_world,
        colors=base.colors + raw[:, 3:6],
        scales=base.scales * raw[:, 6:9].exp(),
        rotations=base.rotations + raw[:, 9:13],
        opacities=torch.sigmoid(logit + raw[:, 13]),
    )


def frame_inputs(world: torch.Tensor, waist: torch.Tensor, scale: float, colors: torch.Tensor, nbrs: torch.Tensor):
    """What the refiner sees of a frame's world points [N, 3]: (base splats in world
    space, features, unit positions root-centred on their own waist points, as the engine
    does)."""
    unit = (world - world[waist].mean(0)) * scale + 0.5
    base, normals = splats.base_splats(world, colors, nbrs)
    median = splats.median_spacing(world, nbrs)
    return base, features(unit, base, normals, median), unit


class Frames:
    """Rendered dataset frames as the refiner sees them at run time: the VAE's
    reconstruction of the ground-truth map, PCA-cleaned, in world space, with the
    ground-truth RGBA renders (downsampled) and their cameras."""

    def __init__(self, data: Path, bundle_dir: Path, size: int, reconstruct: bool = True):
        """`reconstruct`: make every rendered frame's inputs now (training); without it
        only the renders and cameras are read (evaluation)."""
        self.ds = ds = BakedDataset(data)
        vae, _, extra, manifest = bundle_io.load(bundle_dir)
        if not torch.equal(extra["map.pixels"].long(), ds.pixels):
            raise bundle_io.BundleError(f"{data}: its position-map pixels are not the bundle's")
        self.scale = ds.scale
        self.colors = ds.pixel_colors()
        self.nbrs = splats.neighbours(ds.pixels, 128)
        listing = json.loads((Path(data) / "renders" / "cameras.json").read_text())
        cams = listing["cameras"]
        self.every = int(listing.get("every", 1))  # every how many frames a pose is rendered
        self.views: dict[tuple[int, int], list] = {}
        for c in cams:
            if c.get("clip_frame"):
                self.views.setdefault(tuple(c["clip_frame"]), []).append(c)
        self.keys = sorted(self.views)
        self.dir = Path(data) / "renders"
        self.size = size
        self.device = torch.device("cpu")  # where `to` moved what a step reads
        self.unit, self.root = {}, {}
        mean, basis = extra["pca.mean"], extra["pca.basis"]
        with torch.no_grad():
            for start in range(0, len(self.keys) if reconstruct else 0, 64):
                chunk = self.keys[start:start + 64]
                world = torch.stack([ds.positions(c, [f])[0] for c, f in chunk])
                root = ds.root(world)
                unit = (world - root[:, None]) * ds.scale + 0.5
                recon = vae.decode(vae.encoder(ds.to_maps(unit))[0]).flatten(2)[:, :, ds.pixels].transpose(1, 2)
                recon = recon.clamp(0, 1)
                shift = ds.root(recon) - 0.5
                cleaned = pca.project((recon - shift[:, None]).flatten(1), mean, basis).reshape(recon.shape) + shift[:, None]
                for k, u, r in zip(chunk, cleaned, root):
                    self.unit[k], self.root[k] = u, r

    def to(self, device: torch.device) -> "Frames":
        """Moves what a training step reads to `device` (renders move as they are read)."""
        self.device = device
        self.colors, self.nbrs = self.colors.to(device), self.nbrs.to(device)
        self.unit = {k: v.to(device) for k, v in self.unit.items()}
        self.root = {k: v.to(device) for k, v in self.root.items()}
        return self

    def world(self, key) -> torch.Tensor:
        """The frame's reconstructed points in world space [N, 3]."""
        return (self.unit[key] - 0.5) / self.scale + self.root[key]

    def inputs(self, key):
        """(base splats in world space, features, unit positions) of the frame's
        reconstruction."""
        return self.inputs_at(self.world(key))

    def inputs_at(self, world: torch.Tensor):
        """(base splats, features, unit positions) of world points [N, 3]."""
        return frame_inputs(world, self.ds.waist, self.scale, self.colors, self.nbrs)

    def target(self, view: dict) -> tuple[splats.Camera, torch.Tensor]:
        """The view's camera at `size` and its render (linear RGB premultiplied, alpha)."""
        from PIL import Image

        path = self.dir / view["file"]
        try:
            rgba = torch.from_numpy(np.array(Image.open(path).convert("RGBA"))).float() / 255
        except OSError as e:
            raise FileNotFoundError(f"{path}: {e}") from e
        factor = rgba.shape[0] // self.size
        rgba = F.avg_pool2d(rgba.permute(2, 0, 1)[None], factor)[0].permute(1, 2, 0)
        k = view["camera"]
        cam = splats.Camera.orbit(k["target"], k["yaw"], k["pitch"], k["distance"], self.size, self.size)
        rgba = rgba.to(self.device)
        return cam, torch.cat([splats.linear(rgba[..., :3]) * rgba[..., 3:], rgba[..., 3:]], -1)


def refined(base: splats.Splats | None, raw: torch.Tensor, bound: float, level: splats.Level | None = None,
            world: torch.Tensor | None = None) -> splats.Splats:
    """The refined splats: residuals `raw` applied to `base` (the map's own level), or,
    with `level`, the points `world` and the residuals upscaled to that level first (as
    the app draws them, widened above level 256)."""
    if level is None:
        return apply(base, raw, bound)
    fine, up = level.splats(world, raw)
    return splats.widened(apply(fine, up, bound), splats.widen(level.size))


def drawn_level(frames: Frames, cfg: RefinerTrainConfig) -> splats.Level | None:
    """The splat level the refined splats are drawn at (None: the map's own 128²)."""
    return splats.Level(frames.ds.pixels, frames.colors, cfg.splat_level) if cfg.splat_level != 128 else None
