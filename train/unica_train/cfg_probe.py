"""Chooses the sampler's CFG scale by measurement (issue #17): rolls the bundle out on a
key script at each scale (the PyTorch reference of the live loop, 10 DDIM steps, PCA
clean-up) and compares each key segment's heading and distance with the teacher's on
the same keys; the scale with the smallest summed distance error, among those whose
every moving segment heads within 30° of the teacher's, is the best.

    python -m unica_train.cfg_probe --bundle B --data DATA --teacher RENDER/manifest.json \\
        [--keys "30W 30S 30A 20I"] [--scales 1,2,3,4,5,6] [--guided-steps all,5] \\
        [--guide-idle yes|no] [--noise-scale S] [--write]

`--teacher` is `unica render --teacher CHARACTER --keys K --size 16 --views 1`'s
manifest; `--write` sets the bundle's `sampler.cfg_scale` to the best scale (and its
`guide_idle` and `noise_scale` to the ones probed with, the bundle's unless given).
`--guided-steps` also tries guidance intervals (guidance over the first N DDIM steps
only, the PyTorch sampler's `guided_steps`); the engine guides every step, so a best
interval is reported, not written. Session 17 measured that the keys are lost with it
(assets/witch/README.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from . import compare

HEADING_LIMIT = 30.0


def segments(path: list[list[float]], keys: str) -> list[dict]:
    """Per key segment of `keys` ("30W 20I"): the key and `compare.leg` of the root's
    displacement (heading in degrees, 0 = +Z, 90 = +X, none under 5 cm; distance);
    `path` [frames + 1][3] starts with the root before the first frame."""
    frames = len(path) - 1
    return [{"key": key, **compare.leg(path, a, b)} for key, a, b in compare.segments(keys, frames)]


def score(model: list[dict], teacher: list[dict]) -> tuple[float, bool]:
    """(summed distance error in m over the moving segments, every moving heading within
    HEADING_LIMIT of the teacher's; a segment that barely moved has no heading and is
    off)."""
    error, heads = 0.0, True
    for m, t in zip(model, teacher):
        if m["key"] == "I":
            continue
        error += abs(m["distance_m"] - t["distance_m"])
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
    parser.add_argument("--noise-scale", type=float, help="the starting noise's scale (default: the bundle's sampler)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write", action="store_true", help="set the bundle's sampler.cfg_scale to the best scale")
    args = parser.parse_args(argv)
    from .eval import Avatar

    frames = json.loads(args.teacher.read_text())["frames"]
    teacher = segments([frames[0]["root"]] + [f["root"] for f in frames], args.keys)
    print("teacher  " + line(teacher))
    av = Avatar(args.bundle, args.data, 128)
    steps = av.manifest["sampler"]["ddim_steps"]
    options = dict(av.sampler_options)
    if args.guide_idle:
        options["guide_idle"] = args.guide_idle == "yes"
    if args.noise_scale is not None:
        options["noise_scale"] = args.noise_scale
    idle = options.get("idle_cfg_scale")
    idle_text = f"at CFG {idle:g}" if idle is not None else "guided" if options["guide_idle"] else "unguided"
    print(f"sampler: {steps} DDIM steps, Idle {idle_text}, noise scale {options['noise_scale']:g}")
    results = []
    intervals = [None if g == "all" else int(g) for g in args.guided_steps.split(",")]
    for guided in intervals:
        for scale in [float(s) for s in args.scales.split(",")]:
            run = av.rollout(args.keys, {"steps": steps, "cfg_scale": scale, "pca": True, "guided_steps": guided, **options}, args.seed)
            model = segments(run["root_path"], args.keys)
            error, heads = score(model, teacher)
            results.append({"cfg_scale": scale, "guided_steps": guided, "segments": model, "distance_error_m": error,
                            "headings_ok": heads})
            print(f"{label(scale, guided, steps)}  " + line(model) + f"  distance error {error:.2f} m, headings {'ok' if heads else 'off'}",
                  flush=True)
    ok = [r for r in results if r["headings_ok"]] or results
    best = min(ok, key=lambda r: r["distance_error_m"])
    print(f"best: {label(best['cfg_scale'], best['guided_steps'], steps)}")
    if args.write and best["guided_steps"] is not None and best["guided_steps"] < steps:
        raise SystemExit(f"{args.bundle}: not written: the engine guides every DDIM step, and the best here guides "
                         f"only {best['guided_steps']} of {steps}")
    if args.write:
        path = args.bundle / "manifest.json"
        manifest = json.loads(path.read_text())
        manifest["sampler"]["cfg_scale"] = best["cfg_scale"]
        manifest["sampler"].update(options)
        manifest["sampler"]["cfg_probe"] = {"keys": args.keys, "teacher": teacher, "results": results}
        path.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
        print(f"set {path}'s sampler to {label(best['cfg_scale'], best['guided_steps'], steps)}")


if __name__ == "__main__":
    main()
