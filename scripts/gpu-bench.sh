#!/usr/bin/env bash
# Measures unica on this machine's GPU and writes the results to one folder, with a
# markdown summary (summary.md). No network and no build: it runs binaries built
# elsewhere.
#
# Needs:
#   - a Vulkan loader (libvulkan.so.1) and a GPU driver that wgpu can open;
#   - a built unica (cargo build --release), by default target/release/unica;
#   - for the parity tests, the prebuilt nn test binary
#     (cargo test --release --test nn --no-run prints its path), by default the newest
#     target/release/deps/nn-*; the repository (fixtures, bundle) is this script's.
#
# Usage: scripts/gpu-bench.sh [--unica BIN] [--nn-tests BIN] [--bundle DIR] [--out DIR]
#                             [--frames N] [--allow-cpu]
# --allow-cpu measures on a CPU driver too (to try the script; those are not GPU numbers).
# Records, each into OUT:
#   adapters.txt                 unica adapters
#   live_<kernels>_<sampler>_<level>.txt
#                                unica bench --live N (per-frame counts; per-stage and
#                                per-shader times, each submission waited for alone:
#                                wall clock, and the GPU's timestamps as gpu_ms) at the
#                                shipped one-pass
#                                default and at 1, 2 and 10 teacher steps, splat levels 256
#                                and 1024, with the GPU kernels; the shipped default and 10
#                                steps again with the CPU kernels (UNICA_KERNELS=cpu)
#   render.txt                   unica render --bundle: 300 frames at 512x512, one view
#   parity.txt                   the nn parity tests (every kernel variant) on this GPU
#   summary.md                   a table of the above
# Exits 2 with a message when there is no GPU adapter, 1 when a step fails (the other
# steps still run and the summary says which failed).
set -u -o pipefail

here=$(cd "$(dirname "$0")/.." && pwd)
unica="$here/target/release/unica"
nn_tests=""
bundle="$here/assets/witch/bundle"
out="$here/gpu-bench"
frames=100
allow_cpu=0

usage() { sed -n '2,/^set -u/p' "$0" | sed '$d; s/^# \{0,1\}//'; }
while [ $# -gt 0 ]; do
    case "$1" in
        --unica) unica="$2"; shift 2 ;;
        --nn-tests) nn_tests="$2"; shift 2 ;;
        --bundle) bundle="$2"; shift 2 ;;
        --out) out="$2"; shift 2 ;;
        --frames) frames="$2"; shift 2 ;;
        --allow-cpu) allow_cpu=1; shift ;;
        -h|--help) usage; exit 0 ;;
        *) echo "gpu-bench: unknown argument '$1' (see --help)" >&2; exit 2 ;;
    esac
done
if [ -z "$nn_tests" ]; then
    nn_tests=$(ls -t "$here"/target/release/deps/nn-* 2>/dev/null | grep -v '\.d$' | head -1)
fi
[ -x "$unica" ] || { echo "gpu-bench: $unica: no unica binary (cargo build --release, or --unica BIN)" >&2; exit 2; }
[ -f "$bundle/manifest.json" ] || { echo "gpu-bench: $bundle: no bundle (manifest.json missing)" >&2; exit 2; }
mkdir -p "$out" || exit 2
failed=()

# The adapter first: without a GPU there is nothing to measure.
if ! "$unica" adapters >"$out/adapters.txt" 2>&1; then
    echo "gpu-bench: unica adapters failed (is a Vulkan loader, libvulkan.so.1, installed?):" >&2
    cat "$out/adapters.txt" >&2
    exit 2
fi
cat "$out/adapters.txt"
used=$(grep '^\*' "$out/adapters.txt" | head -1)
case "$used" in
    *", Cpu"*) [ $allow_cpu = 1 ] || { echo "gpu-bench: no GPU adapter: unica would use '${used#\* }' (a CPU driver). Install the GPU's Vulkan driver, or pick one with WGPU_ADAPTER_NAME." >&2; exit 2; } ;;
    "") echo "gpu-bench: no GPU adapter: unica would use '${used#\* }' (a CPU driver). Install the GPU's Vulkan driver, or pick one with WGPU_ADAPTER_NAME." >&2; exit 2 ;;
esac
gpu_name=$(echo "$used" | sed 's/^\* //; s/ (.*//')

# One live bench: name, then the environment and arguments.
live() {
    local name=$1 kernels=$2; shift 2
    echo "== $name: UNICA_KERNELS=$kernels unica bench --bundle $bundle --live $frames $*"
    if ! UNICA_KERNELS=$kernels timeout 150 "$unica" bench --bundle "$bundle" --live "$frames" "$@" \
        >"$out/$name.txt" 2>&1; then
        failed+=("$name")
        tail -3 "$out/$name.txt"
    fi
    grep -h '^per generated frame' "$out/$name.txt"
}
for level in 1024 256; do
    live "live_gpu_default_$level" gpu --splat-level $level
    live "live_gpu_steps1_$level" gpu --steps 1 --splat-level $level
    live "live_gpu_steps2_$level" gpu --steps 2 --splat-level $level
    live "live_gpu_steps10_$level" gpu --steps 10 --splat-level $level
done
live live_cpu_default_1024 cpu --splat-level 1024
live live_cpu_steps10_1024 cpu --steps 10 --splat-level 1024

echo "== render: 300 frames at 512x512, one view"
render_dir=$(mktemp -d)
start=$(date +%s.%N)
if timeout 200 "$unica" render --bundle "$bundle" --keys "120W 60D 60W 60I" --size 512 --views 1 \
    --out "$render_dir" >"$out/render.txt" 2>&1; then
    end=$(date +%s.%N)
    pngs=$(find "$render_dir" -name '*.png' | wc -l)
    echo "render: $pngs images in $(awk "BEGIN { printf \"%.1f\", $end - $start }") s (wall, PNG writing included)" | tee -a "$out/render.txt"
else
    failed+=(render)
    tail -3 "$out/render.txt"
fi
rm -rf "$render_dir"

echo "== nn parity tests: $nn_tests"
if [ -x "$nn_tests" ]; then
    if ! UNICA_REPO="$here" timeout 240 "$nn_tests" --test-threads 4 >"$out/parity.txt" 2>&1; then
        failed+=(parity)
    fi
    grep -h '^test result' "$out/parity.txt"
else
    echo "no nn test binary (cargo test --release --test nn --no-run, or --nn-tests BIN)" | tee "$out/parity.txt"
    failed+=(parity)
fi

# The summary: one row per live bench, then the render and the tests.
field() { grep -h '^per generated frame' "$1" | grep -o " $2=[^ ]*" | cut -d= -f2; }
{
    echo "# GPU bench: $gpu_name"
    echo
    echo "$(date -u +%Y-%m-%d), \`scripts/gpu-bench.sh\`, $frames frames a row after a warm-up."
    echo
    echo '```'
    cat "$out/adapters.txt"
    echo '```'
    echo
    echo "| run | kernels | sampler | splat level | UNet passes | dispatches | GFLOP | wall ms | fps |"
    echo "| --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |"
    for f in "$out"/live_*.txt; do
        name=$(basename "$f" .txt)
        IFS=_ read -r _ kernels sampler level <<<"$name"
        gflop=$(grep -ho 'frame plan: .*GFLOP' "$f" | grep -o '[0-9.]* GFLOP' | cut -d' ' -f1)
        echo "| $name | $kernels | $sampler | $level | $(field "$f" unet_passes) | $(field "$f" dispatches) | ${gflop:-} | $(field "$f" wall_ms) | $(field "$f" fps) |"
    done
    echo
    echo "Per stage, each submitted and waited for alone (ms: wall clock, the submit and the wait included; gpu_ms: the GPU's timestamps):"
    echo
    for f in "$out"/live_gpu_default_1024.txt "$out"/live_gpu_steps10_1024.txt "$out"/live_cpu_default_1024.txt; do
        [ -f "$f" ] || continue
        echo "$(basename "$f" .txt):"
        echo '```'
        grep -h '^stage ' "$f"
        echo '```'
    done
    echo
    echo "Render: $(tail -1 "$out/render.txt")"
    echo
    echo "nn parity tests: $(grep -h '^test result' "$out/parity.txt" || tail -1 "$out/parity.txt")"
    echo
    if [ ${#failed[@]} -gt 0 ]; then echo "Failed: ${failed[*]}"; else echo "Every step ran."; fi
} >"$out/summary.md"
cat "$out/summary.md"
[ ${#failed[@]} -eq 0 ]
