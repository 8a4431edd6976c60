"""The splat refiner (docs/architecture.md, Appearance): a small point transformer in the spirit of PTv3 that
predicts per-Gaussian residuals of every attribute from the base splats of a frame.

- Serialisation: positions quantised to 1024 bins per axis, ordered along a z-order and a
  Hilbert curve and their transposes (x and y swapped); attention block i uses order i % 4.
- Attention inside fixed-size patches of the order (the last patch is shorter).
- Strided pooling between stages: groups of `stride` consecutive points along the stage's
  z-order are averaged (features and positions); unpooling copies a group's features
  back to its points and adds them to the skip connection.
- Per-attribute heads in one zero-initialised linear layer, so the refiner starts as the
  identity; mean offsets are tanh-bounded.

It runs on the 128² point set; the app upscales its residual maps to the 1024² splats.
Train it on a baked dataset's renders (L1 + SSIM over random black or white backgrounds):

    python -m unica_train.refiner --bundle B --data DATA --out RUN [--steps N] [--resume]

which writes RUN/refiner.safetensors, losses, eval.json (PSNR/SSIM of base vs refined
splats on the held-out clips) and adds `refiner.*` to the bundle."""

from __future__ import annotations

import argparse
import csv
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import save_file
from torch import nn

from . import bundle as bundle_io
from . import checkpoint as checkpoint_file
from . import pca, splats
from .dataset import BakedDataset

BITS = 10
ORDERS = ("z", "z-trans", "hilbert", "hilbert-trans")
FEATURES = 11
OUTPUTS = 14  # mean 3, colour 3, log-scale 3, rotation 4, opacity logit 1
LN_EPS = 1e-5


# ---- serialisation ------------------------------------------------------------------


def quantise(unit: torch.Tensor) -> torch.Tensor:
    """Unit-cube positions [N, 3] -> integer cells [N, 3] in [0, 1023]."""
    return (unit * (1 << BITS)).floor().clamp(0, (1 << BITS) - 1).long()


def _interleave(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """Bits of x, y, z interleaved from the most significant: x_9 y_9 z_9 x_8 ..."""
    code = torch.zeros_like(x)
    for b in range(BITS - 1, -1, -1):
        for axis in (x, y, z):
            code = (code << 1) | ((axis >> b) & 1)
    return code


def z_order(cells: torch.Tensor) -> torch.Tensor:
    return _interleave(cells[:, 0], cells[:, 1], cells[:, 2])


def hilbert(cells: torch.Tensor) -> torch.Tensor:
    """Hilbert index of 3-D cells (Skilling's transpose algorithm, then interleaved)."""
    x = [cells[:, 0].clone(), cells[:, 1].clone(), cells[:, 2].clone()]
    q = 1 << (BITS - 1)
    while q > 1:
        p = q - 1
        for i in range(3):
            on = (x[i] & q) != 0
            if i == 0:
                x[0] = torch.where(on, x[0] ^ p, x[0])
                continue
            t = (x[0] ^ x[i]) & p
            x[0], x[i] = torch.where(on, x[0] ^ p, x[0] ^ t), torch.where(on, x[i], x[i] ^ t)
        q >>= 1
    for i in (1, 2):
        x[i] = x[i] ^ x[i - 1]
    t = torch.zeros_like(x[0])
    q = 1 << (BITS - 1)
    while q > 1:
        t = torch.where((x[2] & q) != 0, t ^ (q - 1), t)
        q >>= 1
    return _interleave(*(v ^ t for v in x))


def serialise(unit: torch.Tensor, kind: str) -> torch.Tensor:
    """The order (a permutation [N]) of points along curve `kind`; ties keep index order."""
    cells = quantise(unit)
    if kind.endswith("-trans"):
        cells = cells[:, [1, 0, 2]]
    code = z_order(cells) if kind.startswith("z") else hilbert(cells)
    return torch.argsort(code, stable=True)


# ---- the model ----------------------------------------------------------------------


@dataclass
class RefinerConfig:
    channels: list = field(default_factory=lambda: [32, 64])
    depths: list = field(default_factory=lambda: [2, 2])
    heads: list = field(default_factory=lambda: [2, 4])
    decoder_depth: int = 1
    patch: int = 64
    stride: int = 4
    # Bound of the mean offsets in normalised units (the Witch: 0.004 ≈ 11 mm).
    mean_bound: float = 0.004
    # Rows of a learned residual per map pixel, added to the network's output (the map's
    # foreground pixel count; 0: none). The map's pixels are fixed surface points, so
    # this holds what each point needs in every pose (its colour, size and opacity
    # against the teacher's); the network predicts what changes with the pose (#17).
    pixel_residuals: int = 0

    def to_dict(self):
        return asdict(self)


def patch_attention(qkv: torch.Tensor, order: torch.Tensor, patch: int, heads: int) -> torch.Tensor:
    """qkv [N, 3C] (q, k, v, each head's channels together) -> [N, C]: each point attends
    to the points of its patch of `order`."""
    n, c3 = qkv.shape
    c = c3 // 3
    d = c // heads
    patches = -(-n // patch)
    pad = patches * patch - n
    rows = torch.cat([order, order.new_zeros(pad)])
    x = qkv[rows].reshape(patches, patch, 3, heads, d).permute(2, 0, 3, 1, 4)  # [3, P, H, T, d]
    valid = torch.arange(patches * patch) < n
    bias = torch.where(valid, 0.0, float("-inf")).reshape(patches, 1, 1, patch)
    att = (x[0] @ x[1].transpose(-1, -2)) / math.sqrt(d) + bias
    out = (att.softmax(-1) @ x[2]).permute(0, 2, 1, 3).reshape(patches * patch, c)[:n]
    result = torch.empty_like(out)
    result[order] = out
    return result


class Block(nn.Module):
    def __init__(self, channels: int, heads: int):
        super().__init__()
        self.heads = heads
        self.norm1 = nn.LayerNorm(channels, eps=LN_EPS)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.proj = nn.Linear(channels, channels)
        self.norm2 = nn.LayerNorm(channels, eps=LN_EPS)
        self.fc1 = nn.Linear(channels, 2 * channels)
        self.fc2 = nn.Linear(2 * channels, channels)

    def forward(self, x, order, patch):
        x = x + self.proj(patch_attention(self.qkv(self.norm1(x)), order, patch, self.heads))
        return x + self.fc2(F.silu(self.fc1(self.norm2(x))))


def pool_groups(order: torch.Tensor, stride: int) -> tuple[torch.Tensor, int]:
    """Each point's group ([N]: its rank along `order` // stride) and the group count."""
    group = torch.empty_like(order)
    group[order] = torch.arange(len(order)) // stride
    return group, -(-len(order) // stride)


def segment_mean(x: torch.Tensor, order: torch.Tensor, stride: int) -> torch.Tensor:
    """The mean of each run of `stride` consecutive rows along `order` (summed in order)."""
    groups = -(-len(order) // stride)
    index = torch.arange(len(order)) // stride
    total = torch.zeros(groups, x.shape[1], dtype=x.dtype).index_add(0, index, x[order])
    count = torch.zeros(groups, dtype=x.dtype).index_add(0, index, torch.ones(len(order), dtype=x.dtype))
    return total / count[:, None]


class Refiner(nn.Module):
    def __init__(self, cfg: RefinerConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or RefinerConfig()
        c0, c1 = cfg.channels
        self.embed = nn.Linear(FEATURES, c0)
        self.encoder = nn.ModuleList(Block(c0, cfg.heads[0]) for _ in range(cfg.depths[0]))
        self.down = nn.Linear(c0, c1)
        self.middle = nn.ModuleList(Block(c1, cfg.heads[1]) for _ in range(cfg.depths[1]))
        self.up = nn.Linear(c1, c0)
        self.decoder = nn.ModuleList(Block(c0, cfg.heads[0]) for _ in range(cfg.decoder_depth))
        self.norm = nn.LayerNorm(c0, eps=LN_EPS)
        self.head = nn.Linear(c0, OUTPUTS)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.pixel = nn.Parameter(torch.zeros(cfg.pixel_residuals, OUTPUTS)) if cfg.pixel_residuals else None

    def forward(self, features: torch.Tensor, unit: torch.Tensor) -> torch.Tensor:
        """features [N, 11], unit positions [N, 3] -> raw residuals [N, 14]."""
        cfg = self.cfg
        fine = [serialise(unit, k) for k in ORDERS]
        coarse_unit = segment_mean(unit, fine[0], cfg.stride)
        coarse = [serialise(coarse_unit, k) for k in ORDERS]
        group, _ = pool_groups(fine[0], cfg.stride)
        block = 0
        x = self.embed(features)
        for b in self.encoder:
            x = b(x, fine[block % 4], cfg.patch)
            block += 1
        skip = x
        y = self.down(segment_mean(x, fine[0], cfg.stride))
        for b in self.middle:
            y = b(y, coarse[block % 4], cfg.patch)
            block += 1
        x = skip + self.up(y)[group]
        for b in self.decoder:
            x = b(x, fine[block % 4], cfg.patch)
            block += 1
        out = self.head(self.norm(x))
        if self.pixel is None:
            return out
        if self.pixel.shape[0] != out.shape[0]:
            raise ValueError(f"the refiner's pixel residuals have {self.pixel.shape[0]} rows for {out.shape[0]} points")
        return out + self.pixel


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def flops(cfg: RefinerConfig, points: int) -> int:
    """Multiply-adds × 2 of the linear layers and the patch attention for `points`."""
    c0, c1 = cfg.channels
    coarse = -(-points // cfg.stride)

    def block(n, c):
        return 2 * n * (3 * c * c + c * c + 4 * c * c) + 2 * 2 * n * cfg.patch * c

    total = 2 * points * FEATURES * c0 + cfg.depths[0] * block(points, c0)
    total += 2 * coarse * c0 * c1 + cfg.depths[1] * block(coarse, c1) + 2 * coarse * c1 * c0
    total += cfg.decoder_depth * block(points, c0) + 2 * points * c0 * OUTPUTS
    return total + (points * OUTPUTS if cfg.pixel_residuals else 0)


# ---- inputs and outputs ---------------------------------------------------------------


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


# ---- training -----------------------------------------------------------------------


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
    the app draws them)."""
    if level is None:
        return apply(base, raw, bound)
    fine, up = level.splats(world, raw)
    return apply(fine, up, bound)


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


def drawn_level(frames: Frames, cfg: RefinerTrainConfig) -> splats.Level | None:
    """The splat level the refined splats are drawn at (None: the map's own 128²)."""
    return splats.Level(frames.ds.pixels, frames.colors, cfg.splat_level) if cfg.splat_level != 128 else None


def frame_generator(bundle: Path, data: Path, cfg: RefinerTrainConfig):
    """When the config trains on generated frames: a function (clip, f, generator) -> the
    bundle's generated world points [N, 3] of that frame, made as `unica eval` makes its
    teacher-forced frames; else None."""
    if cfg.generated_fraction == 0:
        return None
    from .eval import Avatar, teacher_forced  # eval draws with this module's refiner

    avatar = Avatar(bundle, data, cfg.splat_level)
    return lambda clip, f, gen: teacher_forced(avatar, clip, f, gen)[0]


def train(args) -> dict:
    from .train import distributed, leave_process_group, training_device

    cfg = train_config(args.config)
    if args.steps is not None:
        cfg.steps, cfg.samples = args.steps, 0
    if args.samples is not None:
        cfg.samples = args.samples
    rank, world = distributed(args.device)
    device = training_device(args.device, world)
    steps = cfg.total_steps(world)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    if rank == 0:
        (out / "refiner_config.json").write_text(json.dumps(asdict(cfg), indent=2) + "\n")
    torch.manual_seed(cfg.seed)  # the same initial weights in every process
    # Each process draws its own frames.
    gen = torch.Generator().manual_seed(cfg.seed + rank)
    frames = Frames(args.data, args.bundle, cfg.image_size)
    train_keys = [k for k in frames.keys if k[0] not in cfg.held_out_clips]
    test_keys = held_out_keys(frames, cfg)
    model_cfg = RefinerConfig(**cfg.model)
    if cfg.pixel_table and model_cfg.pixel_residuals == 0:
        model_cfg.pixel_residuals = len(frames.ds.pixels)
    if model_cfg.pixel_residuals not in (0, len(frames.ds.pixels)):
        raise ValueError(f"{args.config}: pixel_residuals {model_cfg.pixel_residuals} is not the map's {len(frames.ds.pixels)} foreground pixels")
    model = Refiner(model_cfg).to(device)
    network = [p for name, p in model.named_parameters() if name != "pixel"]
    groups = [{"params": network, "lr": cfg.lr}]
    if model.pixel is not None:
        groups.append({"params": [model.pixel], "lr": cfg.pixel_lr})
    opt = torch.optim.Adam(groups)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    start = 0
    ckpt = out / "refiner_checkpoint.pt"
    log_path = out / "refiner_losses.csv"
    if args.resume and ckpt.exists():
        state = checkpoint_file.load(ckpt, map_location="cpu")
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        sched.T_max = steps  # this run's length: the number of processes may differ
        start = state["step"]
        # The checkpoint holds the first process's frame draws; the others (any number of
        # them, not necessarily the number that wrote it) draw on from their own seeds.
        if rank == 0:
            gen.set_state(state["gen"])
        else:
            gen.manual_seed(cfg.seed + rank + 7919 * start)
        if start > steps:
            raise SystemExit(f"{ckpt}: step {start} is past this run's {steps} steps")
        if rank == 0:
            print(f"resumed at step {start}")
    else:
        if log_path.exists() and rank == 0:
            log_path.unlink()
        if args.init is not None:
            init_from_bundle(model, args.init)
    # The frames' inputs and renders, and the tensors the splat code makes, live on the
    # device; the frame draws stay on the CPU generator.
    frames.to(device)
    bound = model.cfg.mean_bound / frames.scale
    with torch.device(device):
        level = drawn_level(frames, cfg)
    generate = frame_generator(args.bundle, args.data, cfg)
    # Data-parallel: gradients averaged over the processes after each backward pass.
    trained = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    began = time.time()
    for step in range(start, steps):
        key = train_keys[int(torch.randint(len(train_keys), (1,), generator=gen))]
        points = frames.world(key)
        if generate is not None and key[1] >= 3 and torch.rand(1, generator=gen).item() < cfg.generated_fraction:
            points = generate(key[0], key[1], gen).to(device)
        views = frames.views[key]
        chosen = torch.randperm(len(views), generator=gen)[: cfg.views_per_step]
        backgrounds = [torch.rand(1, generator=gen).item() < 0.5 for _ in chosen]
        with torch.device(device):
            base, feats, unit = frames.inputs_at(points)
            drawn = refined(base, trained(feats, unit), bound, level, points)
            loss_l1, loss_ssim, loss_alpha = 0.0, 0.0, 0.0
            for v, white in zip(chosen, backgrounds):
                cam, target = frames.target(views[int(v)])
                bg = torch.ones(3) if white else torch.zeros(3)
                image, alpha = splats.render(drawn, cam, bg)
                got, want = splats.srgb(image), splats.srgb(composite(target, bg))
                loss_l1 = loss_l1 + (got - want).abs().mean()
                loss_ssim = loss_ssim + 1 - splats.ssim(got, want)
                loss_alpha = loss_alpha + (alpha - target[..., 3]).abs().mean()
            loss = ((1 - cfg.ssim_weight) * loss_l1 + cfg.ssim_weight * loss_ssim + cfg.alpha_weight * loss_alpha) / len(chosen)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        done = step + 1
        if rank != 0:
            continue
        with log_path.open("a", newline="") as f:
            csv.writer(f).writerow([step, f"{loss.item():.6f}", f"{loss_l1.item() / len(chosen):.6f}"])
        if done % 10 == 0 or done == steps:
            rate = (done - start) / (time.time() - began)
            print(f"step {done}/{steps} loss {loss.item():.4f} ({rate:.2f} steps/s, {(steps - done) / rate / 60:.1f} min left)", flush=True)
        if done % cfg.checkpoint_every == 0 or done == steps:
            checkpoint_file.save({"model": model.state_dict(), "opt": opt.state_dict(), "sched": sched.state_dict(), "gen": gen.get_state(), "step": done}, ckpt)
    if world > 1:
        leave_process_group(rank, world, model)
    model = model.cpu().eval()
    frames.to(torch.device("cpu"))
    level = drawn_level(frames, cfg)
    metrics = evaluate(model, frames, test_keys, level)
    metrics.update({
        "parameters": parameter_count(model),
        "gflop_per_frame": flops(model.cfg, len(frames.ds.pixels)) / 1e9,
        "held_out_clips": cfg.held_out_clips,
        "image_size": cfg.image_size,
        "splat_level": cfg.splat_level,
        "minutes": (time.time() - began) / 60,
        "steps": steps,
        "processes": world,
        "device": str(device),
    })
    (out / "refiner_eval.json").write_text(json.dumps(metrics, indent=2) + "\n")
    save_file({f"refiner.{k}": v.contiguous() for k, v in model.state_dict().items()}, str(out / "refiner.safetensors"))
    if args.write_bundle:
        add_to_bundle(args.bundle, model)
    return metrics


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
    (args.out / "refiner_eval.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def state_from(tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The refiner's state dict from a bundle's tensors (`refiner.*`, prefix removed)."""
    return {k.removeprefix("refiner."): v for k, v in tensors.items() if k.startswith("refiner.")}


def from_bundle(manifest: dict, tensors: dict[str, torch.Tensor]) -> Refiner | None:
    """A bundle's refiner (its manifest's config, its `refiner.*` weights) ready to run;
    None when the bundle has none."""
    if "refiner" not in manifest:
        return None
    model = Refiner(RefinerConfig(**manifest["refiner"]))
    model.load_state_dict(state_from(tensors))
    return model.eval()


def init_from_bundle(model: Refiner, directory: Path) -> None:
    """Starts `model` from the refiner in another bundle (fine-tuning it for a new VAE or
    splat level, or adding per-pixel residuals, which then start at zero); the bundle's
    refiner config must be the model's but for `pixel_residuals`."""
    manifest = json.loads((Path(directory) / "manifest.json").read_text())
    theirs = dict(manifest.get("refiner") or {})
    ours = model.cfg.to_dict()
    adding = theirs.get("pixel_residuals", 0) == 0 and ours["pixel_residuals"] > 0
    if adding:
        theirs["pixel_residuals"] = ours["pixel_residuals"]
    if not theirs or RefinerConfig(**theirs).to_dict() != ours:
        raise bundle_io.BundleError(f"{directory}: its refiner config {manifest.get('refiner')} is not this run's {ours}")
    state = state_from(bundle_io.read_weights(Path(directory) / "weights.safetensors"))
    if adding:
        state["pixel"] = torch.zeros_like(model.pixel)
    model.load_state_dict(state)
    print(f"started from the refiner in {directory}" + (" (per-pixel residuals from zero)" if adding else ""), flush=True)


def add_to_bundle(directory: Path, model: Refiner) -> None:
    """Writes `refiner.*` and the manifest's `refiner` config into a bundle (the geometry
    models are untouched)."""
    d = Path(directory)
    tensors = bundle_io.read_weights(d / "weights.safetensors")
    tensors = {k: v for k, v in tensors.items() if not k.startswith("refiner.")}
    tensors.update({f"refiner.{k}": v.detach().contiguous() for k, v in model.state_dict().items()})
    manifest = json.loads((d / "manifest.json").read_text())
    manifest["refiner"] = model.cfg.to_dict()
    bundle_io.write_weights(d, tensors, manifest)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
