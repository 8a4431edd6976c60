"""The position-map VAE: 3x128x128 maps <-> 4x16x16 latents (x8 down), small enough that the
decoder stays under 0.5 GFLOP (docs/architecture.md, The geometry model). L1 on the foreground plus a small KL.

Two decoders (`VaeConfig.decoder`): "conv", the upsampling convolutions, and "pca", a linear
head onto a fixed PCA basis of training maps (`PcaDecoder`): the character's pose space is
nearly linear (200 components reconstruct held-out maps to 0.01 mm), and the PCA head
reaches 8.2 mm held out where the conv decoder reaches 40.6 at the same 3,000 steps
(docs/vae_ablations.md)."""

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
    # "conv" or "pca"; the PCA head's basis size, and the map it writes (foreground pixels
    # and side, set from the dataset by the trainer).
    decoder: str = "conv"
    components: int = 200
    pixels: int = 0
    map_size: int = 128

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


class PcaDecoder(nn.Module):
    """map foreground = mean + (W z + b) @ basis; background 0. `z` [N, latent, S/8, S/8]
    flattened; `basis` [K, 3P] holds K orthonormal rows over the foreground values in
    channel-major order (x of every pixel, then y, then z), fitted once on training maps
    (`fit`) and then fixed; only the linear head W, b (zero at the start) trains."""

    def __init__(self, cfg: VaeConfig):
        super().__init__()
        if cfg.pixels <= 0:
            raise ValueError("a PCA-head decoder needs the map's foreground pixel count (VaeConfig.pixels)")
        self.size = cfg.map_size
        self.head = nn.Linear(cfg.latent * (cfg.map_size // 8) ** 2, cfg.components)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.register_buffer("mean", torch.zeros(3 * cfg.pixels))
        self.register_buffer("basis", torch.zeros(cfg.components, 3 * cfg.pixels))
        self.register_buffer("pixels", torch.zeros(cfg.pixels, dtype=torch.int32))

    def fit(self, maps: torch.Tensor, pixels: torch.Tensor):
        """Sets the basis from training maps [M, 3, S, S] and the foreground pixels [P]."""
        from . import pca

        values = maps.flatten(2)[:, :, pixels].flatten(1)
        mean, basis = pca.fit(values, self.basis.shape[0])
        if basis.shape[0] < self.basis.shape[0]:
            raise ValueError(f"{values.shape[0]} maps cannot give {self.basis.shape[0]} PCA components")
        self.mean.copy_(mean)
        self.basis.copy_(basis)
        self.pixels.copy_(pixels.int())

    def forward(self, z):
        n = z.shape[0]
        values = self.mean + self.head(z.flatten(1)) @ self.basis
        out = values.new_zeros(n, 3, self.size * self.size)
        out[:, :, self.pixels.long()] = values.view(n, 3, -1)
        return out.view(n, 3, self.size, self.size)


class PositionVae(nn.Module):
    def __init__(self, cfg: VaeConfig | None = None):
        super().__init__()
        self.cfg = cfg or VaeConfig()
        if self.cfg.decoder not in ("conv", "pca"):
            raise ValueError(f"unknown VAE decoder {self.cfg.decoder!r} (conv or pca)")
        decoder = PcaDecoder(self.cfg) if self.cfg.decoder == "pca" else Decoder(self.cfg)
        self.encoder, self.decoder = Encoder(self.cfg), decoder

    def decoder_flops(self) -> int:
        """FLOPs of one decode the hooks of `conv_and_linear_flops` do not see: the PCA
        head's product with its basis."""
        if self.cfg.decoder != "pca":
            return 0
        return 2 * self.decoder.basis.numel()

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
