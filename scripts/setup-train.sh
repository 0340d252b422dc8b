#!/usr/bin/env bash
# Opt-in training environment (not run by scripts/setup.sh): a Python venv in `.venv` (git-ignored) with
# PyTorch 2.15.0, onnx, onnxscript, onnxruntime 1.31.1 (export check), numpy and Pillow.
# PyPI's torch 2.15.0 for x86_64 Linux is a CUDA build: it pulls its nvidia-* libraries even on a CPU-only
# machine (about 5.4 GB, 1.5 minutes here). Idempotent, non-interactive.
# Usage: bash scripts/setup-train.sh   then   .venv/bin/python -m train --help
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
if ! python3 -c 'import venv, ensurepip' >/dev/null 2>&1; then
    apt-get update
    apt-get install -y --no-install-recommends python3 python3-venv python3-pip
fi
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/python" -m pip install --no-input --disable-pip-version-check \
    "torch==2.15.0" "onnx" "onnxscript" "onnxruntime==1.31.1" "numpy" "pillow"
"$VENV/bin/python" -c 'import torch, onnx, onnxruntime; print("torch", torch.__version__, "onnx", onnx.__version__, "onnxruntime", onnxruntime.__version__)'
