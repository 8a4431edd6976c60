"""The position-map VAE: 3x128x128 maps <-> 4x16x16 latents (x8 down), small enough that the
decoder stays under 0.5 GFLOP (DESIGN §5). L1 on the foreground plus a small KL."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .layers import Down, ResBlock, Up, norm


@dataclass
class VaeConfig:
    # Channels at 16, 32, 64 and 128 pixels (the decoder's order; the encoder mirrors it).
    channels: tuple = (64, 48, 24, 12)
    latent: int = 4
    kl_weight: float = 1e-6

    def to_dict(self):
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


class Encoder(nn.Module):
    def __init__(self, cfg: VaeConfig):
        super().__init__()
        c16, c32, c64, c128 = cfg.channels
        self.conv_in = nn.Conv2d(3, c128, 3, padding=1)
        self.down = nn.ModuleList([Down(c128, c64), Down(c64, c32), Down(c32, c16)])
        self.res = nn.ModuleList([ResBlock(c64, c64), ResBlock(c32, c32), ResBlock(c16, c16)])
        self.norm_out = norm(c16)
        self.conv_out = nn.Conv2d(c16, 2 * cfg.latent, 3, padding=1)

    def forward(self, x):
        h = self.conv_in(x)
        for down, res in zip(self.down, self.res):
            h = res(down(h))
        mean, logvar = self.conv_out(F.silu(self.norm_out(h))).chunk(2, 1)
        return mean, logvar.clamp(-30, 20)


class Decoder(nn.Module):
    def __init__(self, cfg: VaeConfig):
        super().__init__()
        c16, c32, c64, c128 = cfg.channels
        self.conv_in = nn.Conv2d(cfg.latent, c16, 3, padding=1)
        self.res = nn.ModuleList([ResBlock(c16, c16), ResBlock(c32, c32), ResBlock(c64, c64)])
        self.up = nn.ModuleList([Up(c16, c32), Up(c32, c64), Up(c64, c128)])
        self.norm_out = norm(c128)
        self.conv_out = nn.Conv2d(c128, 3, 3, padding=1)

    def forward(self, z):
        h = self.conv_in(z)
        for res, up in zip(self.res, self.up):
            h = up(res(h))
        return self.conv_out(F.silu(self.norm_out(h)))


class PositionVae(nn.Module):
    def __init__(self, cfg: VaeConfig | None = None):
        super().__init__()
        self.cfg = cfg or VaeConfig()
        self.encoder, self.decoder = Encoder(self.cfg), Decoder(self.cfg)

    def encode(self, x, sample: bool = False, generator=None):
        mean, logvar = self.encoder(x)
        if not sample:
            return mean, mean, logvar
        noise = torch.randn(mean.shape, generator=generator, device=mean.device)
        return mean + (0.5 * logvar).exp() * noise, mean, logvar

    def decode(self, z, mask=None):
        x = self.decoder(z)
        return x * mask if mask is not None else x

    def forward(self, x, mask):
        """The training loss (so DistributedDataParallel can wrap the VAE)."""
        return self.loss(x, mask)

    def loss(self, x, mask, generator=None):
        """L1 on the foreground (mean over foreground values) + kl_weight * KL."""
        z, mean, logvar = self.encode(x, sample=True, generator=generator)
        recon = self.decode(z)
        l1 = ((recon - x).abs() * mask).sum() / (mask.sum() * 3 * x.shape[0] / mask.shape[0])
        kl = 0.5 * (mean.pow(2) + logvar.exp() - 1 - logvar).mean()
        return l1 + self.cfg.kl_weight * kl, {"l1": float(l1.detach()), "kl": float(kl.detach())}
