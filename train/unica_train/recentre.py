"""Recentring the context window in latent space (docs/architecture.md, The live loop) instead of re-encoding it.

The live loop normalises every group so that the 3rd frame's root sits at 0.5; after each
generated frame its root shift δ = root(new) − 0.5 moves the world root by δ / scale and
the window is translated by −δ, which adds −δ_k to channel k of every foreground pixel of
every context map. The reference rollout (train.py `Run.rollout`) decodes, translates and
re-encodes the three context maps every frame; the GPU engine must not re-encode. This
module replaces the re-encoding by a latent translation

    E(x − δ·m) ≈ E(x) − Σ_k δ_k J_k,   J_k = ∂E(x + t·e_k·m)/∂t  (times latent_scale)

with J [3, 4, 16, 16] taken by central finite differences at reference maps (the bundle's
standing-start context decoded, or dataset frames) and averaged, and measures how good that
is: directly on dataset maps (latent error against the re-encoded one, decoded error in
mm) and on the live loop (rollouts of both kinds against the teacher).

    python -m unica_train.recentre --bundle assets/witch/bundle --keys "60W 60S 60A 120I" \\
        --frames 300 --out /tmp/recentre [--teacher RENDER/manifest.json] \\
        [--data DATASET [--basis dataset] [--measure]] [--modes "reencode latent none"]

writes `rollout_<mode>.json` per mode (the comparator's format plus the per-frame root
shifts; with --diagnose each frame's gap between the carried and the re-encoded context),
`basis.safetensors`, with --teacher `comparison.txt` (the comparator's rows of every mode
next to the teacher's), and with --measure `approximation.json` (the direct measurement on
the dataset's held-out clips)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from . import bundle as bundle_io
from . import checkpoint as checkpoint_file
from .diffusion import Schedule, brake_options, frame_idle_scales, sample_next, sampler_options
from .dataset import action_quarter, quarter_turn, quarter_turn_action
from .train import parse_keys

MAP_SIZE = 128
MODES = ("reencode", "latent", "none")
ROOT_MOTIONS = ("centre", "decoded")
HEADINGS = ("world", "canonical")


# -- maps from the bundle's layout tensors ------------------------------------------
def to_maps(unit: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Foreground values [..., N, 3] -> maps [..., 3, 128, 128] with background 0 (as
    BakedDataset.to_maps, from the bundle's map.pixels)."""
    lead = unit.shape[:-2]
    maps = torch.zeros(*lead, MAP_SIZE * MAP_SIZE, 3, dtype=unit.dtype)
    maps[..., pixels.long(), :] = unit
    return maps.reshape(*lead, MAP_SIZE, MAP_SIZE, 3).movedim(-1, -3)


def from_maps(maps: torch.Tensor, pixels: torch.Tensor) -> torch.Tensor:
    """Maps [..., 3, 128, 128] -> foreground values [..., N, 3]."""
    return maps.flatten(-2)[..., pixels.long()].movedim(-2, -1)


def turn_unit(points: torch.Tensor, turns: int) -> torch.Tensor:
    """Normalised points [..., 3] turned `turns` quarter turns (`dataset.quarter_turn`)
    about the vertical through the cube's centre (x = z = 0.5); the engine's
    `quarter_turn.wgsl`."""
    if turns % 4 == 0:
        return points
    centre = torch.tensor([0.5, 0.0, 0.5], dtype=points.dtype)
    return quarter_turn(points - centre, turns) + centre


def heading_quarters(actions: list[int], heading: str) -> int:
    """The model's heading after `actions` (`rollout`'s `heading`): the last movement
    key's quarter turns from W where it is "canonical" (0 before any key), else 0."""
    keys = [a for a in actions if a != 0]
    return action_quarter(keys[-1]) if heading == "canonical" and keys else 0


def root(points: torch.Tensor, waist: torch.Tensor) -> torch.Tensor:
    """Mean of the waist points: [..., N, 3] -> [..., 3]."""
    return points[..., waist.long(), :].mean(-2)


def mask(pixels: torch.Tensor) -> torch.Tensor:
    """[1, 128, 128] foreground mask."""
    m = torch.zeros(MAP_SIZE * MAP_SIZE)
    m[pixels.long()] = 1
    return m.reshape(1, MAP_SIZE, MAP_SIZE)


def encoder_fn(vae, latent_scale: float):
    """maps [B, 3, 128, 128] -> scaled latent means [B, 4, 16, 16]."""

    @torch.no_grad()
    def encode(maps):
        return vae.encoder(maps)[0] * latent_scale

    return encode


# -- the shift basis ----------------------------------------------------------------
@torch.no_grad()
def shift_basis(encode, maps: torch.Tensor, pixels: torch.Tensor, step: float = 0.03, central: bool = True, batch: int = 64) -> torch.Tensor:
    """J [3, C, h, w]: the derivative of `encode` along a uniform shift of channel k of the
    foreground, J_k ≈ (E(x + step·e_k·m) − E(x − step·e_k·m)) / (2·step) (one-sided
    (E(x + step·e_k·m) − E(x)) / step when not central), averaged over the reference maps
    [B, 3, 128, 128] (background 0). A step of the size of the shifts met in the loop
    gives the secant slope over that range rather than the tangent at x."""
    m = mask(pixels).to(maps.dtype)
    out = None
    for start in range(0, maps.shape[0], batch):
        x = maps[start:start + batch]
        base = None if central else encode(x)
        rows = []
        for k in range(3):
            e = torch.zeros(1, 3, 1, 1, dtype=maps.dtype)
            e[0, k] = 1
            d = step * e * m
            if central:
                rows.append((encode(x + d) - encode(x - d)).sum(0) / (2 * step))
            else:
                rows.append((encode(x + d) - base).sum(0) / step)
        part = torch.stack(rows)
        out = part if out is None else out + part
    return out / maps.shape[0]


def apply_shift(latents: torch.Tensor, shift: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
    """Latents [..., C, h, w] of maps translated by −shift (a 3-vector): latents − Σ δ_k J_k."""
    return latents - torch.einsum("k,kchw->chw", shift.to(basis.dtype), basis)


@torch.no_grad()
def decode_points(vae, z: torch.Tensor, latent_scale: float, pixels: torch.Tensor) -> torch.Tensor:
    """Scaled latents [B, C, h, w] -> foreground points [B, N, 3]."""
    return from_maps(vae.decode(z / latent_scale), pixels)


def bundle_basis(vae, extra: dict, manifest: dict, step: float = 0.03) -> torch.Tensor:
    """J at the bundle's standing start: its three context latents decoded (foreground
    kept, background 0), averaged."""
    scale = manifest["latent_scale"]
    pixels = extra["map.pixels"]
    points = decode_points(vae, extra["context.latents"], scale, pixels)
    return shift_basis(encoder_fn(vae, scale), to_maps(points, pixels), pixels, step)


def dataset_basis(vae, ds, manifest: dict, clips: list[int], stride: int = 40, step: float = 0.03) -> tuple[torch.Tensor, int]:
    """(J, frames used) averaged over dataset maps: the anchor (3rd) frame of every
    `stride`-th group of `clips`. Costs one bake and a few hundred encoder passes, so
    training could store it in the bundle next to the context latents."""
    pixels = ds.pixels
    ref = torch.stack([u[2] for u in _groups(ds, clips, stride)])
    scale = manifest["latent_scale"]
    return shift_basis(encoder_fn(vae, scale), to_maps(ref, pixels), pixels, step), int(ref.shape[0])


# -- the rollout ----------------------------------------------------------------------
def keys_text(actions: list[int]) -> str:
    """Run-length key script of an action list ("60W 20I")."""
    out, names = [], "IWSAD"
    for a in actions:
        if out and out[-1][0] == a:
            out[-1][1] += 1
        else:
            out.append([a, 1])
    return " ".join(f"{n}{names[a]}" for a, n in out)


@torch.no_grad()
def rollout(vae, unet, schedule, scale, context, keys, steps, cfg_scale, seed, pixels, waist, norm_scale, shift_mode,
            frames: int | None = None, basis: torch.Tensor | None = None, window: torch.Tensor | None = None,
            start_root: torch.Tensor | None = None, diagnose: bool = False, log_every: int = 0,
            on_frame=None, guided_steps: int | None = None, guide_idle: bool = True, noise_scale: float = 1.0,
            idle_cfg_scale: float | None = None, idle_brake_cfg_scale: float | None = None,
            idle_brake_frames: int = 0, root_motion: str = "centre", heading: str = "world",
            grounded: bool = False, stand_speed: float | None = None, frame_rate: float = 30.0,
            on_context=None) -> dict:
    """The live loop of train.py's `Run.rollout` from the clean context latents [3, C, h, w]
    (scaled), recentring each frame either by re-encoding the translated window
    ("reencode", the reference) or by the latent shift context − Σ δ_k J_k ("latent", no
    encoder call after the start), or not at all ("none", a control). `keys` is a key
    script ("60W 20I") or a list of action ids; `window` the normalised foreground points
    [3, N, 3] of the context (default: the context decoded; only "reencode" and `diagnose`
    use it); `start_root` the world root of the 3rd context frame (default 0).

    With `diagnose` the window is also tracked in the other modes and every frame records
    the relative RMS gap between the carried context and the re-encoded window (the
    re-encoding is measured, never fed back). `on_frame(i, points, shift)` sees each new
    frame's normalised points [N, 3] (its root at 0.5 + shift); `on_context(i, context,
    model_action)` each frame's context latents [3, C, h, w] and action as the model is
    about to see them. Idle frames are guided at
    `idle_cfg_scale`, the first `idle_brake_frames` after a key at `idle_brake_cfg_scale`
    (`diffusion.frame_idle_scales`).

    `root_motion` says what a new frame's root shift is measured from: "centre" (0.5, where
    the window's last frame was put) or "decoded" (the root of the context's last latent
    decoded, so that a bias of the decoder's root common to both frames cancels).

    `heading` "canonical" (mode "reencode" only) shows the model its window turned by the
    quarter turns that take the last movement key's direction to W's, the action turned
    with it, and turns the new frame back (the engine's `Heading::Canonical`); "world"
    shows it as it is. In mode "reencode" every frame's context is the window encoded at
    the frame's start (the first frame's too: the given `context` then only makes the
    default window).

    `grounded` sets each frame's root motion height so that the world root ends (root −
    lowest point) / norm_scale above the floor, y = 0 (the engine's `Manifest::grounded`):
    the frame's lowest point stands on the floor and the height accumulates nothing.

    `stand_speed` (m/s; the engine's `Manifest::stand_speed`) is the stand latch: under
    Idle, once a frame's horizontal root motion is slower than it (at `frame_rate`), the
    world root holds still until a movement key; the standing start begins held."""
    if root_motion not in ROOT_MOTIONS:
        raise ValueError(f"root_motion {root_motion!r}: expected one of {ROOT_MOTIONS}")
    if shift_mode not in MODES:
        raise ValueError(f"shift_mode {shift_mode!r}: expected one of {MODES}")
    if heading not in HEADINGS:
        raise ValueError(f"heading {heading!r}: expected one of {HEADINGS}")
    if heading != "world" and shift_mode != "reencode":
        raise ValueError(f"heading {heading!r} needs shift_mode 'reencode' (the window is turned before it is encoded)")
    if shift_mode == "latent" and basis is None:
        raise ValueError("shift_mode 'latent' needs the shift basis")
    if isinstance(keys, str):
        text = keys
        actions = parse_keys(keys, frames if frames is not None else sum(int(t[:-1]) for t in keys.split()))
    else:
        actions = list(keys)[:frames] if frames is not None else list(keys)
        text = keys_text(actions)
    encode = encoder_fn(vae, scale)
    context = context.clone()
    track = shift_mode == "reencode" or diagnose
    if track and window is None:
        window = decode_points(vae, context, scale, pixels)
    world_root = torch.zeros(3) if start_root is None else start_root.clone().float()
    path, points, shifts, gaps = [world_root.tolist()], [], [], []
    gen = torch.Generator().manual_seed(seed)
    started = time.time()
    idle_scales = frame_idle_scales(actions, idle_cfg_scale, idle_brake_cfg_scale, idle_brake_frames)
    quarters = 0  # the model's heading: the last movement key's quarter turns from W
    stand = 0.0 if stand_speed is None else stand_speed * norm_scale / frame_rate  # normalised units a frame
    standing = True
    for i, a in enumerate(actions):
        if heading == "canonical" and a != 0:
            quarters = action_quarter(a)
        to_model = (4 - quarters) % 4
        if shift_mode == "reencode":
            context = encode(to_maps(turn_unit(window, to_model), pixels))
        model_action = quarter_turn_action(a, to_model)
        if on_context is not None:
            on_context(i, context, model_action)
        z = sample_next(unet, schedule, context[None], torch.tensor([model_action]), steps, cfg_scale, generator=gen,
                        guided_steps=guided_steps, guide_idle=guide_idle, noise_scale=noise_scale,
                        idle_cfg_scale=idle_scales[i])
        # [N, 3], NaN to the cube's centre and clamped into it, as the engine does
        new = turn_unit(decode_points(vae, z, scale, pixels)[0].nan_to_num(0.5).clamp(0.0, 1.0), quarters)
        # the slide puts the new frame's root at 0.5 in the window; the motion moves the world
        shift = root(new, waist) - 0.5
        if root_motion == "decoded":
            last = turn_unit(decode_points(vae, context[-1:], scale, pixels)[0].nan_to_num(0.5).clamp(0.0, 1.0), quarters)
            motion = root(new, waist) - root(last, waist)
        else:
            motion = shift
        if grounded:
            motion = motion.clone()
            motion[1] = root(new, waist)[1] - new[:, 1].min() - norm_scale * world_root[1]
        if stand > 0:
            if a != 0:
                standing = False
            elif standing or float(torch.hypot(motion[0], motion[2])) < stand:
                standing = True
                motion = motion.clone()
                motion[0] = motion[2] = 0.0
        if on_frame is not None:
            on_frame(i, new, shift)
        world_root = world_root + motion / norm_scale
        if track:
            window = torch.cat([window[1:], new[None]]) - shift
        if shift_mode == "reencode":
            pass  # encoded at the next frame's start
        elif shift_mode == "latent":
            context = apply_shift(torch.cat([context[1:], z]), shift, basis)
        else:
            context = torch.cat([context[1:], z])
        if diagnose:
            ref = encode(to_maps(window, pixels))
            if shift_mode == "reencode":
                context = ref  # the context the next frame starts from
            gaps.append([round(float(((context[j] - ref[j]).pow(2).mean() / ref[j].var()).sqrt()), 5) for j in range(3)])
        path.append(world_root.tolist())
        shifts.append([round(float(s), 6) for s in motion])
        if i % 30 == 0:
            points.append(((new - 0.5 - shift) / norm_scale + world_root).tolist())
        if log_every and (i + 1) % log_every == 0:
            print(f"{shift_mode}: frame {i + 1}/{len(actions)} {time.time() - started:.0f} s", flush=True)
    out = {"keys": text, "frames": len(actions), "root_path": path, "sampled_points": points,
           "shift_mode": shift_mode, "shifts": shifts}
    if diagnose:
        out["context_gap"] = gaps
    return out


# -- the direct measurement ---------------------------------------------------------
def _groups(ds, clips: list[int], stride: int):
    """(normalised group [4, N, 3]) of the given clips at the given stride."""
    for c in clips:
        world = ds.positions(c, list(range(ds.clips[c]["actions"].shape[0])))
        for s in range(0, world.shape[0] - 3, stride):
            unit, _ = ds.normalise(world[s:s + 4])
            yield unit


@torch.no_grad()
def measure(vae, manifest: dict, extra: dict, ds, bases: dict, clips: list[int], stride: int = 8,
            magnitudes=(0.01, 0.02, 0.04, 0.08), seed: int = 0, oracle: bool = True) -> dict:
    """How well E(x) − Σ δ_k J_k stands for E(x − δ·m) on dataset maps x (context frames of
    the groups of `clips`, every `stride`-th group): δ either of a given magnitude in a
    random direction, or the real one a context frame gets in the loop (the root shifts of
    the frames that follow it, summed: 1, 2 or 3 of them). Per basis: the latent RMS error
    relative to the latent std, the decoded mean position error (mm) against the decoded
    re-encoding and against the true translated map, the decoded root error (mm); and the
    same with no correction at all for scale, and (`oracle`) with the tangent at x itself."""
    scale = manifest["latent_scale"]
    norm = manifest["normalisation"]["scale"]
    pixels, waist = extra["map.pixels"], extra["map.waist"]
    encode = encoder_fn(vae, scale)
    gen = torch.Generator().manual_seed(seed)
    xs, deltas, kinds = [], [], []
    for unit in _groups(ds, clips, stride):
        r = root(unit, waist)  # [4, 3]; r[2] = 0.5
        j = int(torch.randint(4, (1,), generator=gen))
        for mag in magnitudes:
            d = torch.randn(3, generator=gen)
            d[1] *= 0.3  # mostly horizontal, as root motion is
            xs.append(unit[j])
            deltas.append(d / d.norm() * mag)
            kinds.append(f"random {mag:g}")
        # A generated frame (here the 4th, root 0.5 + v) is shifted by its own root shift,
        # then by those of the next two frames before it leaves the window: in total by
        # v, 2v, 3v under steady motion (v = r3 - r2).
        n = int(torch.randint(1, 4, (1,), generator=gen))
        xs.append(unit[3])
        deltas.append((r[3] - r[2]) * n)
        kinds.append(f"real x{n}")
    xs = torch.stack(xs)
    deltas = torch.stack(deltas)
    maps = to_maps(xs, pixels)
    m = mask(pixels)
    shifted = maps - deltas[:, :, None, None] * m
    exact, base = [], []
    for s in range(0, maps.shape[0], 64):
        exact.append(encode(shifted[s:s + 64]))
        base.append(encode(maps[s:s + 64]))
    exact, base = torch.cat(exact), torch.cat(base)
    std = float(base.std())
    truth = xs - deltas[:, None, :]
    dec_exact = torch.cat([decode_points(vae, exact[s:s + 64], scale, pixels) for s in range(0, exact.shape[0], 64)])

    def stats(approx):
        err = approx - exact
        rel = err.pow(2).mean((1, 2, 3)).sqrt() / std
        dec = torch.cat([decode_points(vae, approx[s:s + 64], scale, pixels) for s in range(0, approx.shape[0], 64)])
        mm_vs_exact = (dec - dec_exact).norm(dim=-1).mean(-1) / norm * 1000
        mm_vs_truth = (dec - truth).norm(dim=-1).mean(-1) / norm * 1000
        root_mm = (root(dec, waist) - root(dec_exact, waist)).norm(dim=-1) / norm * 1000
        root_err = (root(dec, waist) - root(dec_exact, waist)) / norm * 1000  # signed, per axis
        return rel, mm_vs_exact, mm_vs_truth, root_mm, root_err

    reference = {"none (E(x), no shift)": base}
    for name, J in bases.items():
        reference[f"latent J[{name}]"] = base - torch.einsum("bk,kchw->bchw", deltas, J)
    if oracle:
        # The tangent at x itself (an encoder pass per axis and frame: not for the engine,
        # it separates the basis' pose dependence from the encoder's curvature in δ).
        tangent = torch.stack([shift_basis(encode, maps[b:b + 1], pixels, 0.01) for b in range(maps.shape[0])])
        reference["oracle: tangent at x, step 0.01"] = base - torch.einsum("bk,bkchw->bchw", deltas, tangent)
    table = {}
    order = sorted(set(kinds), key=lambda k: (k.startswith("real"), float(k.split()[1].lstrip("x"))))
    ex_mm_truth = (dec_exact - truth).norm(dim=-1).mean(-1) / norm * 1000
    ex_root_truth = (root(dec_exact, waist) - root(truth, waist)).norm(dim=-1) / norm * 1000
    for kind in order:
        sel = torch.tensor([k == kind for k in kinds])
        row = {
            "count": int(sel.sum()),
            "mean_delta_norm": round(float(deltas[sel].norm(dim=-1).mean()), 4),
            "mean_delta_mm": round(float(deltas[sel].norm(dim=-1).mean()) / norm * 1000, 1),
            "reencoded": {"decoded_vs_true_mm": round(float(ex_mm_truth[sel].mean()), 2),
                          "root_vs_true_mm": round(float(ex_root_truth[sel].mean()), 2)},
        }
        for name, approx in reference.items():
            rel, mm_ex, mm_tr, rmm, rerr = stats(approx)
            row[name] = {
                "latent_rel_rms": round(float(rel[sel].mean()), 4),
                "latent_rel_rms_p95": round(float(rel[sel].quantile(0.95)), 4),
                "decoded_vs_reencoded_mm": round(float(mm_ex[sel].mean()), 2),
                "decoded_vs_true_mm": round(float(mm_tr[sel].mean()), 2),
                "root_vs_reencoded_mm": round(float(rmm[sel].mean()), 2),
                "root_vs_reencoded_mm_p95": round(float(rmm[sel].quantile(0.95)), 2),
                "root_bias_mm_xyz": [round(float(v), 2) for v in rerr[sel].mean(0)],
            }
        table[kind] = row
    return {"latent_std": std, "frames": int(xs.shape[0]), "table": table}


def approximation_text(result: dict) -> str:
    """measure()'s table as text: per shift kind and basis, latent relative RMS error,
    decoded error and decoded root error against the re-encoding (mm)."""
    lines = [f"{'shift':13} {'|δ| mm':>7}  {'recentring':44} {'latent rel':>10} {'decoded mm':>10} {'root mm':>8} {'root p95':>8}"]
    for kind, row in result["table"].items():
        first = True
        for name, v in row.items():
            if not (isinstance(v, dict) and "latent_rel_rms" in v):
                continue
            head = f"{kind:13} {row['mean_delta_mm']:7.1f}" if first else " " * 21
            lines.append(f"{head}  {name:44} {v['latent_rel_rms']:10.4f} {v['decoded_vs_reencoded_mm']:10.1f} "
                         f"{v['root_vs_reencoded_mm']:8.1f} {v['root_vs_reencoded_mm_p95']:8.1f}")
            first = False
    return "\n".join(lines)


# -- the command line -----------------------------------------------------------------
def side_by_side(rows_by_mode: dict) -> str:
    """The comparator's rows of several rollouts next to the teacher, as text."""
    modes = list(rows_by_mode)
    first = rows_by_mode[modes[0]]
    head = f"{'key':3} {'frames':>9} | {'teacher dist/head/speed':>25}"
    for mode in modes:
        head += f" | {mode + ' dist/head/speed':>25}"
    lines = [head]

    def cell(leg):
        h = "-" if leg["heading_deg"] is None else f"{leg['heading_deg']:.0f}"
        return f"{leg['distance_m']:7.3f} m {h:>5}° {leg['speed_m_s']:5.2f} m/s"

    for i, row in enumerate(first):
        line = f"{row['key']:3} {row['frames'][0]:>4}-{row['frames'][1]:<4} | {cell(row['teacher']):>25}"
        for mode in modes:
            line += f" | {cell(rows_by_mode[mode][i]['model']):>25}"
        lines.append(line)
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", type=Path, required=True)
    parser.add_argument("--keys", default="60W 60S 60A 120I")
    parser.add_argument("--frames", type=int, default=300, help="rollout length (0: no rollouts)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--modes", default="reencode latent", help="rollouts to run: reencode, latent, none")
    parser.add_argument("--steps", type=int, help="DDIM steps (default: the bundle's sampler)")
    parser.add_argument("--cfg-scale", type=float, help="default: the bundle's sampler")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--basis", choices=("context", "dataset"), default="context",
                        help="J at the bundle's standing start, or averaged over --data's training clips")
    parser.add_argument("--basis-step", type=float, default=0.03, help="finite-difference step of J (normalised units)")
    parser.add_argument("--diagnose", action="store_true", help="record each frame's gap to the re-encoded window")
    parser.add_argument("--teacher", type=Path, help="teacher manifest.json (unica render --teacher) to compare with")
    parser.add_argument("--data", type=Path, help="baked dataset (for --basis dataset and --measure)")
    parser.add_argument("--measure", action="store_true", help="measure the approximation directly on --data's frames")
    parser.add_argument("--clips", default="4,13", help="held-out dataset clips: measured on, left out of the dataset basis")
    parser.add_argument("--stride", type=int, default=8, help="group stride of the measurement")
    args = parser.parse_args(argv)
    if (args.measure or args.basis == "dataset") and not args.data:
        parser.error("--measure and --basis dataset need --data")
    torch.set_num_threads(2)
    torch.manual_seed(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    vae, unet, extra, manifest = bundle_io.load(args.bundle)
    vae.eval(), unet.eval()
    scale = manifest["latent_scale"]
    norm = manifest["normalisation"]["scale"]
    pixels, waist = extra["map.pixels"], extra["map.waist"]
    bases = {f"context, step {args.basis_step:g}": bundle_basis(vae, extra, manifest, args.basis_step)}
    if args.data:
        from .dataset import BakedDataset

        ds = BakedDataset(args.data)
        held = [int(c) for c in args.clips.split(",")]
        J, count = dataset_basis(vae, ds, manifest, [c for c in range(len(ds.clips)) if c not in held], step=args.basis_step)
        bases[f"dataset {count} frames, step {args.basis_step:g}"] = J
    basis = list(bases.values())[0 if args.basis == "context" else 1]
    checkpoint_file.write_tensors(args.out / "basis.safetensors", {"shift_basis": basis})
    print(f"shift basis J ({args.basis}, step {args.basis_step}): per-axis RMS "
          f"{[round(float(v), 3) for v in basis.pow(2).mean((1, 2, 3)).sqrt()]}", flush=True)

    if args.measure:
        bases = {"context, step 0.001": bundle_basis(vae, extra, manifest, 0.001), **bases}
        started = time.time()
        result = measure(vae, manifest, extra, ds, bases, held, args.stride, seed=args.seed)
        checkpoint_file.write_text(args.out / "approximation.json", json.dumps(result, indent=2) + "\n")
        print(approximation_text(result))
        print(f"measured in {time.time() - started:.0f} s", flush=True)

    if args.frames <= 0:
        return
    schedule = Schedule(manifest["diffusion"]["steps"], manifest["diffusion"]["beta_start"], manifest["diffusion"]["beta_end"])
    steps = args.steps or manifest["sampler"]["ddim_steps"]
    cfg_scale = args.cfg_scale if args.cfg_scale is not None else manifest["sampler"]["cfg_scale"]
    rows = {}
    for mode in args.modes.split():
        started = time.time()
        out = rollout(vae, unet, schedule, scale, extra["context.latents"], args.keys, steps, cfg_scale, args.seed,
                      pixels, waist, norm, mode, frames=args.frames, basis=basis, diagnose=args.diagnose, log_every=50,
                      **sampler_options(manifest["sampler"]), **brake_options(manifest["sampler"]))
        out["seconds"] = round(time.time() - started, 1)
        out["basis"] = args.basis if mode == "latent" else None
        path = args.out / f"rollout_{mode}.json"
        checkpoint_file.write_text(path, json.dumps(out) + "\n")
        print(f"{mode}: {args.frames} frames in {out['seconds']} s -> {path}", flush=True)
        if args.teacher:
            from .compare import compare

            teacher = [f["root"] for f in json.loads(args.teacher.read_text())["frames"]]
            rows[mode] = compare(out, teacher)
    if rows:
        text = side_by_side(rows)
        checkpoint_file.write_text(args.out / "comparison.txt", text + "\n")
        checkpoint_file.write_text(args.out / "comparison.json", json.dumps(rows, indent=2) + "\n")
        print(text)


if __name__ == "__main__":
    main()
