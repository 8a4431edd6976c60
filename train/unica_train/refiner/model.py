"""The splat refiner's network (docs/architecture.md, Appearance): a small point
transformer in the spirit of PTv3 that predicts per-Gaussian residuals of every attribute
from the base splats of a frame. Pure PyTorch: what it sees and makes of splats is
`frames.py`, its training `training.py`, its evaluation `evaluation.py`.

- Serialisation: positions quantised to 1024 bins per axis, ordered along a z-order and a
  Hilbert curve and their transposes (x and y swapped); attention block i uses order i % 4.
- Attention inside fixed-size patches of the order (the last patch is shorter).
- Strided pooling between stages: groups of `stride` consecutive points along the stage's
  z-order are averaged (features and positions); unpooling copies a group's features
  back to its points and adds them to the skip connection.
- Per-attribute heads in one zero-initialised linear layer, so the refiner starts as the
  identity; mean offsets are tanh-bounded.

It runs on the 128² point set; the app upscales its residual maps to the 1024² splats."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

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


# ---- the network ----------------------------------------------------------------------


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


# ---- weights ----------------------------------------------------------------------------


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
