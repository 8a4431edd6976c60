"""Compares a rollout's world root path (rollout.json from training) with the teacher's
under the same keys (manifest.json of `unica render --teacher`): per key segment the
horizontal displacement, its heading and the mean speed.

    python -m unica_train.compare --rollout RUN/rollout.json --teacher RENDER/manifest.json [--sheet PNG]"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from .plot import point_sheet
from .train import parse_keys

FRAME_RATE = 30.0


def segments(keys: str, frames: int) -> list[tuple[str, int, int]]:
    """(key, first frame, end frame) of each run of one key in the padded script."""
    actions = parse_keys(keys, frames)
    names = "IWSAD"
    out, start = [], 0
    for i in range(1, frames + 1):
        if i == frames or actions[i] != actions[start]:
            out.append((names[actions[start]], start, i))
            start = i
    return out


def leg(path: list[list[float]], a: int, b: int) -> dict:
    dx, dz = path[b][0] - path[a][0], path[b][2] - path[a][2]
    dist = math.hypot(dx, dz)
    return {
        "dx": round(dx, 3),
        "dz": round(dz, 3),
        "distance_m": round(dist, 3),
        "heading_deg": round(math.degrees(math.atan2(dx, dz)), 1) if dist > 0.05 else None,
        "speed_m_s": round(dist / ((b - a) / FRAME_RATE), 3),
    }


def compare(rollout: dict, teacher_roots: list[list[float]]) -> list[dict]:
    path = rollout["root_path"]
    frames = min(len(path), len(teacher_roots)) - 1
    rows = []
    for key, a, b in segments(rollout["keys"], frames):
        rows.append({"key": key, "frames": [a, b], "model": leg(path, a, b), "teacher": leg(teacher_roots, a, b)})
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rollout", type=Path, required=True)
    parser.add_argument("--teacher", type=Path, required=True)
    parser.add_argument("--sheet", type=Path, help="also write the rollout's sampled frames as point clouds (PNG)")
    args = parser.parse_args(argv)
    rollout = json.loads(args.rollout.read_text())
    teacher = [f["root"] for f in json.loads(args.teacher.read_text())["frames"]]
    print(json.dumps(compare(rollout, teacher), indent=2))
    if args.sheet:
        point_sheet(args.sheet, rollout["sampled_points"])


if __name__ == "__main__":
    main()
