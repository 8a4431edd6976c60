#!/usr/bin/env bash
# The README's clip, made by the app's own recorder: the shipped Witch beside her teacher
# in a 1280x800 window under Xvfb, driven by the key script W, D, S and a stop, recorded
# (--record) for SECONDS (default 300). The recorder samples the window in wall time;
# the clip keeps one picture per avatar root the recorder saw, one per generated frame
# (the recorder writes the root beside each picture), up to the key script's length
# (the app goes on generating Idle frames after it), and plays them
# at FPS (default 15: half the avatar's data rate of 30 frames a second, so the clip runs
# at half speed whatever the machine's own rate was). Writes an animated WebP.
# Needs: Xvfb, img2webp (Debian: apt-get install xvfb webp), python3 with Pillow, a
# built binary (cargo build --release).
#
#   scripts/readme-clip.sh OUT.webp [SECONDS] [FPS]
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:?usage: scripts/readme-clip.sh OUT.webp [SECONDS] [FPS]}"
seconds="${2:-300}"
fps="${3:-15}"
keys="20W 20D 20S 40I"
binary=target/release/unica
[ -x "$binary" ] || { echo "readme-clip.sh: $binary is missing: run cargo build --release" >&2; exit 1; }
command -v Xvfb >/dev/null || { echo "readme-clip.sh: Xvfb is missing (apt-get install xvfb)" >&2; exit 1; }
command -v img2webp >/dev/null || { echo "readme-clip.sh: img2webp is missing (apt-get install webp)" >&2; exit 1; }
work=$(mktemp -d)
display=":$((90 + RANDOM % 100))"
Xvfb "$display" -screen 0 1280x800x24 -nolisten tcp >/dev/null 2>&1 &
xvfb=$!
trap 'kill $xvfb 2>/dev/null || true; rm -rf "$work"' EXIT
sleep 1
DISPLAY="$display" "$binary" --keys "$keys" --record --record-fps 2 --record-dir "$work/rec" \
    --exit-after-seconds "$seconds"
# One picture per generated frame: the viewport's right 70 % (the camera follows the
# neural avatar, drawn right of her teacher), 560 pixels wide.
python3 - "$work" "$keys" <<'PY'
import json, sys
from pathlib import Path
from PIL import Image

work = Path(sys.argv[1])
# The app goes on generating Idle frames after the script: the clip ends with it.
script_frames = sum(int(token[:-1]) for token in sys.argv[2].split())
manifest = json.loads((work / "rec/manifest.json").read_text())
# The recorded frames in runs of the same avatar root: a run is one generated frame
# (while the camera follows, the window first draws a run's picture at a quarter of the
# size, then at full size: the run's last picture is the full one).
runs = []
for frame in manifest["frames"]:
    if runs and runs[-1][0] == frame["root"]:
        runs[-1][1] = frame["file"]
    else:
        runs.append([frame["root"], frame["file"]])
runs = runs[:script_frames]
size = None
for k, (_, file) in enumerate(runs):
    image = Image.open(work / "rec" / file).convert("RGB")
    w, h = image.size
    crop = image.crop((int(0.3 * w), int(0.08 * h), w, int(0.92 * h)))
    size = size or (560, round(560 * crop.height / crop.width))
    crop.resize(size, Image.LANCZOS).save(work / f"clip_{k:04d}.png")
print(f"readme-clip.sh: {len(runs)} pictures (one per avatar root, at most the script's {script_frames}) "
      f"of {len(manifest['frames'])} recorded")
PY
frames=("$work"/clip_*.png)
img2webp -loop 0 -lossy -q 50 -m 6 -d "$((1000 / fps))" "${frames[@]}" -o "$out" >/dev/null
echo "readme-clip.sh: wrote $out ($(du -k "$out" | cut -f1) KB, ${#frames[@]} frames at $fps fps)"
