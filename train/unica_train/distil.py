"""One UNet pass per frame: distils a bundle's sampler (its DDIM steps with classifier-free
guidance and its Idle guidance rules) into a student UNet that makes a frame in one pass
without the guidance batch:

    python -m unica_train.distil --bundle BUNDLE --data DATA --out RUN [--method direct|consistency]
        [--frames 3072] [--steps 1500] [--batch 32] [--resume] [--extra-data MORE]
        [--from-student] [--rollout-frames N] [--truth-weight W]

The student has the teacher's architecture and starts from its weights. It is run as one
DDIM step from t = 999 to the clean sample, conditional only, from the teacher's starting
noise (standard normal times the sampler's `noise_scale`): x0 = (x_T - √(1-ᾱ) ε̂)/√ᾱ.
Guidance is folded in: every training frame is one the live loop could meet (three
ground-truth context frames, turned to the model's heading, the action turned with them),
and the teacher samples it at the guidance scale the live loop would use there (the
keys' scale, Idle's own, the braking scale for the first Idle frames after a key,
`diffusion.frame_options`, or the turn-braking scale for the first frames of a turn,
`diffusion.frame_cfg_scales`). The student therefore learns the braking from the context
it sees: moving context under Idle, or a body not yet facing the key's way.

Methods (`--method`, compared in docs/experiments/distillation.md):
- `direct`: knowledge distillation (Luhman & Luhman 2021). The teacher samples each pooled
  frame once from a stored noise; the student regresses that sample from the same noise
  in one pass (loss on the clean latent).
- `consistency`: consistency distillation (Song et al. 2023) on the teacher's own DDIM
  grid: a training frame is noised to a grid time t_n (t_0 = 999 starts from the
  sampler's noise instead), one guided teacher DDIM step takes it to t_n+1, and the
  student's clean-sample prediction at t_n is pulled to an EMA copy's at t_n+1 (the
  clean latent itself past the last step).

`--truth-weight W` (direct only) pulls the student toward the true next frame as well:
the loss is (1 - W) times the squared distance to the teacher's sample plus W times the
squared distance to the true next latent (W = 1 needs no teacher samples of the pool).

`--rollout-frames N` (direct only) adds N frames whose contexts come from the live loop's
own rollouts of the bundle's student on the training clips' keys (`rollout/`, its
teacher samples in `rollout_teacher/`): the student meets its own frames as context live,
and a teacher-forced pool never shows it them. Held-out rollouts (the held-out clips'
keys) are scored against the teacher's samples of the same contexts.

Steps: the frame pool (`pool/`, encoded contexts, actions, guidance scales, true next
latents), the teacher's samples (`direct` only, `teacher/`), then training with a
checkpoint every `--checkpoint-every` steps. Every file is written under a temporary name
and renamed, and `--resume` continues from what is there, so a killed run loses at most
one chunk or one checkpoint interval. The run ends with `RUN/bundle`: the teacher bundle
with the student's weights as `student.*` and `sampler.kind = "one_pass"` (the app and
`unica render --bundle` run it by default; `--steps N` runs the teacher), and
`RUN/curves.png` (the loss) and `RUN/metrics.json`: the student's held-out error against the teacher's samples and the
truth, in latent units and in mm, beside the teacher's own and its one-step DDIM."""

from __future__ import annotations

import argparse
import copy
import csv
import json
import math
import os
import shutil
import time
from pathlib import Path

import torch
from safetensors.torch import load_file

from . import bundle as bundle_io
from . import checkpoint as checkpoint_file
from . import recentre
from .dataset import ANCHOR, AFTER_SWITCH, BakedDataset, DatasetError, quarter_turn_action
from .diffusion import (Schedule, brake_options, ddim_step, frame_cfg_scales, frame_options, guided_eps, sample_next,
                        sampler_options, turn_brake_options)
from .plot import curves
from .train import bar, extra_clips

METHODS = ("direct", "consistency")
CHUNK = 256
# The held-out clips of the shipped training configs (train.TrainConfig.held_out_clips).
HELD_OUT_CLIPS = [4, 13]
# Frames after a key is released into Idle that `--release-share` draws from: the braked
# frames and the first frames of standing still (the teacher stops within 9-11).
RELEASE_WINDOW = 40


class DistilError(ValueError):
    """A bad input to the distillation; the message names the file and the problem."""


def one_pass(student, schedule: Schedule, context, action, noise):
    """The student's frame: one conditional DDIM step from t = 999 to the clean sample."""
    return sample_next(student, schedule, context, action, steps=1, cfg_scale=1.0, noise=noise)


def x0_prediction(model, schedule: Schedule, context, x_t, t: torch.Tensor, action):
    """The clean latent a model predicts from x_t at per-sample times t ([B]; -1 gives x_t
    itself, the consistency boundary)."""
    b = x_t.shape[0]
    times = torch.cat([torch.zeros(b, 3, dtype=torch.long), t.clamp(min=0)[:, None]], 1)
    eps = model(torch.cat([context, x_t[:, None]], 1), times, action)[:, -1]
    a = schedule.alpha_bar(t).view(b, 1, 1, 1)
    x0 = (x_t - (1 - a).sqrt() * eps) / a.sqrt()
    return torch.where((t < 0).view(b, 1, 1, 1), x_t, x0)


class Teacher:
    """The bundle, the dataset, and the live loop's view of a training frame."""

    def __init__(self, bundle_dir: Path, data: Path, extra: list[Path], held_out: list[int] = HELD_OUT_CLIPS):
        self.bundle_dir = bundle_dir
        self.held_out = set(held_out)
        self.vae, self.unet, self.extra, self.manifest = bundle_io.load(bundle_dir)
        self.vae.eval()
        self.unet.eval()
        self.ds = BakedDataset(data)
        for folder in extra:
            self.ds.clips += extra_clips(self.ds, BakedDataset(folder))
        if not torch.equal(self.extra["map.pixels"].long(), self.ds.pixels):
            raise DistilError(f"{data}: its position-map pixels are not the bundle's (another character or table)")
        sampler = self.manifest["sampler"]
        self.steps, self.cfg_scale = int(sampler["ddim_steps"]), float(sampler["cfg_scale"])
        self.options, self.brake = sampler_options(sampler), brake_options(sampler)
        self.turn = turn_brake_options(sampler)
        self.heading = self.manifest.get("heading", "world")
        self.latent_scale = float(self.manifest["latent_scale"])
        self.schedule = Schedule()

    def frames(self, held_out: bool) -> list[tuple[int, int]]:
        """Every (clip, frame) with three frames before it, in the held-out clips or not."""
        out = []
        for c, clip in enumerate(self.ds.clips):
            if (c in self.held_out) != held_out:
                continue
            out += [(c, f) for f in range(3, clip["actions"].shape[0])]
        return out

    def after_switch(self, clip: int, f: int) -> bool:
        s = self.ds.clips[clip]["switch"]
        return s <= f < s + AFTER_SWITCH

    def after_release(self, clip: int, f: int) -> bool:
        """Frame f is one of the first RELEASE_WINDOW after a movement key is released
        into Idle (where the live loop brakes, then must stand still)."""
        c = self.ds.clips[clip]
        s, actions = c["switch"], c["actions"]
        if not 0 < s < actions.shape[0]:
            return False
        return int(actions[s]) == 0 and int(actions[s - 1]) != 0 and s <= f < s + RELEASE_WINDOW

    @torch.no_grad()
    def encode(self, picks: list[tuple[int, int]]) -> dict:
        """The live loop's view of frames (clip, f): the three context latents turned to the
        model's heading, the action turned with them, the Idle guidance scale the loop
        would use after the clip's keys so far (-1: the keys' scale) and the guidance scale
        of its keys (turn braking), the true frame's latent turned the same way, and the
        heading's quarter turns."""
        maps, actions, idle, cfgs, quarters = [], [], [], [], []
        for clip, f in picks:
            world = self.ds.positions(clip, list(range(f - 3, f + 1)))
            unit, _ = self.ds.normalise(world, anchor=ANCHOR)
            history = [int(a) for a in self.ds.clips[clip]["actions"][:f]]
            q = recentre.heading_quarters(history, self.heading)
            to_model = (4 - q) % 4
            maps.append(self.ds.to_maps(recentre.turn_unit(unit, to_model)))
            actions.append(quarter_turn_action(history[-1], to_model))
            scale = frame_options(self.options, self.brake, history)["idle_cfg_scale"]
            idle.append(-1.0 if scale is None else float(scale))
            cfgs.append(frame_cfg_scales(history, self.cfg_scale, **self.turn)[-1])
            quarters.append(q)
        maps = torch.stack(maps)  # [B, 4, 3, 128, 128]
        z = self.vae.encoder(maps.flatten(0, 1))[0] * self.latent_scale
        z = z.reshape(maps.shape[0], 4, *z.shape[1:])
        return {"context": z[:, :3], "truth": z[:, 3], "action": torch.tensor(actions),
                "idle_scale": torch.tensor(idle), "cfg_scale": torch.tensor(cfgs, dtype=torch.float32),
                "quarters": torch.tensor(quarters)}

    def groups(self, idle_scale, frame_cfg=None):
        """The frames that sample alike, one group per pair of Idle scale (-1: the keys')
        and keys' guidance scale (`frame_cfg`; where not given, as from a pool encoded
        before turn braking, the sampler's own): (rows, keys' scale, `sample_next`
        options)."""
        cfg = torch.full(idle_scale.shape, self.cfg_scale) if frame_cfg is None else frame_cfg
        for s, c in torch.stack([idle_scale.float(), cfg.float()], 1).unique(dim=0).tolist():
            yield (idle_scale == s) & (cfg == c), c, dict(self.options, idle_cfg_scale=None if s < 0 else s)

    @torch.no_grad()
    def sample(self, context, action, idle_scale, noise, steps: int | None = None, cfg_scale: float | None = None,
               frame_cfg=None):
        """The teacher's frames, each at its own Idle scale and its keys' scale
        (`frame_cfg`; one batch per pair), or all at `cfg_scale` where given."""
        steps = self.steps if steps is None else steps
        if cfg_scale is not None:
            frame_cfg = torch.full(idle_scale.shape, cfg_scale)
        out = torch.empty_like(noise)
        for rows, c, opts in self.groups(idle_scale, frame_cfg):
            out[rows] = sample_next(self.unet, self.schedule, context[rows], action[rows], steps, c,
                                    noise=noise[rows], **opts)
        return out

    def guided(self, x_t, t: int, context, action, idle_scale, frame_cfg=None):
        """The teacher's guided noise prediction at one time, each sample at its Idle
        scale and its keys' scale."""
        out = torch.empty_like(x_t)
        b = x_t.shape[0]
        for rows, c, opts in self.groups(idle_scale, frame_cfg):
            n = int(rows.sum())
            latents = torch.cat([context[rows], x_t[rows][:, None]], 1)
            t_frames = torch.tensor([[0, 0, 0, t]] * n)
            out[rows] = guided_eps(self.unet, latents, t_frames, action[rows], c, opts["guide_idle"],
                                   opts["idle_cfg_scale"])
        assert out.shape[0] == b
        return out

    def decode_mm(self, a, b) -> float:
        """Mean per-point distance (mm) between the decoded frames of latents a and b."""
        pa = recentre.decode_points(self.vae, a, self.latent_scale, self.ds.pixels)
        pb = recentre.decode_points(self.vae, b, self.latent_scale, self.ds.pixels)
        return float((pa - pb).norm(dim=-1).mean() / self.ds.scale * 1000)


# -- the pool and the teacher's samples ------------------------------------------------
def pick_frames(teacher: Teacher, count: int, seed: int, held_out: bool, release_share: float = 0.0) -> list[tuple[int, int]]:
    """`count` frames: a `release_share` of them within RELEASE_WINDOW frames after a key
    is released into Idle (`Teacher.after_release`), then of the rest half within
    AFTER_SWITCH frames after any key change (where starts, stops and turns happen) and
    half uniform."""
    gen = torch.Generator().manual_seed(seed)
    frames = teacher.frames(held_out)
    if not frames:
        raise DistilError(f"{teacher.ds.dir}: no {'held-out' if held_out else 'training'} clip has 4 frames")
    after = [x for x in frames if teacher.after_switch(*x)] or frames
    released = [x for x in frames if teacher.after_release(*x)] or frames
    releases = round(release_share * count)
    out = []
    for i in range(count):
        if i < releases:
            pool = released
        else:
            pool = after if (i - releases) % 2 == 0 else frames
        out.append(pool[int(torch.randint(len(pool), (1,), generator=gen))])
    return out


def build_pool(teacher: Teacher, folder: Path, count: int, seed: int, held_out: bool, label: str,
               release_share: float = 0.0) -> dict:
    """The encoded frames in chunks of CHUNK (`folder/chunk_NNNN.safetensors`), each with
    its starting noise; chunks already there are kept (resume)."""
    folder.mkdir(parents=True, exist_ok=True)
    picks = pick_frames(teacher, count, seed, held_out, release_share)
    gen = torch.Generator().manual_seed(seed + 7)
    started = time.time()
    noise_scale = teacher.options["noise_scale"]
    for k, at in enumerate(range(0, count, CHUNK)):
        chunk = picks[at:at + CHUNK]
        noise = noise_scale * torch.randn(len(chunk), 4, 16, 16, generator=gen)  # drawn even when kept: same noise on resume
        path = folder / f"chunk_{k:04d}.safetensors"
        if path.exists():
            continue
        part = teacher.encode(chunk)
        part["noise"] = noise
        part["frames"] = torch.tensor(chunk, dtype=torch.int32)
        checkpoint_file.write_tensors(path, part)
        done = min(at + CHUNK, count)
        print(f"{label} {bar(done, count)} {done}/{count} {time.time() - started:.0f} s", flush=True)
    return read_chunks(folder, (count + CHUNK - 1) // CHUNK)


def read_chunks(folder: Path, chunks: int) -> dict:
    parts = []
    for k in range(chunks):
        path = folder / f"chunk_{k:04d}.safetensors"
        try:
            parts.append(load_file(str(path)))
        except Exception as e:
            raise DistilError(f"{path}: {e}") from e
    return {key: torch.cat([p[key] for p in parts]) for key in parts[0]}


# Pool keys both kinds of frame carry; the direct method trains on these alone.
DIRECT_KEYS = ("context", "action", "idle_scale", "cfg_scale", "noise")


@torch.no_grad()
def rollout_pool(teacher: Teacher, path: Path, count: int, seed: int, held_out: bool, stride: int, label: str) -> dict:
    """`count` frames of the live loop's own rollouts of the bundle's student (where the
    student's frames are its next context): each training clip's keys (the held-out
    clips' with `held_out`) from the bundle's standing start, run as `eval.Avatar.rollout`
    runs the engine's loop, every `stride`-th frame kept: the context latents and action
    as the model saw them, the Idle and keys' guidance scales the teacher's sampler
    would use after those keys, and a starting noise. Held-out runs draw their noise from
    seeds no training run uses and skip frame 0 (the standing start every rollout shares).
    Written whole to `path` with the options that made it (a file already there is read
    instead: resume, refused when its options differ)."""
    meta = torch.tensor([count, stride, seed, int(held_out)], dtype=torch.int64)
    if path.exists():
        part = read_pool_file(path)
        if "meta" not in part or not torch.equal(part["meta"], meta):
            raise DistilError(f"{path}: made with other rollout options (count, stride, seed); "
                              "use the same options or remove the folder")
        return part
    if not any(k.startswith("student.") for k in teacher.extra):
        raise DistilError(f"{teacher.bundle_dir}: --rollout-frames rolls out the bundle's one-pass student, "
                          "and it has none (no student.* tensors)")
    student = bundle_io.live_sampler(dict(teacher.manifest, sampler=dict(teacher.manifest["sampler"], kind="one_pass")),
                                     teacher.unet, teacher.extra, teacher.bundle_dir / "manifest.json")[0]
    clips = [c for c in range(len(teacher.ds.clips)) if (c in teacher.held_out) == held_out]
    if not clips:
        raise DistilError(f"{teacher.ds.dir}: no {'held-out' if held_out else 'training'} clip to roll out")
    gen = torch.Generator().manual_seed(seed + 11)
    order = [clips[int(i)] for i in torch.randperm(len(clips), generator=gen)]
    manifest, noise_scale = teacher.manifest, teacher.options["noise_scale"]
    rows = {k: [] for k in DIRECT_KEYS + ("frames",)}
    started = time.time()
    run, kept_before = 0, 0
    while len(rows["noise"]) < count:
        if run and run % len(order) == 0:
            if len(rows["noise"]) == kept_before:
                raise DistilError(f"{teacher.ds.dir}: the clips to roll out give no frame at stride {stride}")
            kept_before = len(rows["noise"])
        clip = order[run % len(order)]
        actions = [int(a) for a in teacher.ds.clips[clip]["actions"]]
        offset = int(torch.randint(stride, (1,), generator=gen))
        wanted = count - len(rows["noise"])
        first = stride if held_out and offset == 0 else offset
        frames = min(len(actions), first + stride * (wanted - 1) + 1)

        def keep(i, context, model_action, clip=clip, actions=actions, first=first):
            if i < first or (i - first) % stride:
                return
            history = actions[:i + 1]
            scale = frame_options(teacher.options, teacher.brake, history)["idle_cfg_scale"]
            rows["context"].append(context.clone())
            rows["action"].append(model_action)
            rows["idle_scale"].append(-1.0 if scale is None else float(scale))
            rows["cfg_scale"].append(frame_cfg_scales(history, teacher.cfg_scale, **teacher.turn)[-1])
            rows["noise"].append(noise_scale * torch.randn(4, 16, 16, generator=gen))
            rows["frames"].append((clip, i))

        recentre.rollout(
            teacher.vae, student, teacher.schedule, teacher.latent_scale, teacher.extra["context.latents"], actions,
            1, 1.0, seed + (50_000 if held_out else 100) + run, teacher.ds.pixels, teacher.extra["map.waist"].long(),
            manifest["normalisation"]["scale"], "reencode", frames=frames, on_context=keep,
            root_motion=manifest.get("root_motion", "centre"), heading=teacher.heading,
            grounded=bool(manifest.get("grounded", False)), stand_speed=manifest.get("stand_speed"),
            frame_rate=float(manifest["frame_rate"]), **teacher.options, **teacher.brake)
        run += 1
        done = min(len(rows["noise"]), count)
        print(f"{label} {bar(done, count)} {done}/{count} {time.time() - started:.0f} s", flush=True)
    part = {"context": torch.stack(rows["context"][:count]), "action": torch.tensor(rows["action"][:count]),
            "idle_scale": torch.tensor(rows["idle_scale"][:count]),
            "cfg_scale": torch.tensor(rows["cfg_scale"][:count], dtype=torch.float32),
            "noise": torch.stack(rows["noise"][:count]), "frames": torch.tensor(rows["frames"][:count], dtype=torch.int32),
            "meta": meta}
    path.parent.mkdir(parents=True, exist_ok=True)
    checkpoint_file.write_tensors(path, part)
    return part


def read_pool_file(path: Path) -> dict:
    try:
        return load_file(str(path))
    except Exception as e:
        raise DistilError(f"{path}: {e}") from e


def joined(pool: dict, more: dict) -> dict:
    """The direct method's training frames of two pools, one after the other."""
    for k in DIRECT_KEYS:
        if k not in pool:
            raise DistilError(f"the training pool has no '{k}' (made before turn guidance): "
                              "--rollout-frames needs a pool made by this version; remove the run's pool folder")
    return {k: torch.cat([pool[k], more[k]]) for k in DIRECT_KEYS}


def teacher_samples(teacher: Teacher, pool: dict, folder: Path, label: str) -> torch.Tensor:
    """The teacher's sample of every pooled frame from its stored noise, in chunks
    (`folder/chunk_NNNN.safetensors`, kept on resume)."""
    folder.mkdir(parents=True, exist_ok=True)
    n = pool["noise"].shape[0]
    started, out = time.time(), []
    for k, at in enumerate(range(0, n, CHUNK)):
        path = folder / f"chunk_{k:04d}.safetensors"
        rows = slice(at, min(at + CHUNK, n))
        if not path.exists():
            cfg = pool["cfg_scale"][rows] if "cfg_scale" in pool else None
            z = teacher.sample(pool["context"][rows], pool["action"][rows], pool["idle_scale"][rows], pool["noise"][rows],
                               frame_cfg=cfg)
            checkpoint_file.write_tensors(path, {"sample": z})
            print(f"{label} {bar(rows.stop, n)} {rows.stop}/{n} {time.time() - started:.0f} s", flush=True)
        out.append(load_file(str(path))["sample"])
    return torch.cat(out)


# -- training --------------------------------------------------------------------------
def train(teacher: Teacher, pool: dict, targets: torch.Tensor | None, out: Path, args) -> torch.nn.Module:
    """Trains the student (`args.method`) with checkpoints every `args.checkpoint_every`
    steps; returns its EMA weights."""
    student = copy.deepcopy(teacher.unet).train()
    if args.from_student:
        weights = {k[len("student."):]: v for k, v in teacher.extra.items() if k.startswith("student.")}
        if not weights:
            raise DistilError(f"{teacher.bundle_dir}: --from-student: the bundle has no student (no student.* tensors)")
        student.load_state_dict(weights)
    ema = copy.deepcopy(student).eval()
    opt = torch.optim.AdamW(student.parameters(), lr=args.lr, weight_decay=0.0)
    ckpt = out / "checkpoint.pt"
    step = 0
    if args.resume and ckpt.exists():
        saved = checkpoint_file.load(ckpt)
        student.load_state_dict(saved["student"])
        ema.load_state_dict(saved["ema"])
        opt.load_state_dict(saved["opt"])
        step = int(saved["step"])
        print(f"distil: resumed at step {step}", flush=True)
    gen = torch.Generator().manual_seed(args.seed + 1000 + step)
    log_path = out / "losses.csv"
    if step == 0 and log_path.exists():
        log_path.unlink()
    checkpoint_file.cut_log(log_path, step)
    n = pool["noise"].shape[0]
    grid = teacher.schedule.ddim_timesteps(teacher.steps) + [-1]
    noise_scale = teacher.options["noise_scale"]
    started = time.time()
    while step < args.steps:
        idx = torch.randint(n, (args.batch,), generator=gen)
        context, action = pool["context"][idx], pool["action"][idx]
        if args.method == "direct":
            noise = pool["noise"][idx]
            got = x0_prediction(student, teacher.schedule, context, noise, torch.full((args.batch,), grid[0]), action)
            # Each term only where it is weighted: at W = 1 there are no teacher samples,
            # and rollout frames have no truth (main() refuses W > 0 with them).
            w, loss = args.truth_weight, 0.0
            if w < 1:
                loss = loss + (1 - w) * ((got - targets[idx]) ** 2).mean()
            if w > 0:
                loss = loss + w * ((got - pool["truth"][idx]) ** 2).mean()
        else:
            x0, scales = pool["truth"][idx], pool["idle_scale"][idx]
            cfgs = pool["cfg_scale"][idx] if "cfg_scale" in pool else None
            n_at = torch.randint(teacher.steps, (args.batch,), generator=gen)
            eps = torch.randn(x0.shape, generator=gen)
            t_n = torch.tensor([grid[i] for i in n_at])
            t_next = torch.tensor([grid[i + 1] for i in n_at])
            x_t = teacher.schedule.add_noise(x0, eps, t_n)
            start = n_at == 0
            x_t[start] = noise_scale * eps[start]  # the sampler's own start at t_0
            with torch.no_grad():
                x_next = torch.empty_like(x_t)
                for i in n_at.unique().tolist():
                    rows = n_at == i
                    e = teacher.guided(x_t[rows], grid[i], context[rows], action[rows], scales[rows],
                                       None if cfgs is None else cfgs[rows])
                    x_next[rows] = ddim_step(teacher.schedule, x_t[rows], e, grid[i], grid[i + 1])
                target = x0_prediction(ema, teacher.schedule, context, x_next, t_next, action)
            got = x0_prediction(student, teacher.schedule, context, x_t, t_n, action)
            loss = ((got - target) ** 2).mean()
        lr = args.lr * 0.5 * (1 + math.cos(math.pi * step / args.steps))
        for group in opt.param_groups:
            group["lr"] = lr
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(student.parameters(), 1.0)
        opt.step()
        with torch.no_grad():
            for pe, p in zip(ema.parameters(), student.parameters()):
                pe.lerp_(p, 1 - args.ema)
        step += 1
        if step % 10 == 0 or step == args.steps:
            new = not log_path.exists()
            with log_path.open("a", newline="") as f:
                w = csv.writer(f)
                if new:
                    w.writerow(["step", "loss", "seconds"])
                w.writerow([step, f"{loss.item():.6g}", f"{time.time() - started:.1f}"])
            print(f"distil {args.method} {bar(step, args.steps)} {step}/{args.steps} loss {loss.item():.5f} "
                  f"{time.time() - started:.0f} s", flush=True)
        if step % args.checkpoint_every == 0 or step == args.steps:
            checkpoint_file.save({"student": student.state_dict(), "ema": ema.state_dict(), "opt": opt.state_dict(), "step": step}, ckpt)
    return ema.eval()


def write_curves(out: Path, method: str) -> None:
    """RUN/curves.png: the training loss (log scale) against the step."""
    with (out / "losses.csv").open() as f:
        rows = [(int(r["step"]), float(r["loss"])) for r in csv.DictReader(f)]
    curves(out / "curves.png", {f"{method} distillation loss": rows})


# -- evaluation and the bundle -----------------------------------------------------------
@torch.no_grad()
def held_out_errors(teacher: Teacher, student, held: dict, teacher_z: torch.Tensor) -> dict:
    """The student's one pass, the teacher UNet's one pass (where the student started),
    the teacher's sampler at one guided step and at its own steps, on the held-out frames:
    RMS latent error and mean decoded distance (mm) to the teacher's samples and to the
    truth."""
    noise = held["noise"]
    rows = {
        "student_one_pass": one_pass(student, teacher.schedule, held["context"], held["action"], noise),
        "teacher_one_pass": one_pass(teacher.unet, teacher.schedule, held["context"], held["action"], noise),
        "teacher_one_step": teacher.sample(held["context"], held["action"], held["idle_scale"], noise, steps=1,
                                           frame_cfg=held.get("cfg_scale")),
        "teacher": teacher_z,
    }
    out = {}
    for name, z in rows.items():
        out[name] = {
            "latent_rms_to_teacher": float(((z - teacher_z) ** 2).mean().sqrt()),
            "latent_rms_to_truth": float(((z - held["truth"]) ** 2).mean().sqrt()),
            "mm_to_teacher": teacher.decode_mm(z, teacher_z),
            "mm_to_truth": teacher.decode_mm(z, held["truth"]),
        }
    return out


@torch.no_grad()
def rollout_errors(teacher: Teacher, students: dict, held: dict, teacher_z: torch.Tensor) -> dict:
    """Each student's one pass on held-out frames of the live loop's own rollouts
    (`rollout_pool`): RMS latent error and mean decoded distance (mm) to the teacher's
    samples of the same contexts (there is no truth for a rollout)."""
    out = {}
    for name, model in students.items():
        z = one_pass(model, teacher.schedule, held["context"], held["action"], held["noise"])
        out[name] = {"latent_rms_to_teacher": float(((z - teacher_z) ** 2).mean().sqrt()),
                     "mm_to_teacher": teacher.decode_mm(z, teacher_z)}
    return out


def write_bundle(teacher: Teacher, student, out: Path, record: dict) -> Path:
    """RUN/bundle: the teacher bundle with `student.*` and `sampler.kind = "one_pass"`,
    written beside and renamed into place whole."""
    final, tmp = out / "bundle", out / "bundle.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    extra = {k: v for k, v in teacher.extra.items() if not k.startswith("student.")}
    extra.update({f"student.{k}": v for k, v in student.state_dict().items()})
    manifest = {k: v for k, v in teacher.manifest.items() if k not in ("format", "version", "vae", "unet", "tensors")}
    manifest["sampler"] = dict(manifest["sampler"], kind="one_pass")
    manifest["metrics"] = dict(manifest.get("metrics", {}), one_pass=record)
    bundle_io.save(tmp, teacher.vae, teacher.unet, extra, manifest)
    for name in ("weights.safetensors", "manifest.json"):
        with open(tmp / name, "rb") as f:
            os.fsync(f.fileno())
    if final.exists():
        old = out / "bundle.old"
        if old.exists():
            shutil.rmtree(old)
        os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old)
    else:
        os.replace(tmp, final)
    return final


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", required=True, type=Path, help="the teacher bundle (its sampler is distilled)")
    parser.add_argument("--data", required=True, type=Path, help="its dataset (`unica bake`)")
    parser.add_argument("--out", required=True, type=Path, help="run folder (pool, teacher samples, checkpoint, bundle)")
    parser.add_argument("--method", default="direct", choices=METHODS)
    parser.add_argument("--frames", type=int, default=3072, help="training frames in the pool")
    parser.add_argument("--held-out-frames", type=int, default=256, help="held-out frames scored at the end")
    parser.add_argument("--steps", type=int, default=1500, help="student training steps")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-4)
    parser.add_argument("--ema", type=float, default=0.99)
    parser.add_argument("--checkpoint-every", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--extra-data", type=Path, action="append", default=[], help="more clips of the same character")
    parser.add_argument("--held-out-clips", type=int, nargs="+", default=HELD_OUT_CLIPS,
                        help="clips scored at the end and never trained on (default: 4 13, as the geometry trainer)")
    parser.add_argument("--resume", action="store_true", help="continue from what the run folder holds")
    parser.add_argument("--release-share", type=float, default=0.0,
                        help=f"share of the pool drawn from the first {RELEASE_WINDOW} frames after a key is released into Idle "
                             "(default 0: half the pool after any key change, half uniform)")
    parser.add_argument("--from-student", action="store_true",
                        help="start from the bundle's own one-pass student (its student.* tensors), not the teacher")
    parser.add_argument("--rollout-frames", type=int, default=0,
                        help="more training frames from the live loop's own rollouts of the bundle's student on the "
                             "training clips' keys, where its frames are its next context (direct method only; default 0)")
    parser.add_argument("--rollout-stride", type=int, default=4, help="every this many rollout frames is kept")
    parser.add_argument("--rollout-held-out-frames", type=int, default=128,
                        help="held-out rollout frames (the held-out clips' keys) scored at the end")
    parser.add_argument("--truth-weight", type=float, default=0.0,
                        help="weight of the true next frame in the direct method's loss, the rest on the teacher's "
                             "sample (0-1; default 0: the teacher's sample only; 1 needs no teacher samples)")
    args = parser.parse_args(argv)
    if not 0.0 <= args.truth_weight <= 1.0:
        parser.error("--truth-weight must be between 0 and 1")
    if args.truth_weight and args.method != "direct":
        parser.error("--truth-weight needs --method direct")
    if args.truth_weight and args.rollout_frames:
        parser.error("--truth-weight cannot go with --rollout-frames (a rollout frame has no truth)")
    if args.rollout_frames and args.method != "direct":
        parser.error("--rollout-frames needs --method direct (a rollout frame has no truth to noise)")
    if not 0.0 <= args.release_share <= 1.0:
        parser.error("--release-share must be between 0 and 1")
    if args.rollout_frames < 0:
        parser.error("--rollout-frames must be at least 0")
    for name in ("frames", "held_out_frames", "steps", "batch", "checkpoint_every", "rollout_stride",
                 "rollout_held_out_frames"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.out.exists() and any(args.out.iterdir()) and not args.resume:
        raise SystemExit(f"unica_train.distil: {args.out} is not empty: give --resume to continue it, or another folder")
    args.out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(args.seed)
    started = time.time()
    try:
        teacher = Teacher(args.bundle, args.data, args.extra_data, args.held_out_clips)
        pool = build_pool(teacher, args.out / "pool", args.frames, args.seed, False, "pool", args.release_share)
        held = build_pool(teacher, args.out / "held_out", args.held_out_frames, args.seed + 1, True, "held-out pool")
        held_z = teacher_samples(teacher, held, args.out / "held_out_teacher", "teacher (held out)")
        sampled = args.method == "direct" and args.truth_weight < 1
        targets = teacher_samples(teacher, pool, args.out / "teacher", "teacher") if sampled else None
        if args.rollout_frames:
            rolled_held = rollout_pool(teacher, args.out / "rollout_held_out" / "pool.safetensors",
                                       args.rollout_held_out_frames, args.seed + 1, True, args.rollout_stride,
                                       "student rollouts (held out)")
            rolled_held_z = teacher_samples(teacher, rolled_held, args.out / "rollout_held_out_teacher",
                                            "teacher (held-out rollouts)")
            rolled = rollout_pool(teacher, args.out / "rollout" / "pool.safetensors", args.rollout_frames, args.seed,
                                  False, args.rollout_stride, "student rollouts")
            rolled_z = teacher_samples(teacher, rolled, args.out / "rollout_teacher", "teacher (rollouts)")
            pool, targets = joined(pool, rolled), torch.cat([targets, rolled_z])
    except (bundle_io.BundleError, DatasetError, DistilError) as e:
        raise SystemExit(f"unica_train.distil: {e}") from None
    try:
        student = train(teacher, pool, targets, args.out, args)
    except DistilError as e:
        raise SystemExit(f"unica_train.distil: {e}") from None
    record = {
        "method": args.method,
        "teacher_steps": teacher.steps,
        "teacher_cfg_scale": teacher.cfg_scale,
        "frames": args.frames,
        "steps": args.steps,
        "batch": args.batch,
        "lr": args.lr,
        "release_share": args.release_share,
        "truth_weight": args.truth_weight,
        "from_student": args.from_student,
        "minutes": (time.time() - started) / 60,
        "held_out": held_out_errors(teacher, student, held, held_z),
    }
    if args.rollout_frames:
        start = bundle_io.live_sampler(dict(teacher.manifest, sampler=dict(teacher.manifest["sampler"], kind="one_pass")),
                                       teacher.unet, teacher.extra)[0]
        record.update(rollout_frames=args.rollout_frames, rollout_stride=args.rollout_stride,
                      held_out_rollouts=rollout_errors(teacher, {"bundle_student": start, "student_one_pass": student},
                                                       rolled_held, rolled_held_z))
    checkpoint_file.write_text(args.out / "metrics.json", json.dumps(record, indent=2) + "\n")
    write_curves(args.out, args.method)
    path = write_bundle(teacher, student, args.out, record)
    print(json.dumps(record, indent=2), flush=True)
    print(f"distil: wrote {path}", flush=True)


if __name__ == "__main__":
    main()
