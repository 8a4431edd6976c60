"""Building blocks shared by the VAE and the UNet: residual conv blocks with group norm,
resampling, and the attention kinds (spatial, cross to the action token, temporal)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def norm(channels: int) -> nn.GroupNorm:
    """Group norm with up to 8 groups (the largest count that divides the channels)."""
    return nn.GroupNorm(math.gcd(8, channels), channels, eps=1e-5)


class ResBlock(nn.Module):
    """GroupNorm-SiLU-Conv twice, an optional per-sample embedding added in between, and
    a 1x1 skip when the channel count changes."""

    def __init__(self, c_in: int, c_out: int, emb: int | None = None):
        super().__init__()
        self.norm1, self.conv1 = norm(c_in), nn.Conv2d(c_in, c_out, 3, padding=1)
        self.emb = nn.Linear(emb, c_out) if emb else None
        self.norm2, self.conv2 = norm(c_out), nn.Conv2d(c_out, c_out, 3, padding=1)
        self.skip = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, emb: torch.Tensor | None = None) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        if self.emb is not None:
            h = h + self.emb(F.silu(emb))[:, :, None, None]
        h = self.conv2(F.silu(self.norm2(h)))
        return self.skip(x) + h


class Down(nn.Module):
    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, 3, stride=2, padding=1)

    def forward(self, x):
        return self.conv(x)


class Up(nn.Module):
    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, 3, padding=1)

    def forward(self, x):
        return self.conv(F.interpolate(x, scale_factor=2, mode="nearest"))


def attention(q, k, v, mask=None):
    """Softmax attention over the second-to-last axis; q, k, v: [..., heads, tokens, dim]."""
    scores = q @ k.transpose(-1, -2) / math.sqrt(q.shape[-1])
    if mask is not None:
        scores = scores.masked_fill(~mask, float("-inf"))
    return scores.softmax(-1) @ v


class SpatialAttention(nn.Module):
    """Self-attention among the H*W positions of each frame."""

    def __init__(self, channels: int, heads: int):
        super().__init__()
        self.heads = heads
        self.norm = norm(channels)
        self.qkv = nn.Linear(channels, 3 * channels)
        self.out = nn.Linear(channels, channels)

    def forward(self, x):
        b, c, h, w = x.shape
        t = self.norm(x).flatten(2).transpose(1, 2)  # [b, hw, c]
        q, k, v = self.qkv(t).reshape(b, h * w, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        o = attention(q, k, v).transpose(1, 2).reshape(b, h * w, c)
        return x + self.out(o).transpose(1, 2).reshape(b, c, h, w)


class CrossAttention(nn.Module):
    """Every position attends to the context tokens (here: the one action token)."""

    def __init__(self, channels: int, context: int, heads: int):
        super().__init__()
        self.heads = heads
        self.norm = norm(channels)
        self.q = nn.Linear(channels, channels)
        self.kv = nn.Linear(context, 2 * channels)
        self.out = nn.Linear(channels, channels)

    def forward(self, x, ctx):
        b, c, h, w = x.shape
        d = c // self.heads
        t = self.norm(x).flatten(2).transpose(1, 2)
        q = self.q(t).reshape(b, h * w, self.heads, d).transpose(1, 2)
        k, v = self.kv(ctx).reshape(b, ctx.shape[1], 2, self.heads, d).permute(2, 0, 3, 1, 4)
        o = attention(q, k, v).transpose(1, 2).reshape(b, h * w, c)
        return x + self.out(o).transpose(1, 2).reshape(b, c, h, w)


class TemporalAttention(nn.Module):
    """Each position attends across the frames of its group, with a learned frame-position
    encoding and a causal mask (frame i sees frames <= i: clean context frames never see the
    noisy target, so their activations can be computed once per generated frame)."""

    def __init__(self, channels: int, frames: int, heads: int):
        super().__init__()
        self.heads, self.frames = heads, frames
        self.norm = norm(channels)
        self.position = nn.Parameter(torch.zeros(frames, channels))
        self.qkv = nn.Linear(channels, 3 * channels)
        self.out = nn.Linear(channels, channels)
        nn.init.normal_(self.position, std=0.02)

    def forward(self, x):
        bf, c, h, w = x.shape
        f = self.frames
        b = bf // f
        t = self.norm(x).reshape(b, f, c, h * w).permute(0, 3, 1, 2)  # [b, hw, f, c]
        t = t + self.position
        q, k, v = self.qkv(t).reshape(b, h * w, f, 3, self.heads, c // self.heads).permute(3, 0, 1, 4, 2, 5)
        causal = torch.ones(f, f, dtype=torch.bool, device=x.device).tril()
        o = attention(q, k, v, causal).permute(0, 1, 3, 2, 4).reshape(b, h * w, f, c)
        o = self.out(o).permute(0, 2, 3, 1).reshape(bf, c, h, w)
        return x + o


def timestep_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal embedding of (float) timesteps: [...] -> [..., dim], cos then sin."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    args = t.float()[..., None] * freqs
    return torch.cat([args.cos(), args.sin()], -1)
