#!/usr/bin/env bash
# A full-size `unica make` killed part-way (issue #51): runs `unica make CHARACTER --out
# OUT` and kills the make alone with SIGKILL at KILLS moments drawn from SEED over the
# first SPAN seconds of wall-clock time (its trainers die with it), checks that no process
# naming OUT is left, starts the same command again each time, and lets the last run
# finish. Then checks the end: every stage done, a bundle the engine plays, no staging
# file left. Everything goes to OUT.log (the make's output) and OUT.kills (one line a
# kill: the moment, the stage and the last progress line before it).
#   scripts/make-kill.sh CHARACTER OUT [KILLS] [SPAN] [SEED]
# Run it with `nice -n 19` beside other work. UNICA (the binary) and UNICA_PYTHON are
# passed on to the make.
set -uo pipefail
character=${1:?usage: scripts/make-kill.sh CHARACTER OUT [KILLS] [SPAN] [SEED]}
out=${2:?usage: scripts/make-kill.sh CHARACTER OUT [KILLS] [SPAN] [SEED]}
kills=${3:-3}
span=${4:-7200}
seed=${5:-51}
unica=${UNICA:-target/release/unica}
log="$out.log"
record="$out.kills"
moments=$(python3 -c "import random; r = random.Random($seed); print(' '.join(str(round(m)) for m in sorted(r.uniform(60, $span) for _ in range($kills))))")
echo "$(date -u +%FT%TZ) start: kills at ${moments} s" >> "$record"
start=$(date +%s)

left_behind() {  # processes that name OUT, other than this script and its subshells
    python3 -c '
import os, sys
for pid in filter(str.isdigit, os.listdir("/proc")):
    try:
        line = open(f"/proc/{pid}/cmdline", "rb").read().replace(b"\0", b" ").decode()
    except OSError:
        continue
    if sys.argv[1] in line and "make-kill.sh" not in line and int(pid) != os.getpid():
        print(pid, line[:120])
' "$out"
}

for moment in $moments; do
    "$unica" make "$character" --out "$out" >> "$log" 2>&1 &
    make=$!
    while kill -0 "$make" 2>/dev/null && [ $(( $(date +%s) - start )) -lt "$moment" ]; do
        sleep 1
    done
    if ! kill -0 "$make" 2>/dev/null; then
        wait "$make"
        echo "$(date -u +%FT%TZ) the make ended (exit $?) before the kill at ${moment} s" >> "$record"
        break
    fi
    kill -KILL "$make"
    wait "$make" 2>/dev/null
    sleep 10
    left=$(left_behind)
    stage=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['done'])" "$out/make.json" 2>/dev/null || echo "[]")
    last=$(tr '\r' '\n' < "$log" | grep -v '^$' | tail -1 | cut -c1-160)
    echo "$(date -u +%FT%TZ) killed at ${moment} s; done before it: ${stage}; last line: ${last}; left running: ${left:-none}" >> "$record"
done

"$unica" make "$character" --out "$out" >> "$log" 2>&1
status=$?
echo "$(date -u +%FT%TZ) the last run ended with exit ${status} after $(( $(date +%s) - start )) s" >> "$record"
[ "$status" -eq 0 ] || exit "$status"
staging=$(find "$out" -name '*.tmp' -o -name '*.new' -o -name '*.old' | head -5)
"$unica" render --bundle "$out/bundle" --keys 3W --out "$out.check" --size 32 --views 1 >> "$log" 2>&1
played=$?
echo "$(date -u +%FT%TZ) make.json done: $(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['done'])" "$out/make.json"); the bundle plays 3 W frames: exit ${played}; staging files left: ${staging:-none}" >> "$record"
