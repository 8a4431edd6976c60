"""Training the refiner on a baked dataset's renders (L1 + SSIM over random black or white
backgrounds), resumable from its checkpoint, and writing it into a bundle."""

from __future__ import annotations

import csv
import json
import time
from dataclasses import asdict
from pathlib import Path

import torch

from .. import bundle as bundle_io
from .. import checkpoint as checkpoint_file
from .. import splats
from .config import RefinerTrainConfig, held_out_keys, train_config
from .evaluation import composite, evaluate
from .frames import Frames, drawn_level, refined
from .model import Refiner, RefinerConfig, flops, parameter_count, state_from


def frame_generator(bundle: Path, data: Path, cfg: RefinerTrainConfig):
    """When the config trains on generated frames: a function (clip, f, generator) -> the
    bundle's generated world points [N, 3] of that frame, made as `unica eval` makes its
    teacher-forced frames; else None."""
    if cfg.generated_fraction == 0:
        return None
    from ..eval import Avatar, teacher_forced  # eval draws with this module's refiner

    avatar = Avatar(bundle, data, cfg.splat_level)
    return lambda clip, f, gen: teacher_forced(avatar, clip, f, gen)[0]


def train(args) -> dict:
    from ..train import distributed, leave_process_group, training_device

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
        checkpoint_file.write_text(out / "refiner_config.json", json.dumps(asdict(cfg), indent=2) + "\n")
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
            checkpoint_file.cut_log(log_path, start - 1)  # rows are numbered from step 0
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
    checkpoint_file.write_text(out / "refiner_eval.json", json.dumps(metrics, indent=2) + "\n")
    checkpoint_file.write_tensors(out / "refiner.safetensors", {f"refiner.{k}": v for k, v in model.state_dict().items()})
    if args.write_bundle:
        add_to_bundle(args.bundle, model)
    return metrics


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
