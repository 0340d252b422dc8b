#!/usr/bin/env bash
# Soak runs (issue 16): the desktop window under Xvfb and the OpenXR session against Monado, each for N frames
# with the live synthetic source, Vulkan (and OpenXR) validation on. Resident memory is sampled every second, and
# the process logs its C heap (bytes malloc has handed out and holds: R2HUMAN_HEAP_LOG) every second;
# examples/soak_report.rs summarises each run (NAME_summary.txt/.json): the memory slopes (least squares after a
# 10 % warm-up, MiB/hour and MiB per 1000 frames, for resident memory and for the heap in use), the validation
# message count (must be 0), whether the run ended as asked (exit status 0, the XR session on its frame budget:
# not dropped) and the display loop's frame-time histogram (CSV and PNG). The script exits non-zero when a run was
# dropped or validation spoke.
#
# Usage: scripts/soak.sh [--frames N] [--view-only | --xr-only] [--faults] [--person-model] [--release] [--out DIR]
#   --frames N   frames per run (default 10000: about 10-20 minutes on this 2-core machine)
#   --faults     the source stalls, vanishes and changes resolution every 12 s (synthetic:…+faults)
#   --person-model  keep the person model across the frames (view and xr --person-model)
#   --release    build and run the release profile (default: dev)
#   --out DIR    where the logs and summaries go (default target/soak)
# The XR run needs root and the Monado root of scripts/xr/make-root.sh (skipped with a message otherwise).
set -euo pipefail
cd "$(dirname "$0")/.."
FRAMES=10000
RUN_VIEW=1
RUN_XR=1
SOURCE="synthetic:320x240@30"
PROFILE=debug
CARGO_PROFILE=()
OUT=target/soak
FAILED=0
EXTRA=()
while [ $# -gt 0 ]; do
    case "$1" in
        --frames) FRAMES=$2; shift 2 ;;
        --view-only) RUN_XR=0; shift ;;
        --xr-only) RUN_VIEW=0; shift ;;
        --faults) SOURCE="synthetic:320x240@30+faults"; shift ;;
        --person-model) EXTRA+=(--person-model); shift ;;
        --release) PROFILE=release; CARGO_PROFILE=(--release); shift ;;
        --out) OUT=$2; shift 2 ;;
        *) echo "unknown option $1 (see the header of $0)" >&2; exit 2 ;;
    esac
done
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
cargo build "${CARGO_PROFILE[@]}" --bin r2human --example soak_report
BIN=$PWD/target/$PROFILE/r2human
REPORT=$PWD/target/$PROFILE/examples/soak_report
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"

# Samples the resident memory of PID every second into FILE until the process exits: seconds, VmRSS and its
# parts (RssAnon: heap and anonymous maps; RssFile: mapped files; RssShmem: shared memory such as the memfd
# buffers a Vulkan driver shares with the compositor), all in KiB.
sample_rss() {
    local pid=$1 file=$2 t0
    t0=$(date +%s.%N)
    echo "seconds,rss_kib,anon_kib,file_kib,shmem_kib" > "$file"
    while kill -0 "$pid" 2>/dev/null; do
        local rss
        rss=$(awk '/^VmRSS:/ {r = $2} /^RssAnon:/ {a = $2} /^RssFile:/ {f = $2} /^RssShmem:/ {s = $2}
            END { if (r != "") print r "," a "," f "," s }' "/proc/$pid/status" 2>/dev/null || true)
        [ -n "$rss" ] && awk -v now="$(date +%s.%N)" -v t0="$t0" -v rss="$rss" \
            'BEGIN { printf "%.2f,%s\n", now - t0, rss }' >> "$file"
        sleep 1
    done
}

if [ "$RUN_VIEW" = 1 ]; then
    DISPLAY_NUM=$((200 + $$ % 300))
    Xvfb ":$DISPLAY_NUM" -screen 0 800x600x24 -nolisten tcp >/dev/null 2>&1 &
    XVFB_PID=$!
    trap 'kill "$XVFB_PID" 2>/dev/null || true' EXIT
    for _ in $(seq 100); do [ -e "/tmp/.X11-unix/X$DISPLAY_NUM" ] && break; sleep 0.05; done
    echo "soak: view, $FRAMES frames of $SOURCE under Xvfb :$DISPLAY_NUM (validation on)"
    DISPLAY=":$DISPLAY_NUM" R2HUMAN_VULKAN_VALIDATION=1 R2HUMAN_LOG=warn R2HUMAN_HEAP_LOG="$OUT/view_heap.csv" \
        "$BIN" view --video "$SOURCE" \
        --segment alpha --frames "$FRAMES" --size 256 --spin 0.5 --frame-log "$OUT/view_frames.csv" "${EXTRA[@]}" \
        > "$OUT/view.log" 2>&1 &
    VIEW_PID=$!
    sample_rss "$VIEW_PID" "$OUT/view_rss.csv" &
    SAMPLER=$!
    VIEW_STATUS=0
    wait "$VIEW_PID" || VIEW_STATUS=$?
    wait "$SAMPLER" || true
    kill "$XVFB_PID" 2>/dev/null || true
    trap - EXIT
    echo "exit status: $VIEW_STATUS" >> "$OUT/view.log"
    grep -E "^(view|frame times|live|exit status)" "$OUT/view.log" || true
    "$REPORT" "$OUT" view || FAILED=1
fi

if [ "$RUN_XR" = 1 ]; then
    if [ "$(id -u)" != 0 ] || [ ! -f .tools/xr-root/.r2human-xr-root ]; then
        echo "soak: XR skipped: needs root and the Monado root (bash scripts/xr/make-root.sh)"
    else
        echo "soak: xr, $FRAMES frames of $SOURCE against Monado (null compositor, OpenXR and Vulkan validation on)"
        # The XR process runs in the Monado root, which sees the checkout but not $OUT: its heap log goes to target/.
        HEAP_LOG=$PWD/target/soak-xr-heap.$$.csv
        XR_ENABLE_API_LAYERS=XR_APILAYER_LUNARG_core_validation VK_INSTANCE_LAYERS=VK_LAYER_KHRONOS_validation \
            R2HUMAN_LOG=warn R2HUMAN_HEAP_LOG="$HEAP_LOG" scripts/xr/run-in-root.sh "$BIN" xr --video "$SOURCE" --segment alpha \
            --frames "$FRAMES" --eye-size 192 --no-mirror "${EXTRA[@]}" > "$OUT/xr.log" 2>&1 &
        RUNNER=$!
        XR_PID=""
        for _ in $(seq 600); do
            XR_PID=$(pgrep -f -n "^$BIN xr --video" || true)
            [ -n "$XR_PID" ] && break
            kill -0 "$RUNNER" 2>/dev/null || break
            sleep 0.1
        done
        if [ -n "$XR_PID" ]; then
            sample_rss "$XR_PID" "$OUT/xr_rss.csv" &
            SAMPLER=$!
        fi
        XR_STATUS=0
        wait "$RUNNER" || XR_STATUS=$?
        [ -n "$XR_PID" ] && { wait "$SAMPLER" || true; }
        echo "exit status: $XR_STATUS" >> "$OUT/xr.log"
        [ -f "$HEAP_LOG" ] && mv "$HEAP_LOG" "$OUT/xr_heap.csv"
        grep -E "^(frames submitted|frame interval|validation messages|session ended|input frames|exit status)" \
            "$OUT/xr.log" || true
        if [ -n "$XR_PID" ]; then "$REPORT" "$OUT" xr || FAILED=1; else echo "soak: the xr process never started"; FAILED=1; fi
    fi
fi
exit "$FAILED"
