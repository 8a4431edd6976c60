"""Walk, turn and stop numbers from a `unica render` manifest (world root per frame), as
docs/make.md uses them: `python3 docs/make_motion.py DIR/manifest.json …`."""
import json, math, sys

def load(path):
    m = json.load(open(path))
    frames = m["frames"]
    roots = [f["root"] for f in frames]
    actions = [f.get("action") for f in frames]
    return roots, actions

def speed(roots, i, fps=30.0):
    a, b = roots[i - 1], roots[i]
    return math.hypot(b[0] - a[0], b[2] - a[2]) * fps

def heading(roots, i, span=3):
    a, b = roots[i - span], roots[i]
    return math.degrees(math.atan2(b[0] - a[0], b[2] - a[2]))

def segments(actions):
    out, start = [], 0
    for i in range(1, len(actions) + 1):
        if i == len(actions) or actions[i] != actions[start]:
            out.append((actions[start], start, i))
            start = i
    return out

def summary(path):
    roots, actions = load(path)
    segs = segments(actions)
    res = {}
    for key, s, e in segs:
        tail = range(max(s + 1, e - 15), e)
        res.setdefault("segments", []).append({
            "key": key, "frames": e - s,
            "speed_last15": sum(speed(roots, i) for i in tail) / len(tail),
            "heading_end": heading(roots, e - 1) if e - s > 4 else None})
    # turn: frames after the second movement key starts until the motion heading is within 10 degrees of its end heading
    moves = [(k, s, e) for k, s, e in segs if k != "Idle"]
    if len(moves) >= 2:
        _, s, e = moves[1]
        target = heading(roots, e - 1)
        res["turn_frames"] = next((i - s for i in range(s + 3, e)
                                  if abs((heading(roots, i) - target + 180) % 360 - 180) < 10), None)
    # stop: after the last idle starts, frames until the speed stays below 0.05 m/s, and the slide
    k, s, e = segs[-1]
    stop = next((i - s for i in range(s + 1, e) if all(speed(roots, j) < 0.05 for j in range(i, e))), None)
    res["stop_frames"] = stop
    res["slide_m"] = math.hypot(roots[e - 1][0] - roots[s][0], roots[e - 1][2] - roots[s][2])
    res["speed_10_after_release"] = speed(roots, min(s + 10, e - 1))
    return res

for p in sys.argv[1:]:
    print(p, json.dumps(summary(p), indent=1))
