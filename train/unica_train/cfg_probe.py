"""Chooses the sampler's CFG scale by measurement (issue #17): rolls the bundle out on a
key script at each scale (the PyTorch reference of the live loop, 10 DDIM steps, PCA
clean-up) and compares each key segment's heading and distance with the teacher's on
the same keys; the scale with the smallest summed distance error (every segment's, the
distance glided under Idle too), among those whose every moving segment heads within 30°
of the teacher's, is the best.

    python -m unica_train.cfg_probe --bundle B --data DATA --teacher RENDER/manifest.json \\
        [--keys "30W 30S 30A 20I"] [--scales 1,2,3,4,5,6] [--guided-steps all,5] \\
        [--guide-idle yes|no] [--noise-scale S] [--idle-scale S] [--brake S:N] [--seeds 0,1] [--write]

`--teacher` is `unica render --teacher CHARACTER --keys K --size 16 --views 1`'s
manifest; `--write` sets the bundle's `sampler.cfg_scale` to the best scale (and its
`guide_idle` and `noise_scale` to the ones probed with, the bundle's unless given).
`--guided-steps` also tries guidance intervals (guidance over the first N DDIM steps
only, the PyTorch sampler's `guided_steps`); the engine guides every step, so a best
interval is reported, not written: measured, the keys are lost with it
(docs/records/witch/README.md).

Each line also gives the evaluation's motion numbers for the run (`eval.motion`, as
`unica eval` scores them): every turn's frames, the stop after every release (frames
until the root stays below 0.05 m/s, and the distance), and the worst key's speed error;
`--noise-scale`, `--idle-scale` and `--brake` (the first N Idle frames after a key guided
at S, `diffusion.frame_idle_scales`; `none` for no braking) take comma-separated lists and
`--seeds` several seeds, so one call measures a grid. The best is chosen as before, by
the distance error summed over the seeds."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch

from . import bundle as bundle_io
from . import compare

HEADING_LIMIT = 30.0


def segments(path: list[list[float]], keys: str) -> list[dict]:
    """Per key segment of `keys` ("30W 20I"): the key and `compare.leg` of the root's
    displacement (heading in degrees, 0 = +Z, 90 = +X, none under 5 cm; distance);
    `path` [frames + 1][3] starts with the root before the first frame."""
    frames = len(path) - 1
    return [{"key": key, **compare.leg(path, a, b)} for key, a, b in compare.segments(keys, frames)]


def score(model: list[dict], teacher: list[dict]) -> tuple[float, bool]:
    """(summed distance error in m over every segment, Idle's too: a glide after a
    release counts; every moving heading within HEADING_LIMIT of the
    teacher's; a moving segment that barely moved has no heading and is off)."""
    error, heads = 0.0, True
    for m, t in zip(model, teacher):
        error += abs(m["distance_m"] - t["distance_m"])
        if m["key"] == "I":
            continue
        if m["heading_deg"] is None or t["heading_deg"] is None:
            heads = False
            continue
        turn = (m["heading_deg"] - t["heading_deg"] + 180) % 360 - 180
        heads &= abs(turn) <= HEADING_LIMIT
    return error, heads


def line(segs: list[dict]) -> str:
    heading = lambda s: "   —  " if s["heading_deg"] is None else f"{s['heading_deg']:6.1f}°"
    return " | ".join(f"{s['key']} {heading(s)} {s['distance_m']:.2f} m" for s in segs)


def label(scale: float, guided: int | None, steps: int) -> str:
    """"cfg 4.0" (every step guided) or "cfg 4.0 for 5/10 steps"."""
    return f"cfg {scale:3.1f}" + ("" if guided is None or guided >= steps else f" for {guided}/{steps} steps")


def floats(text: str | None) -> list[float]:
    return [float(v) for v in text.split(",")] if text else []


def idle_label(options: dict, idle: float | None) -> str:
    """How Idle frames are guided: "CFG 1.5", "guided" (as the keys) or "unguided", with
    the braking after a key where set (", braked at CFG 2 for 10")."""
    text = f"CFG {idle:g}" if idle is not None else "guided" if options["guide_idle"] else "unguided"
    brake = options.get("idle_brake_cfg_scale")
    return text + ("" if brake is None else f", braked at CFG {brake:g} for {options.get('idle_brake_frames', 0)}")


def brakes(text: str | None, default: dict) -> list[dict]:
    """`--brake` "2:10,none" -> the braking settings to try (default: the bundle's)."""
    if not text:
        return [default]
    out = []
    for item in text.split(","):
        if item.strip() == "none":
            out.append({"idle_brake_cfg_scale": None, "idle_brake_frames": 0})
            continue
        scale, _, frames = item.partition(":")
        try:
            brake = {"idle_brake_cfg_scale": float(scale), "idle_brake_frames": int(frames)}
        except ValueError:
            brake = None
        if brake is None or not math.isfinite(brake["idle_brake_cfg_scale"]) or brake["idle_brake_frames"] < 1:
            raise SystemExit(f"--brake {item!r}: expected SCALE:FRAMES (2.0:10: a finite scale, at least 1 frame) or none")
        out.append(brake)
    return out


def motion_numbers(path: list[list[float]], teacher: list[list[float]], keys: str) -> dict:
    """The evaluation's motion numbers (`eval.motion`) of a rollout's root path against the
    teacher's: turns {label: (frames, teacher's)}, stop frames and distance, worst speed
    error in %."""
    from .eval import motion, settle_frames
    from .train import parse_keys

    frames = len(path) - 1
    m = motion(torch.tensor(path), torch.tensor(teacher[: len(path)]), parse_keys(keys, frames), settle_frames(keys))
    return {"turns": {t["turn"]: (t["generated"], t["teacher"]) for t in m["turns"]},
            "stop_frames": m["stop_frames"], "teacher_stop_frames": m["teacher_stop_frames"],
            "stop_distance_m": m["stop_distance_m"], "stops": m["stops"],
            "speed_error_pct": max((s["speed_error_pct"] for s in m["segments"]), default=0.0)}


def motion_line(m: dict) -> str:
    turns = ", ".join(f"{k.split()[0]} {g if g is not None else '—'}/{t}" for k, (g, t) in m["turns"].items())
    frames = lambda n: "never" if n is None else n
    stops = ", ".join(f"{st['after']} {frames(st['frames'])}/{frames(st['teacher_frames'])} ({st['distance_m']:.2f} m)"
                      for st in m["stops"])
    return (f"turns (teacher) {turns}; stops after {stops}; worst speed error {m['speed_error_pct']:.1f} %")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", required=True, type=Path)
    parser.add_argument("--data", required=True, type=Path, help="a dataset baked from the bundle's character")
    parser.add_argument("--teacher", required=True, type=Path, help="manifest.json of `unica render --teacher` on --keys")
    parser.add_argument("--keys", default="30W 30S 30A 20I")
    parser.add_argument("--scales", default="1,2,3,4,5,6")
    parser.add_argument("--guided-steps", default="all",
                        help="comma-separated guidance intervals to try: guide only the first N DDIM steps ('all': every step)")
    parser.add_argument("--guide-idle", choices=("yes", "no"), help="guide Idle frames too (default: the bundle's sampler)")
    parser.add_argument("--noise-scale", help="the starting noise's scale, comma-separated to try several (default: the bundle's sampler)")
    parser.add_argument("--idle-scale", help="Idle frames' CFG scale, comma-separated to try several (default: the bundle's sampler)")
    parser.add_argument("--brake", help="SCALE:FRAMES, the first FRAMES Idle frames after a key at CFG SCALE, or none; "
                                        "comma-separated to try several (default: the bundle's sampler)")
    parser.add_argument("--root-motion", choices=("centre", "decoded"),
                        help="what a frame's root motion is measured from (recentre.rollout; default: the bundle's)")
    parser.add_argument("--heading", choices=("world", "canonical"),
                        help="which way the model sees its window (recentre.rollout; default: the bundle's)")
    parser.add_argument("--seeds", default="0", help="comma-separated seeds; each setting runs every one")
    parser.add_argument("--write", action="store_true", help="set the bundle's sampler.cfg_scale to the best scale")
    args = parser.parse_args(argv)
    from .eval import Avatar

    frames = json.loads(args.teacher.read_text())["frames"]
    roots = [frames[0]["root"]] + [f["root"] for f in frames]
    teacher = segments(roots, args.keys)
    print("teacher  " + line(teacher))
    av = Avatar(args.bundle, args.data, 128)
    steps = av.manifest["sampler"]["ddim_steps"]
    options = dict(av.sampler_options)
    if args.guide_idle:
        options["guide_idle"] = args.guide_idle == "yes"
    noise_scales = floats(args.noise_scale) or [options["noise_scale"]]
    idle_scales = floats(args.idle_scale) or [options.get("idle_cfg_scale")]
    brake_list = brakes(args.brake, av.brake_options)
    seeds = [int(s) for s in args.seeds.split(",")]
    root_motion = args.root_motion or av.root_motion
    heading = args.heading or av.heading
    print(f"sampler: {steps} DDIM steps, Idle {idle_label({**options, **av.brake_options}, options.get('idle_cfg_scale'))}, "
          f"noise scale {options['noise_scale']:g}")
    results = []
    intervals = [None if g == "all" else int(g) for g in args.guided_steps.split(",")]
    for guided in intervals:
        for noise in noise_scales:
            for idle, brake in [(i, b) for i in idle_scales for b in brake_list]:
                for scale in [float(s) for s in args.scales.split(",")]:
                    setting = dict(options, noise_scale=noise, idle_cfg_scale=idle, **brake)
                    runs, error, heads = [], 0.0, True
                    for seed in seeds:
                        run = av.rollout(args.keys, {"steps": steps, "cfg_scale": scale, "pca": True,
                                                     "guided_steps": guided, "root_motion": root_motion, "heading": heading, **setting}, seed)
                        model = segments(run["root_path"], args.keys)
                        seed_error, seed_heads = score(model, teacher)
                        moved = motion_numbers(run["root_path"], roots, args.keys)
                        error, heads = error + seed_error, heads and seed_heads
                        runs.append({"seed": seed, "segments": model, "distance_error_m": seed_error, **moved})
                        print(f"{label(scale, guided, steps)}, noise {noise:g}, Idle {idle_label(setting, idle)}, seed {seed}  "
                              + line(model) + f"  distance error {seed_error:.2f} m, headings {'ok' if seed_heads else 'off'}"
                              + "\n    " + motion_line(moved), flush=True)
                    results.append({"cfg_scale": scale, "guided_steps": guided, "noise_scale": noise,
                                    "idle_cfg_scale": idle, **brake, "runs": runs, "distance_error_m": error, "headings_ok": heads})
    ok = [r for r in results if r["headings_ok"]] or results
    best = min(ok, key=lambda r: r["distance_error_m"])
    print(f"best: {label(best['cfg_scale'], best['guided_steps'], steps)}, noise {best['noise_scale']:g}, "
          f"Idle {idle_label({**options, **best}, best['idle_cfg_scale'])}")
    if args.write and best["guided_steps"] is not None and best["guided_steps"] < steps:
        raise SystemExit(f"{args.bundle}: not written: the engine guides every DDIM step, and the best here guides "
                         f"only {best['guided_steps']} of {steps}")
    if args.write:
        path = args.bundle / "manifest.json"
        manifest = json.loads(path.read_text())
        manifest["sampler"]["cfg_scale"] = best["cfg_scale"]
        manifest["sampler"].update(options, noise_scale=best["noise_scale"])
        if best["idle_cfg_scale"] is not None:
            manifest["sampler"]["idle_cfg_scale"] = best["idle_cfg_scale"]
        for key in ("idle_brake_cfg_scale", "idle_brake_frames"):
            manifest["sampler"].pop(key, None)
        if best["idle_brake_cfg_scale"] is not None:
            manifest["sampler"]["idle_brake_cfg_scale"] = best["idle_brake_cfg_scale"]
            manifest["sampler"]["idle_brake_frames"] = best["idle_brake_frames"]
        if args.root_motion:
            manifest["root_motion"] = args.root_motion
        if args.heading:
            manifest["heading"] = args.heading
        manifest["sampler"]["cfg_probe"] = {"keys": args.keys, "teacher": teacher, "results": results}
        bundle_io.write_manifest(args.bundle, manifest)
        print(f"set {path}'s sampler to {label(best['cfg_scale'], best['guided_steps'], steps)}")


if __name__ == "__main__":
    main()
