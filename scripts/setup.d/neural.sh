#!/usr/bin/env bash
# Neural renderer runtime: ONNX Runtime 1.31.1 (CPU build) from its PyPI wheel, unpacked into the project's
# git-ignored `.tools/onnxruntime`. The Rust side (`ort` with load-dynamic) finds
#   .tools/onnxruntime/onnxruntime/capi/libonnxruntime.so.1.31.1
# by itself; `ORT_DYLIB_PATH` overrides it (GPU users: point it at the library of `onnxruntime-gpu` 1.31.1).
# Idempotent, non-interactive. Training needs PyTorch: that is the separate, opt-in scripts/setup-train.sh.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
DEST="$ROOT/.tools/onnxruntime"
LIB="$DEST/onnxruntime/capi/libonnxruntime.so.1.31.1"
if [ ! -f "$LIB" ]; then
    if ! command -v python3 >/dev/null 2>&1; then
        apt-get update
        apt-get install -y --no-install-recommends python3 python3-pip
    fi
    # --no-deps: only the shared library is needed, not the Python bindings' dependencies.
    python3 -m pip install --no-deps --no-input --disable-pip-version-check --upgrade \
        --target "$DEST" "onnxruntime==1.31.1"
fi
if [ ! -f "$LIB" ]; then
    echo "neural.sh: the onnxruntime 1.31.1 wheel did not contain $LIB" >&2
    exit 1
fi
echo "$LIB" > "$ROOT/.tools/onnxruntime/ORT_DYLIB_PATH"
echo "ONNX Runtime: $LIB (export ORT_DYLIB_PATH=$LIB to use it from elsewhere)"
