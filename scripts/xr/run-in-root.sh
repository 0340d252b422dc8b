#!/usr/bin/env bash
# Runs one command inside the XR test root (see make-root.sh) next to a headless Monado OpenXR runtime.
#
# Usage: scripts/xr/run-in-root.sh [--root ROOT] [--xvfb] [--no-runtime] [--] CMD [ARGS...]
#   --root ROOT    the root built by make-root.sh (default: <checkout>/.tools/xr-root, or $R2HUMAN_XR_ROOT)
#   --xvfb         start Xvfb :99 inside the root and run Monado's XCB compositor on it (about 55 Hz, unthrottled
#                  by the null compositor's 20 Hz) instead of the null compositor; CMD gets DISPLAY=:99
#   --no-runtime   do not start Monado (CMD sees no runtime: for the "no runtime" paths)
# Can also serve as CARGO_TARGET_X86_64_UNKNOWN_LINUX_GNU_RUNNER (CMD is then the test binary).
#
# The checkout is bind-mounted at the same path inside the root, so CMD and the working directory keep their paths.
# Monado gets its own XDG_RUNTIME_DIR, shared with CMD. Whatever happens, Monado (and Xvfb) are stopped by PID and
# everything mounted here is unmounted again (trap). The exit status is CMD's. Runs are serialised by a lock file.
# Environment passed through to CMD: RUST_LOG RUST_BACKTRACE XR_ENABLE_API_LAYERS VK_INSTANCE_LAYERS
# VK_LOADER_DEBUG XR_LOADER_DEBUG MESA_VK_ENABLE_SUBMIT_THREAD LP_NUM_THREADS and every R2HUMAN_* variable; CMD also
# gets R2HUMAN_XR_IN_ROOT=1 and R2HUMAN_XR_RUNTIME_PID (Monado's PID, empty with --no-runtime).
set -euo pipefail
HERE=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
source "$HERE/lib.sh"
CHECKOUT=$(cd "$HERE/../.." && pwd)

ROOT=${R2HUMAN_XR_ROOT:-$(xr_default_root)}
XVFB=0
RUNTIME=1
while [ $# -gt 0 ]; do
    case "$1" in
        --root) ROOT=$2; shift 2 ;;
        --xvfb) XVFB=1; shift ;;
        --no-runtime) RUNTIME=0; shift ;;
        --) shift; break ;;
        *) break ;;
    esac
done
if [ $# -eq 0 ]; then
    echo "usage: run-in-root.sh [--root ROOT] [--xvfb] [--no-runtime] [--] CMD [ARGS...]" >&2
    exit 2
fi
if [ "$(id -u)" != 0 ]; then
    echo "run-in-root.sh: needs root (mount, chroot)" >&2
    exit 2
fi
if [ ! -f "$ROOT/.r2human-xr-root" ]; then
    echo "run-in-root.sh: $ROOT is not a finished XR root: run scripts/xr/make-root.sh first" >&2
    exit 2
fi
ROOT=$(cd "$ROOT" && pwd -P)

exec 9>"$ROOT.lock"
flock 9

XDG_DIR=/tmp/r2human-xdg-$$
MONADO_PID=""
XVFB_PID=""
cleanup() {
    local status=$?
    for pid in $MONADO_PID $XVFB_PID; do
        if kill -0 "$pid" 2>/dev/null; then
            kill -TERM "$pid" 2>/dev/null || true
            for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
            kill -KILL "$pid" 2>/dev/null || true
        fi
    done
    wait 2>/dev/null || true
    rm -rf "${ROOT:?}$XDG_DIR"
    xr_unmount_all "$ROOT"
    exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

xr_mount_system "$ROOT"
mkdir -p "$ROOT$CHECKOUT"
mountpoint -q "$ROOT$CHECKOUT" || mount --bind "$CHECKOUT" "$ROOT$CHECKOUT"
# A git worktree may link its .tools to another checkout's; the root only sees what is mounted into it.
if [ -L "$CHECKOUT/.tools" ]; then
    TOOLS_TARGET=$(readlink -f "$CHECKOUT/.tools")
    mkdir -p "$ROOT$TOOLS_TARGET"
    mountpoint -q "$ROOT$TOOLS_TARGET" || mount --bind "$TOOLS_TARGET" "$ROOT$TOOLS_TARGET"
fi
# Cargo's home (for `cargo run`-style paths) is not needed: binaries are run directly.
mkdir -p "$ROOT$XDG_DIR" "$ROOT/tmp"
chmod 700 "$ROOT$XDG_DIR"
chmod 1777 "$ROOT/tmp"

BASE_ENV=(PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root XDG_RUNTIME_DIR="$XDG_DIR")
LOG_DIR=${R2HUMAN_XR_LOG_DIR:-$CHECKOUT/.tools/xr-logs}
mkdir -p "$LOG_DIR"

if [ "$XVFB" = 1 ]; then
    chroot "$ROOT" env -i "${BASE_ENV[@]}" Xvfb :99 -screen 0 2560x1440x24 -nolisten tcp \
        >"$LOG_DIR/xvfb.log" 2>&1 &
    XVFB_PID=$!
    for _ in $(seq 100); do [ -e "$ROOT/tmp/.X11-unix/X99" ] && break; sleep 0.05; done
fi

if [ "$RUNTIME" = 1 ]; then
    if [ "$XVFB" = 1 ]; then
        COMP_ENV=(DISPLAY=:99 XRT_COMPOSITOR_FORCE_XCB=1)
    else
        COMP_ENV=(XRT_COMPOSITOR_NULL=1)
    fi
    chroot "$ROOT" env -i "${BASE_ENV[@]}" "${COMP_ENV[@]}" SIMULATED_ENABLE=1 XRT_NO_STDIN=1 \
        monado-service >"$LOG_DIR/monado.log" 2>&1 &
    MONADO_PID=$!
    for _ in $(seq 600); do
        [ -S "$ROOT$XDG_DIR/monado_comp_ipc" ] && break
        if ! kill -0 "$MONADO_PID" 2>/dev/null; then
            echo "run-in-root.sh: monado-service exited early; see $LOG_DIR/monado.log" >&2
            exit 3
        fi
        sleep 0.05
    done
    if [ ! -S "$ROOT$XDG_DIR/monado_comp_ipc" ]; then
        echo "run-in-root.sh: monado-service did not create its socket within 30 s; see $LOG_DIR/monado.log" >&2
        exit 3
    fi
fi

PASS_ENV=(R2HUMAN_XR_IN_ROOT=1 R2HUMAN_XR_RUNTIME_PID="$MONADO_PID")
[ "$XVFB" = 1 ] && PASS_ENV+=(DISPLAY=:99)
for name in RUST_LOG RUST_BACKTRACE XR_ENABLE_API_LAYERS VK_INSTANCE_LAYERS VK_LOADER_DEBUG XR_LOADER_DEBUG \
    MESA_VK_ENABLE_SUBMIT_THREAD LP_NUM_THREADS; do
    [ -n "${!name:-}" ] && PASS_ENV+=("$name=${!name}")
done
while IFS='=' read -r name _; do
    case "$name" in R2HUMAN_XR_IN_ROOT|R2HUMAN_XR_RUNTIME_PID) ;; R2HUMAN_*) PASS_ENV+=("$name=${!name}") ;; esac
done < <(env)

set +e
chroot "$ROOT" env -i "${BASE_ENV[@]}" "${PASS_ENV[@]}" R2HUMAN_XR_CWD="$PWD" \
    sh -c 'cd "$R2HUMAN_XR_CWD" && exec "$@"' sh "$@"
STATUS=$?
set -e
exit "$STATUS"
