"""The action-conditioned UNet over a group of 4 latent frames: residual blocks with a
per-frame timestep embedding, spatial self-attention, cross-attention to one action token
(5 actions + a null one for classifier-free guidance) and causal temporal attention with a
frame-position encoding. It predicts the noise of every frame; training uses the last."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .layers import CrossAttention, Down, ResBlock, SpatialAttention, TemporalAttention, Up, norm, timestep_embedding

NULL_ACTION = 5


@dataclass
class UNetConfig:
    latent: int = 4
    channels: tuple = (64, 128)  # at 16x16 and 8x8
    embed: int = 128
    heads: int = 4
    frames: int = 4
    actions: int = 5

    def to_dict(self):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


class AttentionStack(nn.Module):
    """Spatial self-attention, cross-attention to the action, temporal attention."""

    def __init__(self, c: int, cfg: UNetConfig):
        super().__init__()
        self.spatial = SpatialAttention(c, cfg.heads)
        self.cross = CrossAttention(c, cfg.embed, cfg.heads)
        self.temporal = TemporalAttention(c, cfg.frames, cfg.heads)

    def forward(self, h, action_token):
        return self.temporal(self.cross(self.spatial(h), action_token))


class UNet(nn.Module):
    def __init__(self, cfg: UNetConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or UNetConfig()
        c0, c1 = cfg.channels
        e = cfg.embed
        self.time_mlp = nn.Sequential(nn.Linear(e, e), nn.SiLU(), nn.Linear(e, e))
        self.action = nn.Embedding(cfg.actions + 1, e)
        self.conv_in = nn.Conv2d(cfg.latent, c0, 3, padding=1)
        self.down0 = ResBlock(c0, c0, e)
        self.temporal0 = TemporalAttention(c0, cfg.frames, cfg.heads)
        self.down = Down(c0, c0)
        self.down1 = ResBlock(c0, c1, e)
        self.attn1 = AttentionStack(c1, cfg)
        self.mid1 = ResBlock(c1, c1, e)
        self.mid_attn = AttentionStack(c1, cfg)
        self.mid2 = ResBlock(c1, c1, e)
        self.up1 = ResBlock(2 * c1, c1, e)
        self.up_attn = AttentionStack(c1, cfg)
        self.up = Up(c1, c1)
        self.up0 = ResBlock(c1 + c0, c0, e)
        self.temporal_up0 = TemporalAttention(c0, cfg.frames, cfg.heads)
        self.norm_out = norm(c0)
        self.conv_out = nn.Conv2d(c0, cfg.latent, 3, padding=1)
        # The output starts at zero: an untrained model predicts no noise.
        nn.init.zeros_(self.conv_out.weight)
        nn.init.zeros_(self.conv_out.bias)

    def forward(self, x: torch.Tensor, t: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """x [B, F, C, 16, 16] latents, t [B, F] timesteps, action [B] ids (5 = null)."""
        b, f, c, h, w = x.shape
        emb = self.time_mlp(timestep_embedding(t.reshape(-1), self.cfg.embed))  # [B*F, E]
        token = self.action(action)[:, None, :].repeat_interleave(f, 0)  # [B*F, 1, E]
        x = x.reshape(b * f, c, h, w)
        h0 = self.temporal0(self.down0(self.conv_in(x), emb))
        h1 = self.attn1(self.down1(self.down(h0), emb), token)
        m = self.mid2(self.mid_attn(self.mid1(h1, emb), token), emb)
        u1 = self.up_attn(self.up1(torch.cat([m, h1], 1), emb), token)
        u0 = self.temporal_up0(self.up0(torch.cat([self.up(u1), h0], 1), emb))
        out = self.conv_out(F.silu(self.norm_out(u0)))
        return out.reshape(b, f, c, h, w)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def conv_and_linear_flops(model: nn.Module, *inputs) -> int:
    """FLOPs (2 per multiply-add) of the convolutions, linear layers and attention
    products of one forward pass, counted with hooks; norms and activations are ignored."""
    total = 0

    def conv_hook(m, inp, out):
        nonlocal total
        k = m.kernel_size[0] * m.kernel_size[1] * (m.in_channels // m.groups)
        total += 2 * out.numel() * k

    def linear_hook(m, inp, out):
        nonlocal total
        total += 2 * out.numel() * m.in_features

    hooks = []
    for m in model.modules():
        if isinstance(m, nn.Conv2d):
            hooks.append(m.register_forward_hook(conv_hook))
        elif isinstance(m, nn.Linear):
            hooks.append(m.register_forward_hook(linear_hook))

    import unica_train.layers as layers

    original = layers.attention

    def counted(q, k, v, mask=None):
        nonlocal total
        total += 2 * q.shape[:-1].numel() * k.shape[-2] * q.shape[-1] * 2
        return original(q, k, v, mask)

    layers.attention = counted
    try:
        with torch.no_grad():
            model(*inputs)
    finally:
        layers.attention = original
        for hook in hooks:
            hook.remove()
    return total
