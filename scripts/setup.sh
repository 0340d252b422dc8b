#!/usr/bin/env bash
# Installs everything r2human needs on a fresh Debian/Ubuntu machine (idempotent, non-interactive, as root or
# with sudo). Each layer adds its own needs in scripts/setup.d/*.sh, which this script runs in order.
# `--gpu` also installs ONNX Runtime's GPU build with its CUDA / cuDNN / TensorRT libraries (scripts/setup-gpu.sh,
# about 2.4 GB in .tools/onnxruntime-gpu); without it nothing GPU-specific is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
GPU=0
for arg in "$@"; do
  case "$arg" in
    --gpu) GPU=1 ;;
    *) echo "setup: unknown option $arg (the only option is --gpu)" >&2; exit 2 ;;
  esac
done

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive

# Build tools and libraries for the Rust dependencies: nokhwa's V4L2 bindings need libclang; ash loads
# libvulkan; lavapipe (mesa-vulkan-drivers) gives a software Vulkan device where no GPU exists.
need=()
for pkg in build-essential pkg-config libclang-dev cmake libvulkan1 libvulkan-dev mesa-vulkan-drivers \
           vulkan-tools vulkan-validationlayers libv4l-dev libudev-dev xvfb libx11-dev libxkbcommon-dev \
           libxcursor1 libxrandr2 libxi6 python3 python3-venv curl ca-certificates; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
if [ "${#need[@]}" -gt 0 ]; then
  echo "setup: installing ${need[*]}"
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo is missing. Install Rust (https://rustup.rs, or your distribution's rustup package) and run this again." >&2
  exit 1
fi

for part in scripts/setup.d/*.sh; do
  [ -e "$part" ] || continue
  echo "setup: $part"
  bash "$part"
done
if [ "$GPU" = 1 ]; then
  echo "setup: scripts/setup-gpu.sh"
  bash scripts/setup-gpu.sh
fi
echo "setup: done"
