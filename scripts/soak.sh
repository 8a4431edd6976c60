#!/usr/bin/env bash
# A long session (issue #51): the app on the shipped Witch under Xvfb with the model
# running, a key script that keeps her moving, and a recording on, for SECONDS (default
# 1800). Samples the process's resident memory every 10 s into OUT/memory.csv (on a CPU
# driver such as lavapipe, GPU memory is process memory too), and keeps the app's final
# line and the recording's manifest in OUT.
#   scripts/soak.sh OUT [SECONDS]
set -euo pipefail
out=${1:?usage: scripts/soak.sh OUT [SECONDS]}
seconds=${2:-1800}
mkdir -p "$out"
unica=${UNICA:-target/release/unica}
keys=$(for _ in $(seq 40); do printf '60W 40A 60W 40D 30S 30I '; done)
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp}
xvfb-run -a -s "-screen 0 1280x800x24" "$unica" --keys "$keys" \
    --exit-after-seconds "$seconds" --record --record-fps 1 --record-dir "$out/rec" \
    > "$out/app.log" 2>&1 &
runner=$!
echo "seconds,rss_kb" > "$out/memory.csv"
start=$(date +%s)
pid=""
while kill -0 "$runner" 2>/dev/null; do
    [ -z "$pid" ] && pid=$(pgrep -n -x "$(basename "$unica")" || true)
    if [ -n "$pid" ] && [ -r "/proc/$pid/status" ]; then
        rss=$(awk '/^VmRSS/ {print $2}' "/proc/$pid/status")
        echo "$(( $(date +%s) - start )),$rss" >> "$out/memory.csv"
    fi
    sleep 10
done
wait "$runner"
echo "exit $?" >> "$out/app.log"
