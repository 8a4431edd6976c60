#!/usr/bin/env bash
# The app as a person runs it, measured: the shipped Witch beside her teacher in a
# 1280x800 window under Xvfb, driven by a key script for SECONDS (default 90), with a
# camera drag every few seconds sent by xdotool so that the app can time input to the
# drawn frame. Prints the app's final line (generated_fps=, window_fps=,
# input_latency_ms=). Needs: Xvfb, xdotool (Debian: apt-get install xvfb xdotool), a
# built binary (cargo build --release).
#
#   scripts/live-window.sh [SECONDS] [extra unica options...]
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-90}"
shift || true
binary=target/release/unica
[ -x "$binary" ] || { echo "live-window.sh: $binary is missing: run cargo build --release" >&2; exit 1; }
command -v Xvfb >/dev/null || { echo "live-window.sh: Xvfb is missing (apt-get install xvfb)" >&2; exit 1; }
command -v xdotool >/dev/null || { echo "live-window.sh: xdotool is missing (apt-get install xdotool)" >&2; exit 1; }
display=":$((90 + RANDOM % 100))"
Xvfb "$display" -screen 0 1280x800x24 -nolisten tcp >/dev/null 2>&1 &
xvfb=$!
trap 'kill $xvfb 2>/dev/null || true' EXIT
sleep 1
export DISPLAY="$display"
"$binary" --keys "30I 600W 300D 300I" --exit-after-seconds "$seconds" "$@" &
app=$!
# Camera drags over the viewport (left part of the window), one every 4 s after the
# window has had 10 s to open.
(
    sleep 10
    while kill -0 $app 2>/dev/null; do
        xdotool mousemove 400 400 mousedown 1 2>/dev/null || true
        for x in 420 440 460 480; do
            xdotool mousemove "$x" 400 2>/dev/null || true
            sleep 0.05
        done
        xdotool mouseup 1 2>/dev/null || true
        sleep 4
    done
) &
wait $app
