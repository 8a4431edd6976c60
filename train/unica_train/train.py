"""Trains the geometry model on a baked dataset and writes the bundle:

    python -m unica_train.train --data DATA --out OUT [--config CONFIG.json] [--resume] [--init BUNDLE]
        [--extra-data MORE] [--unet-only]

Stages: the VAE; latents of every 4-frame group; UNet stage 1 (steady locomotion) and
stage 2 (frames just after a key change oversampled, action embeddings frozen), with
context-noise augmentation, CFG dropout, Min-SNR weights, noise offset and EMA; PCA; then
the evaluation numbers, the bundle, losses.csv and curves.png. Runs on CUDA (bf16
autocast) when present, else on the CPU; checkpoints after every stage and every
`checkpoint_every` steps so `--resume` continues where a run stopped. `--init BUNDLE`
continues a shipped bundle: its VAE (and its splat refiner, which was fit to that VAE) are
kept as they are, and its UNet is trained further on the config's schedule. With
`--unet-only` as well, the run writes the --init bundle again with only its UNet replaced
(its sampler settings, PCA, decoder head and refiner kept; the held-out denoising errors
before and after in metrics.json) and skips the PCA, evaluation and rollout. A config's
`unet_minutes` fits the UNet's schedule to a time budget (a borrowed GPU): after 30
steps the two stages are shortened in proportion to what fits at the measured pace, and
`unet_schedule.json` records the steps run. `--extra-data` adds the clips of another
dataset of the same character (`unica bake --switch-phases`) to the training clips."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch

from . import bundle, pca
from . import checkpoint as checkpoint_file
from .dataset import ANCHOR, BakedDataset, DatasetError, quarter_turn, quarter_turn_action
from .diffusion import Schedule, sample_next
from .plot import curves
from .unet import NULL_ACTION, UNet, UNetConfig, conv_and_linear_flops, parameter_count
from .vae import PositionVae, VaeConfig

DDP = torch.nn.parallel.DistributedDataParallel


@dataclass
class TrainConfig:
    vae: dict = field(default_factory=lambda: VaeConfig().to_dict())
    unet: dict = field(default_factory=lambda: UNetConfig().to_dict())
    vae_steps: int = 3000
    vae_batch: int = 16
    vae_lr: float = 1e-3
    unet_steps: int = 6000
    stage2_steps: int = 1500
    unet_batch: int = 32
    unet_lr: float = 3e-4
    after_switch_share: float = 0.7
    cfg_dropout: float = 0.1
    clean_context_share: float = 0.3
    context_max_t: int = 300
    noise_offset: float = 0.1
    # Also train the UNet on every training group turned by 90°, 180° and 270° about the
    # vertical, its action turned with it (dataset.quarter_turn): each stop, start and turn
    # of the transition table then appears facing all four key directions.
    quarter_turns: bool = False
    min_snr_gamma: float = 5.0
    ema: float = 0.999
    pca_components: int = 200
    pca_frames: int = 3000
    held_out_clips: list = field(default_factory=lambda: [4, 13])
    rollout_keys: str = "60W 60S 60A 20I"
    rollout_frames: int = 300
    ddim_steps: int = 10
    cfg_scale: float = 1.0
    checkpoint_every: int = 500
    # > 0: shorten the UNet's two stages, in proportion, to what fits in this many minutes
    # at the pace of its first 30 steps (unet_schedule.json records the steps run).
    unet_minutes: float = 0.0
    seed: int = 0
    # > 0: a stage's schedule in samples (training groups seen) instead of steps: each
    # step sees a batch on each data-parallel process, so the steps are
    # samples / (batch x processes), and a larger batch or more processes see the same
    # data in fewer steps.
    vae_samples: int = 0
    unet_samples: int = 0
    stage2_samples: int = 0
    # How the live loop samples and places each frame, written into the bundle's manifest
    # (src/engine/bundle.rs and src/nn/sampler.rs say what each does; `heading` is
    # "canonical" where the UNet learnt quarter turns, else "world"). The defaults are
    # those of bundles made before these settings; `unica make` gives the shipped Witch's
    # (train/configs/make_full.json).
    guide_idle: bool = True
    noise_scale: float = 1.0
    idle_brake_cfg_scale: float = 0.0  # 0: no brake
    idle_brake_frames: int = 0
    turn_brake_cfg_scale: float = 0.0  # 0: no turn brake
    turn_brake_frames: int = 0
    root_motion: str = "centre"  # or "decoded"
    grounded: bool = False
    stand_speed: float = 0.0  # m/s; 0: no stand latch

    def resolve_samples(self, processes: int) -> None:
        """Sets each stage's steps from its samples, where given."""
        for stage, batch in (("vae", self.vae_batch), ("unet", self.unet_batch), ("stage2", self.unet_batch)):
            samples = getattr(self, f"{stage}_samples")
            if samples > 0:
                setattr(self, f"{stage}_steps", math.ceil(samples / (batch * processes)))

    def __post_init__(self):
        from .recentre import ROOT_MOTIONS  # recentre imports this module

        if self.root_motion not in ROOT_MOTIONS:
            raise ValueError(f"root_motion {self.root_motion!r}: expected one of {ROOT_MOTIONS}")
        if self.noise_scale <= 0 or min(self.stand_speed, self.idle_brake_cfg_scale, self.idle_brake_frames,
                                        self.turn_brake_cfg_scale, self.turn_brake_frames) < 0:
            raise ValueError("noise_scale must be positive; stand_speed, idle_brake_cfg_scale, idle_brake_frames, "
                             "turn_brake_cfg_scale and turn_brake_frames not negative")

    def live(self) -> dict:
        """The manifest entries the live loop reads, from these settings."""
        sampler = {"ddim_steps": self.ddim_steps, "cfg_scale": self.cfg_scale,
                   "guide_idle": self.guide_idle, "noise_scale": self.noise_scale}
        if self.idle_brake_frames > 0 and self.idle_brake_cfg_scale > 0:
            sampler.update(idle_brake_cfg_scale=self.idle_brake_cfg_scale, idle_brake_frames=self.idle_brake_frames)
        if self.turn_brake_frames > 0 and self.turn_brake_cfg_scale > 0:
            sampler.update(turn_brake_cfg_scale=self.turn_brake_cfg_scale, turn_brake_frames=self.turn_brake_frames)
        out = {"sampler": sampler, "root_motion": self.root_motion, "grounded": self.grounded,
               "heading": "canonical" if self.quarter_turns else "world"}
        if self.stand_speed > 0:
            out["stand_speed"] = self.stand_speed
        return out


def bar(step: int, total: int, width: int = 24) -> str:
    """A text progress bar: [#####-------] 41%."""
    done = int(width * step / max(total, 1))
    return f"[{'#' * done}{'-' * (width - done)}] {100 * step // max(total, 1):3d}%"


def parse_keys(text: str, frames: int) -> list[int]:
    letters = {"I": 0, "W": 1, "S": 2, "A": 3, "D": 4}
    out = []
    for token in text.split():
        out += [letters[token[-1].upper()]] * int(token[:-1])
    return (out + [0] * frames)[:frames]


def distributed(device: str = "auto") -> tuple[int, int]:
    """(rank, world size): under torchrun the process group is set up (NCCL for CUDA,
    gloo for the CPU; `device` as the trainers' --device); a plain run is rank 0 of 1."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1
    cuda = device == "cuda" or (device == "auto" and torch.cuda.is_available())
    torch.distributed.init_process_group("nccl" if cuda else "gloo")
    return torch.distributed.get_rank(), world


def training_device(name: str, world: int) -> torch.device:
    """The device a trainer runs on (`name` as its --device; `auto` is CUDA when PyTorch
    sees a GPU); under torchrun each process takes the GPU of its LOCAL_RANK. On CUDA,
    full fp32 where no autocast is asked for: the encoder's latents are the UNet's targets
    and the engine computes in fp32."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(name)
    if device.type == "cuda":
        if world > 1:
            device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
            torch.cuda.set_device(device)
        torch.backends.cuda.matmul.allow_tf32 = False
        torch.backends.cudnn.allow_tf32 = False
    return device


def checksum(module: torch.nn.Module) -> float:
    return float(sum(p.detach().double().sum() for p in module.parameters()))


def leave_process_group(rank: int, world: int, *modules: torch.nn.Module) -> None:
    """After data-parallel training: checks that every process ends with the same
    parameters and leaves the process group; only the first process (which writes the
    results) returns, the others exit here."""
    sums = [None] * world
    torch.distributed.all_gather_object(sums, [checksum(m) for m in modules])
    if any(s != sums[0] for s in sums):
        raise RuntimeError(f"processes disagree after training: {sums}")
    if rank == 0:
        print(f"parameters in sync across {world} processes", flush=True)
    torch.distributed.barrier()  # no collective is in flight on any process past this point
    torch.distributed.destroy_process_group()
    if rank != 0:
        # gloo's transport threads can still be joinable in the interpreter's teardown and
        # abort the process ("terminate called without an active exception", seen once in
        # CI after a run whose processes were in sync): flush and leave without it.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)


def vae_error_mm(vae, maps: torch.Tensor, pixels: torch.Tensor, scale: float) -> float:
    """The VAE's reconstruction of normalised maps [B, 3, 128, 128] (the mean latent,
    decoded): the mean distance of the foreground `pixels` in millimetres at the avatar's
    `scale` (normalised units per metre)."""
    diff = (vae.decode(vae.encoder(maps)[0]) - maps).flatten(2)[:, :, pixels]  # [B, 3, N]
    return diff.norm(dim=1).mean().item() / scale * 1000


def extra_clips(main: BakedDataset, more: BakedDataset) -> list[dict]:
    """The clips of `more` (`unica bake --switch-phases`), to train on after `main`'s
    (so the held-out clip numbers keep meaning the same clips; normalised with `main`'s
    scale). Both must be baked from the same character: the same reference surface."""
    where = more.dir / "reference.safetensors"
    for name in ("bind", "pixels", "pixel_triangles", "barycentrics", "waist"):
        a, b = getattr(main, name), getattr(more, name)
        if a.shape != b.shape or not torch.equal(a, b):
            raise DatasetError(f"{where}: its {name} differ from {main.dir}'s: not baked from the same character")
    return more.clips


class Run:
    def __init__(self, data: Path, out: Path, cfg: TrainConfig, device: torch.device, rank: int = 0, world: int = 1,
                 init: tuple | None = None, extra: list[Path] = ()):
        self.cfg, self.out, self.device = cfg, out, device
        self.init = init  # (vae, unet, extra, manifest) of a bundle to continue, or None
        self.rank, self.ranks = rank, world
        self.ds = BakedDataset(data)
        for folder in extra:
            self.ds.clips += extra_clips(self.ds, BakedDataset(folder))
        t0 = time.time()
        self.world = [self.ds.positions(c, list(range(clip["actions"].shape[0]))) for c, clip in enumerate(self.ds.clips)]
        print(f"materialised {sum(w.shape[0] for w in self.world)} frames in {time.time() - t0:.1f} s", flush=True)
        self.groups = self.ds.groups()
        held = set(cfg.held_out_clips)
        self.train_groups = [i for i, g in enumerate(self.groups) if g.clip not in held]
        self.test_groups = [i for i, g in enumerate(self.groups) if g.clip in held]
        self.turned = None  # the quarter-turned training latents (encode_groups)
        self.mask = self.ds.mask().to(device)
        self.gen = torch.Generator().manual_seed(cfg.seed + rank)
        self.log_path = out / "losses.csv"
        self.autocast = torch.autocast("cuda", dtype=torch.bfloat16) if device.type == "cuda" else torch.autocast("cpu", enabled=False)

    def log(self, stage: str, step: int, values: dict):
        if self.rank != 0:
            return
        new = not self.log_path.exists()
        with self.log_path.open("a", newline="") as f:
            w = csv.writer(f)
            if new:
                w.writerow(["stage", "step", "name", "value"])
            for k, v in values.items():
                w.writerow([stage, step, k, f"{v:.6g}"])

    def group_maps(self, index: int, turns: int = 0) -> torch.Tensor:
        """The 4 normalised maps [4, 3, 128, 128] of group `index` (3rd frame's root at 0.5),
        turned `turns` quarter turns about +Y."""
        g = self.groups[index]
        unit, _ = self.ds.normalise(quarter_turn(self.world[g.clip][g.start:g.start + 4], turns))
        return self.ds.to_maps(unit)

    def pick(self, pool: list[int], n: int) -> list[int]:
        idx = torch.randint(len(pool), (n,), generator=self.gen)
        return [pool[i] for i in idx]

    # -- the VAE ---------------------------------------------------------------------
    def train_vae(self, resume: bool) -> PositionVae:
        cfg = self.cfg
        vae_cfg = VaeConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.vae.items()})
        if vae_cfg.decoder == "pca":
            vae_cfg.pixels, vae_cfg.map_size = int(self.ds.pixels.shape[0]), int(self.ds.manifest["map_size"])
        if self.init is not None:
            vae = self.init[0].to(self.device)
            if vae.cfg.to_dict() != vae_cfg.to_dict() and self.rank == 0:
                print("vae: the config's VAE differs from the --init bundle's; the bundle's is kept", flush=True)
            return vae.eval()
        vae = PositionVae(vae_cfg).to(self.device)
        opt = torch.optim.AdamW(vae.parameters(), lr=cfg.vae_lr)
        step = self.restore("vae", resume, {"vae": vae, "opt": opt})
        if step == 0 and vae_cfg.decoder == "pca":
            self.fit_vae_basis(vae)
        model = DDP(vae) if self.ranks > 1 else vae
        start = time.time()
        while step < cfg.vae_steps:
            batch = []
            for i in self.pick(self.train_groups, cfg.vae_batch):
                batch.append(self.group_maps(i)[torch.randint(4, (1,), generator=self.gen)])
            x = torch.cat(batch).to(self.device)
            lr = cfg.vae_lr * 0.5 * (1 + math.cos(math.pi * step / cfg.vae_steps))
            for group in opt.param_groups:
                group["lr"] = lr
            with self.autocast:
                loss, parts = model(x, self.mask)
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            if step % 50 == 0 or step == cfg.vae_steps:
                mm = parts["l1"] / self.ds.scale * 1000
                self.log("vae", step, {"loss": loss.item(), "l1_mm": mm})
                if self.rank == 0:
                    print(f"vae {bar(step, cfg.vae_steps)} {step}/{cfg.vae_steps} loss {loss.item():.5f} (~{mm:.1f} mm per coordinate) {time.time() - start:.0f} s", flush=True)
            if step % cfg.checkpoint_every == 0 or step == cfg.vae_steps:
                self.save("vae", step, {"vae": vae, "opt": opt})
        return vae.eval()

    @torch.no_grad()
    def fit_vae_basis(self, vae: PositionVae):
        """The PCA head's basis from the maps of up to 600 random training groups (2,400
        maps; each group normalised as the VAE sees it)."""
        t0 = time.time()
        gen = torch.Generator().manual_seed(self.cfg.seed + 1)
        picks = torch.randperm(len(self.train_groups), generator=gen)[:600]
        maps = torch.cat([self.group_maps(self.train_groups[i]) for i in picks])
        vae.decoder.fit(maps.to(self.device), self.ds.pixels.to(self.device))
        if self.rank == 0:
            print(f"vae: PCA-head basis of {vae.cfg.components} components from {maps.shape[0]} training maps ({time.time() - t0:.0f} s)", flush=True)

    # -- latents ---------------------------------------------------------------------
    @torch.no_grad()
    def encode_groups(self, vae: PositionVae) -> tuple[torch.Tensor, float]:
        """The encoder's latents of every group [G, 4, C, h, w] and the latent scale (one
        over their standard deviation on the training groups). With `quarter_turns` the
        training groups are also encoded turned by 1, 2 and 3 quarter turns, kept in
        `self.turned` ([3, G, 4, C, h, w], zero for held-out groups); the scale stays that
        of the unturned groups."""
        path = self.out / "checkpoints" / "latents.pt"
        if path.exists():
            saved = checkpoint_file.load(path)
            self.turned = saved.get("turned")
            return saved["latents"], saved["scale"]
        latents = self._encode(vae, range(len(self.groups)), 0, "latents")
        self.turned = None
        if self.cfg.quarter_turns:
            self.turned = torch.zeros(3, *latents.shape)
            for turns in (1, 2, 3):
                self.turned[turns - 1, self.train_groups] = self._encode(vae, self.train_groups, turns, f"latents turned {turns * 90}°")
        scale = float(1.0 / latents[self.train_groups].std())
        if self.rank == 0:
            checkpoint_file.save({"latents": latents, "scale": scale, "turned": self.turned}, path)
        return latents, scale

    @torch.no_grad()
    def _encode(self, vae: PositionVae, indices, turns: int, label: str) -> torch.Tensor:
        indices = list(indices)
        out, start = [], time.time()
        for at in range(0, len(indices), 64):
            chunk = indices[at:at + 64]
            maps = torch.stack([self.group_maps(i, turns) for i in chunk])
            mean, _ = vae.encoder(maps.flatten(0, 1).to(self.device))
            out.append(mean.reshape(maps.shape[0], 4, *mean.shape[1:]).cpu())
            done = at + len(chunk)
            if self.rank == 0 and (done == len(indices) or at % 1024 == 0):
                print(f"{label} {bar(done, len(indices))} {done}/{len(indices)} {time.time() - start:.0f} s", flush=True)
        return torch.cat(out)

    # -- the UNet --------------------------------------------------------------------
    def train_unet(self, latents: torch.Tensor, scale: float, resume: bool):
        cfg = self.cfg
        unet = UNet(UNetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.unet.items()})).to(self.device)
        ema = UNet(unet.cfg).to(self.device)
        ema.load_state_dict(unet.state_dict())
        opt = torch.optim.AdamW(unet.parameters(), lr=cfg.unet_lr)
        schedule = Schedule()
        step = self.restore("unet", resume, {"unet": unet, "ema": ema, "opt": opt})
        steps1, steps2 = self.unet_schedule(resume)
        if step == 0 and self.init is not None:
            # The bundle holds the EMA weights; both copies start from them.
            unet.load_state_dict(self.init[1].state_dict())
            ema.load_state_dict(self.init[1].state_dict())
            if self.rank == 0:
                print("unet: started from the --init bundle's weights", flush=True)
        model = DDP(unet) if self.ranks > 1 else unet
        frozen_actions = None
        steady = [i for i in self.train_groups if not self.groups[i].after_switch]
        after = [i for i in self.train_groups if self.groups[i].after_switch]
        total = steps1 + steps2
        start, first, paced = time.time(), step, None
        while step < total:
            if cfg.unet_minutes > 0 and step == first + 10:
                paced = time.time()
            if paced is not None and step == first + 30 and not (self.out / "unet_schedule.json").exists():
                steps1, steps2 = self.fit_schedule(step, (time.time() - paced) / 20, time.time() - start, steps1, steps2)
                total = steps1 + steps2
                if step >= total:
                    self.save("unet", step, {"unet": unet, "ema": ema, "opt": opt})
                    break
            stage2 = step >= steps1
            if stage2 and frozen_actions is None:
                frozen_actions = unet.action.weight.detach().clone()
            if stage2:
                n_after = int(round(cfg.unet_batch * cfg.after_switch_share))
                chosen = self.pick(after, n_after) + self.pick(steady, cfg.unet_batch - n_after)
            else:
                chosen = self.pick(steady, cfg.unet_batch)
            # With quarter turns each sample faces one of the four key directions, its action
            # turned with it; without, every sample is unturned.
            turns = [0] * len(chosen) if self.turned is None else torch.randint(0, 4, (len(chosen),), generator=self.gen).tolist()
            x0 = torch.stack([latents[i] if k == 0 else self.turned[k - 1, i] for i, k in zip(chosen, turns)])
            action = torch.tensor([quarter_turn_action(self.groups[i].action, k) for i, k in zip(chosen, turns)])
            x0 = (x0 * scale).to(self.device)  # [B, 4, C, H, W]
            b = x0.shape[0]
            action[torch.rand(b, generator=self.gen) < cfg.cfg_dropout] = NULL_ACTION
            t_target = torch.randint(0, schedule.steps, (b,), generator=self.gen)
            t_context = torch.randint(0, cfg.context_max_t, (b, 3), generator=self.gen)
            t_context[torch.rand(b, generator=self.gen) < cfg.clean_context_share] = -1
            t = torch.cat([t_context, t_target[:, None]], 1)
            noise = torch.randn(x0.shape, generator=self.gen)
            noise += cfg.noise_offset * torch.randn(b, 4, x0.shape[2], 1, 1, generator=self.gen)
            noise = noise.to(self.device)
            xt = schedule.add_noise(x0, noise, t.to(self.device))
            with self.autocast:
                eps = model(xt, t.clamp(min=0).to(self.device), action.to(self.device))
            weight = schedule.min_snr_weight(t_target, cfg.min_snr_gamma).to(self.device)
            per_sample = ((eps[:, -1].float() - noise[:, -1]) ** 2).mean((1, 2, 3))
            loss = (weight * per_sample).mean()
            lr = cfg.unet_lr * 0.5 * (1 + math.cos(math.pi * step / total))
            for group in opt.param_groups:
                group["lr"] = lr
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(unet.parameters(), 1.0)
            opt.step()
            with torch.no_grad():
                if frozen_actions is not None:
                    # Stage 2 keeps the action embeddings of stage 1.
                    unet.action.weight.copy_(frozen_actions)
                for pe, p in zip(ema.parameters(), unet.parameters()):
                    pe.lerp_(p, 1 - cfg.ema)
            step += 1
            if step % 50 == 0 or step == total:
                self.log("unet2" if stage2 else "unet1", step, {"loss": loss.item(), "mse": per_sample.mean().item()})
                if self.rank == 0:
                    print(f"unet {bar(step, total)} {step}/{total} loss {loss.item():.4f} {time.time() - start:.0f} s", flush=True)
            if step % cfg.checkpoint_every == 0 or step == total:
                self.save("unet", step, {"unet": unet, "ema": ema, "opt": opt})
        return ema.eval(), schedule

    def unet_schedule(self, resume: bool) -> tuple[int, int]:
        """The UNet's (stage-1, stage-2) steps: the config's, or those a time budget fitted
        (unet_schedule.json) when a run is resumed."""
        path = self.out / "unet_schedule.json"
        if resume and path.exists():
            saved = json.loads(path.read_text())
            return saved["unet_steps"], saved["stage2_steps"]
        path.unlink(missing_ok=True)
        return self.cfg.unet_steps, self.cfg.stage2_steps

    def fit_schedule(self, step: int, pace: float, spent: float, steps1: int, steps2: int) -> tuple[int, int]:
        """Both stages shortened in proportion so that the run ends within `unet_minutes`
        at `pace` seconds a step (never lengthened)."""
        total = steps1 + steps2
        fits = step + max(int((self.cfg.unet_minutes * 60 - spent) / pace), 0)
        if fits < total:
            steps1 = round(steps1 * fits / total)
            steps2 = fits - steps1
        record = {"unet_steps": steps1, "stage2_steps": steps2, "seconds_per_step": pace,
                  "unet_minutes": self.cfg.unet_minutes, "config_steps": [self.cfg.unet_steps, self.cfg.stage2_steps]}
        if self.rank == 0:
            checkpoint_file.write_text(self.out / "unet_schedule.json", json.dumps(record, indent=2) + "\n")
            print(f"unet: {pace:.3f} s a step; {steps1} + {steps2} steps fit in {self.cfg.unet_minutes:g} min "
                  f"(config {self.cfg.unet_steps} + {self.cfg.stage2_steps})", flush=True)
        return steps1, steps2

    # -- checkpoints -----------------------------------------------------------------
    def save(self, name: str, step: int, parts: dict):
        if self.rank != 0:
            return
        path = self.out / "checkpoints" / f"{name}.pt"
        checkpoint_file.save({"step": step, **{k: v.state_dict() for k, v in parts.items()}}, path)

    def restore(self, name: str, resume: bool, parts: dict) -> int:
        """The step `name` resumes at (its checkpoint's, or 0); its rows of losses.csv past
        that step, logged before a kill, are cut."""
        path = self.out / "checkpoints" / f"{name}.pt"
        if not (resume and path.exists()):
            step = 0
        else:
            saved = checkpoint_file.load(path)
            for k, v in parts.items():
                v.load_state_dict(saved[k])
            print(f"resumed {name} at step {saved['step']}", flush=True)
            step = saved["step"]
        if resume and self.rank == 0:
            checkpoint_file.cut_log(self.log_path, step, step_column=1, only=lambda row: row[0].startswith(name))
        return step

    # -- PCA, evaluation -------------------------------------------------------------
    def fit_pca(self) -> tuple[torch.Tensor, torch.Tensor]:
        frames = []
        for c, world in enumerate(self.world):
            if c in self.cfg.held_out_clips:
                continue
            root = self.ds.root(world)[:, None]
            frames.append(((world - root) * self.ds.scale + 0.5).flatten(1))
        frames = torch.cat(frames)
        pick = torch.randperm(frames.shape[0], generator=self.gen)[: self.cfg.pca_frames]
        return pca.fit(frames[pick], self.cfg.pca_components)

    @torch.no_grad()
    def reconstruction_mm(self, vae) -> float:
        """VAE reconstruction of held-out frames (every 7th held-out group's 4 frames): the
        mean point error in millimetres at the avatar's scale."""
        errors = [vae_error_mm(vae, self.group_maps(i).to(self.device), self.ds.pixels, self.ds.scale)
                  for i in self.test_groups[::7]]
        return sum(errors) / len(errors)

    @torch.no_grad()
    def denoise_errors(self, unet, schedule, latents, scale, seed: int = 0) -> dict:
        """One-step denoising error of the held-out groups' target frame (clean context)
        at three noise levels, on the UNet's device, the same noise for every UNet."""
        gen = torch.Generator().manual_seed(seed)
        device = next(unet.parameters()).device
        denoise = {}
        for level in (100, 500, 900):
            mses = []
            for start in range(0, len(self.test_groups), 64):
                chosen = self.test_groups[start:start + 64]
                x0 = latents[chosen] * scale
                noise = torch.randn(x0.shape, generator=gen)
                t = torch.tensor([[-1, -1, -1, level]] * len(chosen))
                xt = schedule.add_noise(x0, noise, t)
                action = torch.tensor([self.groups[i].action for i in chosen])
                eps = unet(xt.to(device), t.clamp(min=0).to(device), action.to(device)).cpu()
                mses.append(((eps[:, -1] - noise[:, -1]) ** 2).mean().item())
            denoise[f"t{level}"] = sum(mses) / len(mses)
        return denoise

    @torch.no_grad()
    def evaluate(self, vae, unet, schedule, latents, scale, basis, mean) -> dict:
        fg = self.ds.pixels
        denoise = self.denoise_errors(unet, schedule, latents, scale)
        # PCA: how much of a held-out frame the basis keeps, in millimetres.
        held = torch.cat([self.world[c] for c in self.cfg.held_out_clips])
        unit = ((held - self.ds.root(held)[:, None]) * self.ds.scale + 0.5).flatten(1)
        pca_mm = (pca.project(unit, mean, basis) - unit).reshape(-1, fg.shape[0], 3).norm(dim=2).mean().item() / self.ds.scale * 1000
        return {
            "vae_reconstruction_mm": self.reconstruction_mm(vae),
            "denoise_mse": denoise,
            "pca_reconstruction_mm": pca_mm,
        }

    @torch.no_grad()
    def rollout(self, vae, unet, schedule, scale) -> dict:
        """The reference of the live loop (docs/architecture.md, The live loop): from a standing start, generate each
        next frame from the last three, move the world root by the new frame's root shift,
        recentre the window on the new frame and slide it."""
        cfg, ds = self.cfg, self.ds
        keys = parse_keys(cfg.rollout_keys, cfg.rollout_frames)
        unit, root = ds.normalise(self.world[0][0:4])
        window = unit[:3]  # [3, N, 3] normalised, the 3rd frame's root at 0.5
        world_root = root.clone()
        path, points = [world_root.tolist()], []
        gen = torch.Generator().manual_seed(cfg.seed)

        def encode(w):
            return vae.encoder(ds.to_maps(w).to(self.device))[0] * scale

        context = encode(window)
        for i, a in enumerate(keys):
            z = sample_next(unet, schedule, context[None], torch.tensor([a]), cfg.ddim_steps, cfg.cfg_scale, generator=gen)
            # [N, 3], NaN to the cube's centre and clamped into it, as the engine does
            new = (vae.decode(z / scale)[0].flatten(1)[:, ds.pixels]).T.nan_to_num(0.5).clamp(0.0, 1.0)
            shift = ds.root(new) - 0.5
            world_root = world_root + shift / ds.scale
            window = torch.cat([window[1:], new[None]]) - shift
            context = encode(window)
            path.append(world_root.tolist())
            if i % 30 == 0:
                points.append(((new - 0.5) / ds.scale + world_root - shift / ds.scale).tolist())
        return {"keys": cfg.rollout_keys, "frames": len(keys), "root_path": path, "sampled_points": points}


def write_curves(log_path: Path, png: Path):
    """The loss of every stage against its step, from losses.csv."""
    series: dict[str, list] = {}
    if not log_path.exists():
        return  # no step was logged (a run cut to its first 30 steps)
    with log_path.open() as f:
        for row in csv.DictReader(f):
            if row["name"] == "loss":
                series.setdefault(f"{row['stage']} loss", []).append((int(row["step"]), float(row["value"])))
    curves(png, series)


def write_unet_only(out: Path, run: Run, init: tuple, unet, schedule, latents, scale: float, before: dict, device, started: float):
    """OUT/bundle: the --init bundle with only its UNet replaced; metrics.json with the
    held-out denoising errors of the UNet before and after; curves.png."""
    after = run.denoise_errors(unet, schedule, latents, scale)
    vae0, _, extra0, manifest0 = init
    record = {"device": str(device), "minutes": (time.time() - started) / 60, "denoise_mse_before": before, "denoise_mse": after}
    schedule_path = out / "unet_schedule.json"
    if schedule_path.exists():
        record["unet_schedule"] = json.loads(schedule_path.read_text())
    checkpoint_file.write_text(out / "metrics.json", json.dumps(record, indent=2) + "\n")
    manifest = {k: v for k, v in manifest0.items() if k not in ("format", "version", "vae", "unet", "tensors")}
    manifest["metrics"] = {**manifest0.get("metrics", {}), "denoise_mse": after, "unet_only": record}
    bundle.save(out / "bundle", vae0.cpu(), unet.cpu(), extra0, manifest)
    write_curves(run.log_path, out / "curves.png")
    print(json.dumps(record, indent=2), flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", required=True, type=Path, help="dataset folder written by `unica bake`")
    parser.add_argument("--out", required=True, type=Path, help="run folder (checkpoints, logs, bundle)")
    parser.add_argument("--config", type=Path, help="JSON file overriding TrainConfig fields")
    parser.add_argument("--resume", action="store_true", help="continue from the run folder's checkpoints")
    parser.add_argument("--device", default="auto", help="auto, cpu or cuda")
    parser.add_argument("--init", type=Path, help="a bundle to continue: its VAE and refiner are kept, its UNet trained further")
    parser.add_argument("--extra-data", type=Path, action="append", default=[],
                        help="more clips to train on (`unica bake --switch-phases N`), never held out; repeatable")
    parser.add_argument("--unet-only", action="store_true",
                        help="with --init: write the --init bundle with only its UNet replaced (no PCA, evaluation or rollout)")
    args = parser.parse_args(argv)
    if args.unet_only and not args.init:
        parser.error("--unet-only continues a bundle: give it --init BUNDLE")
    try:
        init = bundle.load(args.init) if args.init else None
        cfg = TrainConfig(**(json.loads(args.config.read_text()) if args.config else {}))
    except (bundle.BundleError, OSError, ValueError, TypeError) as e:
        raise SystemExit(f"unica_train.train: {e}") from None
    rank, world = distributed(args.device)
    cfg.resolve_samples(world)
    device = training_device(args.device, world)
    (args.out / "checkpoints").mkdir(parents=True, exist_ok=True)
    if rank == 0:
        checkpoint_file.write_text(args.out / "config.json", json.dumps(asdict(cfg), indent=2) + "\n")
    torch.manual_seed(cfg.seed)  # the same initial weights on every rank
    try:
        run = Run(args.data, args.out, cfg, device, rank, world, init, args.extra_data)
    except DatasetError as e:
        raise SystemExit(f"unica_train.train: {e}") from None
    started = time.time()
    vae = run.train_vae(args.resume)
    latents, scale = run.encode_groups(vae)
    if init is not None:
        # The VAE is the --init bundle's: its context latents and the engine use its
        # scale; the one measured again differs only by rounding (the bundle stores the
        # VAE as float16).
        if rank == 0:
            print(f"unet: the bundle's latent scale {init[3]['latent_scale']:.5f} (measured again {scale:.5f})", flush=True)
        scale = float(init[3]["latent_scale"])
    if args.unet_only:
        before = run.denoise_errors(init[1].to(device).eval(), Schedule(), latents, scale) if rank == 0 else None
    unet, schedule = run.train_unet(latents, scale, args.resume)
    if args.unet_only:
        if world > 1:
            torch.distributed.destroy_process_group()
        if rank == 0:
            write_unet_only(args.out, run, init, unet, schedule, latents, scale, before, device, started)
        return
    if world > 1:
        leave_process_group(rank, world, vae, unet)
    vae, unet = vae.cpu(), unet.cpu()
    run.device = torch.device("cpu")
    run.mask = run.mask.cpu()
    mean, basis = run.fit_pca()
    metrics = run.evaluate(vae, unet, schedule, latents, scale, basis, mean)
    rollout = run.rollout(vae, unet, schedule, scale)
    x = torch.zeros(1, 4, 4, 16, 16)
    metrics.update({
        "device": str(device),
        "minutes": (time.time() - started) / 60,
        "unet_parameters": parameter_count(unet),
        "vae_parameters": parameter_count(vae),
        "unet_gflop_per_step_per_frame": conv_and_linear_flops(unet, x, torch.zeros(1, 4, dtype=torch.long), torch.tensor([0])) / 4e9,
        "vae_decoder_gflop": (conv_and_linear_flops(vae.decoder, torch.zeros(1, vae.cfg.latent, 16, 16)) + vae.decoder_flops()) / 1e9,
        "latent_scale": scale,
    })
    checkpoint_file.write_text(args.out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    checkpoint_file.write_text(args.out / "rollout.json", json.dumps(rollout) + "\n")
    unit, _ = run.ds.normalise(run.world[0][0:4])
    context = vae.encoder(run.ds.to_maps(unit[:3]))[0] * scale
    m = run.ds.manifest
    # An --init bundle's refiner was fit to its VAE, which is kept: it travels along.
    carried = {k: v for k, v in init[2].items() if k.startswith("refiner.")} if init else {}
    carried_manifest = {"refiner": init[3]["refiner"]} if init and "refiner" in init[3] else {}
    bundle.save(
        args.out / "bundle",
        vae,
        unet,
        {
            "pca.mean": mean,
            "pca.basis": basis,
            "context.latents": context,
            "map.pixels": run.ds.pixels.int(),
            "map.waist": run.ds.waist.int(),
            "map.colors": run.ds.pixel_colors(),
            **carried,
        },
        {
            "avatar": m["avatar"],
            "actions": m["actions"],
            "frame_rate": m["frame_rate"],
            "map_size": m["map_size"],
            "foreground_pixels": m["foreground_pixels"],
            "normalisation": {"scale": run.ds.scale, "fill": 0.7, "group": 4, "anchor": ANCHOR},
            "latent_scale": scale,
            "diffusion": {"steps": schedule.steps, "beta_start": 0.00085, "beta_end": 0.012, "schedule": "scaled_linear", "prediction": "epsilon"},
            **cfg.live(),
            "pca": {"components": int(basis.shape[0])},
            "metrics": metrics,
            **carried_manifest,
        },
    )
    write_curves(run.log_path, args.out / "curves.png")
    print(json.dumps(metrics, indent=2))


if __name__ == "__main__":
    main()
