#!/usr/bin/env bash
# Vulkan runtime for the GPU path and the mirror window: Mesa's lavapipe (software Vulkan), the loader,
# vulkaninfo, the Khronos validation layers (tests run with them on) and Xvfb (window tests under CI).
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
apt-get update
apt-get install -y --no-install-recommends mesa-vulkan-drivers vulkan-tools vulkan-validationlayers xvfb libvulkan1
