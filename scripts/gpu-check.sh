#!/usr/bin/env bash
# One command for a machine with an NVIDIA GPU: the measurements the README lacks, as one Markdown table
# (OUT/results.md) plus every raw log (OUT/*.log), in under 8 minutes. On a machine without a GPU it still runs to
# the end: the GPU rows say "no GPU" (with the doctor's reason) and the CPU rows are measured.
#
# Rows:
#   - doctor: what the machine offers and what `auto` takes (r2human doctor);
#   - Vulkan per eye at 1832x1920 and 2064x2208 (Quest-2/3-class eyes): `render --backend vulkan` on a square of the
#     eye's larger side (1920, 2208: 5-7% more pixels than the eye), per view = (time of N+1 views - time of 1)/N,
#     which includes writing each view's PNG; the CPU reference at the same sizes for comparison;
#   - neural decoder per eye on TensorRT / CUDA / CPU: the same orbit with `--renderer neural --ep EP` minus the
#     geometric one (the decoder and the packing of its inputs); TensorRT's first run builds its engine into
#     .tools/tensorrt-cache (the log's "TensorRT session ... ready in" lines give the build time), the second
#     run loads it;
#   - live benchmark: `r2human bench-live` on R2HUMAN_GPU_CHECK_CLIP (default: the four photos of assets/photos;
#     a row says so when the command is missing);
#   - XR: a session against Monado (scripts/xr/run-in-root.sh) with the eye size capped at 2208, its report.
# Usage: bash scripts/gpu-check.sh [OUT]   (default out/gpu-check; R2HUMAN_BIN=path uses that binary)
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
OUT="${1:-out/gpu-check}"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
START=$(date +%s)
BUDGET=${R2HUMAN_GPU_CHECK_SECONDS:-450}
IMG="$ROOT/assets/demo/person.png"
# The live benchmark's clip: R2HUMAN_GPU_CHECK_CLIP (a video file or a folder of frames), else the four photos.
CLIP="${R2HUMAN_GPU_CHECK_CLIP:-$ROOT/assets/photos}"
ROWS=()
row() { ROWS+=("| $1 | $2 | $3 | $4 |"); echo "gpu-check: $1 | $2 | $3 | $4"; }
left() { echo $(( BUDGET - ($(date +%s) - START) )); }

# The binary: R2HUMAN_BIN, else a release build (cargo reuses an up-to-date one).
BIN="${R2HUMAN_BIN:-$ROOT/target/release/r2human}"
if [ -z "${R2HUMAN_BIN:-}" ]; then
    if ! cargo build --release --bin r2human >"$OUT/build.log" 2>&1; then
        echo "gpu-check: cargo build --release failed (see $OUT/build.log); using the existing $BIN" >&2
    fi
fi
[ -x "$BIN" ] || { echo "gpu-check: no r2human binary at $BIN (cargo build --release)" >&2; exit 1; }
"$BIN" help doctor >/dev/null 2>&1 || { echo "gpu-check: $BIN has no doctor command: rebuild it" >&2; exit 1; }

# 1. Doctor.
timeout 120 "$BIN" doctor >"$OUT/doctor.log" 2>"$OUT/doctor.err.log"
DEVICE=$(sed -n 's/^  r2human uses: //p' "$OUT/doctor.log")
AUTO_EP=$(sed -n 's/^  --ep auto: //p' "$OUT/doctor.log")
TRT_STATUS=$(sed -n 's/^  TensorRT: *//p' "$OUT/doctor.log" | sed 's/ ([0-9.]* s)$//')
CUDA_STATUS=$(sed -n 's/^  CUDA: *//p' "$OUT/doctor.log" | sed 's/ ([0-9.]* s)$//')
GPU=0
if [ -e /dev/nvidia0 ] || nvidia-smi -L >/dev/null 2>&1; then GPU=1; nvidia-smi -L >"$OUT/nvidia-smi.log" 2>&1; fi
VK_GPU=0
grep -q "r2human uses" "$OUT/doctor.log" && ! grep -q "^  view --backend auto: Cpu" "$OUT/doctor.log" && VK_GPU=1
row "doctor" "Vulkan: ${DEVICE:-none}; --ep auto: ${AUTO_EP:-?}" "NVIDIA GPU: $([ $GPU = 1 ] && echo yes || echo no)" "doctor.log"

# Time of `render --orbit N` in seconds (wall clock), or empty on failure; log in $OUT/$1.log.
orbit_time() {
    local name=$1 views=$2; shift 2
    local t0 t1
    t0=$(date +%s.%N)
    if R2HUMAN_LOG=info timeout 150 "$BIN" render --image "$IMG" --orbit "$views" --out "$OUT/views/$name" "$@" \
        >"$OUT/$name.log" 2>&1; then
        t1=$(date +%s.%N)
        echo "$t1 - $t0" | bc -l
    fi
}
# Per-view milliseconds: (T(n+1 views) - T(1 view)) / n.
per_view() {
    local name=$1 n=$2; shift 2
    local one many
    one=$(orbit_time "$name-1" 1 "$@") || true
    many=$(orbit_time "$name-$((n + 1))" "$((n + 1))" "$@") || true
    if [ -n "$one" ] && [ -n "$many" ]; then printf '%.0f' "$(echo "($many - $one) * 1000 / $n" | bc -l)"; fi
}
cell() { if [ -n "$1" ]; then echo "$1 ms"; else echo "failed (see $2)"; fi; }

# 2. Vulkan per eye, and the CPU reference at the same sizes.
for eye in 1832x1920 2064x2208; do
    side=${eye#*x}
    if [ "$VK_GPU" = 1 ]; then
        ms=$(per_view "vulkan-$side" 8 --size "$side" --backend vulkan --renderer geometric)
        row "Vulkan render per eye $eye (square $side)" "$(cell "$ms" "vulkan-$side-9.log")" "$DEVICE" "vulkan-$side-*.log"
    else
        row "Vulkan render per eye $eye (square $side)" "no GPU" "Vulkan device: ${DEVICE:-none} (software)" "doctor.log"
    fi
    if [ "$(left)" -gt 120 ]; then
        ms=$(per_view "cpu-$side" 2 --size "$side" --backend cpu --renderer geometric)
        row "CPU reference render per eye $eye (square $side)" "$(cell "$ms" "cpu-$side-3.log")" "$(nproc) cores" "cpu-$side-*.log"
    else
        row "CPU reference render per eye $eye (square $side)" "skipped: time budget" "" ""
    fi
done

# 3. Neural decoder per eye: neural minus geometric per view, on each provider.
side=1920
geo=""
if [ "$(left)" -gt 90 ]; then geo=$(per_view "geo-$side" 2 --size "$side" --backend cpu --renderer geometric); fi
for ep in tensorrt cuda cpu; do
    case $ep in
        tensorrt) status="$TRT_STATUS" ;;
        cuda) status="$CUDA_STATUS" ;;
        cpu) status="works" ;;
    esac
    if [ "$ep" != cpu ] && [ "$status" != works ]; then
        row "neural decoder per eye 1832x1920 on $ep" "no GPU" "$status" "doctor.log"
        continue
    fi
    if [ "$(left)" -lt 60 ] || [ -z "$geo" ]; then
        row "neural decoder per eye 1832x1920 on $ep" "skipped: time budget" "" ""
        continue
    fi
    backend=cpu; [ "$ep" != cpu ] && [ "$VK_GPU" = 1 ] && backend=vulkan
    if [ "$ep" = tensorrt ]; then
        # First run builds the engine (its log has the build time), the measured runs below load it.
        orbit_time "trt-warmup-$side" 1 --size "$side" --backend "$backend" --renderer neural --ep tensorrt >/dev/null
    fi
    neu=$(per_view "neural-$ep-$side" 2 --size "$side" --backend "$backend" --renderer neural --ep "$ep")
    ran=$(grep -h -o "decoder \`[^\`]*\` runs on [A-Za-z]*" "$OUT/neural-$ep-$side-1.log" 2>/dev/null | head -1 | sed 's/.* runs on //')
    if [ -n "$neu" ]; then
        row "neural decoder per eye 1832x1920 on $ep" "$(( neu - geo )) ms" "decoder ran on ${ran:-?}; neural $neu ms - geometric $geo ms per view" "neural-$ep-$side-*.log"
    else
        row "neural decoder per eye 1832x1920 on $ep" "failed (see neural-$ep-$side-3.log)" "" "neural-$ep-$side-*.log"
    fi
done
if ls "$OUT"/trt-warmup-*.log >/dev/null 2>&1; then
    build=$(grep -h "TensorRT session" "$OUT"/trt-warmup-*.log | head -3 | sed 's/.*TensorRT session/TensorRT session/' | tr '\n' ';')
    row "TensorRT engine build (first run)" "${build:-no TensorRT session line}" "cache: .tools/tensorrt-cache" "trt-warmup-*.log"
fi

# 4. Live benchmark.
if "$BIN" help bench-live >/dev/null 2>&1; then
    if [ "$(left)" -gt 60 ]; then
        timeout 90 "$BIN" bench-live --video "$CLIP" --fps 10 --seconds 20 >"$OUT/bench-live.log" 2>&1
        rc=$?
        summary=$(grep -E "^(frames:|latency |views:)" "$OUT/bench-live.log" | tr '\n' ' ')
        row "live benchmark (bench-live --video $(basename "$CLIP"))" "$([ $rc = 0 ] && echo "${summary:-see log}" || echo "failed (exit $rc)")" "$([ $GPU = 1 ] && echo GPU || echo "no GPU: CPU paths")" "bench-live.log"
    else
        row "live benchmark" "skipped: time budget" "" ""
    fi
else
    row "live benchmark" "not measured: this r2human has no bench-live command" "" ""
fi

# 5. XR session against Monado with the GPU.
if [ "$GPU" = 1 ] && [ "$(left)" -gt 90 ]; then
    if bash scripts/xr/make-root.sh >"$OUT/xr-root.log" 2>&1; then
        timeout 120 bash scripts/xr/run-in-root.sh --xvfb "$BIN" xr --image "$IMG" --frames 300 --eye-size 2208 \
            --no-mirror >"$OUT/xr.log" 2>&1
        rc=$?
        row "XR session (Monado, eye side <= 2208, 300 frames)" "$([ $rc = 0 ] && grep -v -E "INFO|WARN" "$OUT/xr.log" | head -3 | tr '\n' ' ' || echo "failed (exit $rc)")" "$DEVICE" "xr.log"
    else
        row "XR session (Monado)" "not run: the Monado root could not be built" "" "xr-root.log"
    fi
elif [ "$GPU" = 1 ]; then
    row "XR session (Monado)" "skipped: time budget" "" ""
else
    row "XR session (Monado) with the GPU" "no GPU" "Monado on lavapipe runs in scripts/test.sh" ""
fi

ELAPSED=$(( $(date +%s) - START ))
{
    echo "# gpu-check $(date -u +%Y-%m-%dT%H:%MZ) on $(hostname)"
    echo
    echo "Binary: $BIN; NVIDIA GPU: $([ $GPU = 1 ] && echo yes || echo no); Vulkan device: ${DEVICE:-none};" \
         "run time: ${ELAPSED} s. Per view = (N+1 views - 1 view)/N of \`render --orbit\`, PNG writing included."
    echo
    echo "| measurement | result | notes | log |"
    echo "|---|---|---|---|"
    printf '%s\n' "${ROWS[@]}"
} >"$OUT/results.md"
echo "gpu-check: done in ${ELAPSED} s: $OUT/results.md"
