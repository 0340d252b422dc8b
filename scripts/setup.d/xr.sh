#!/usr/bin/env bash
# XR client (issue 6): host packages for building the Monado test root and running the client's Vulkan side.
# The root itself (Debian trixie + Monado, about 1 GB) is built on demand by scripts/xr/make-root.sh.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
apt-get update -q
apt-get install -y -q --no-install-recommends debootstrap debian-archive-keyring util-linux mount \
    mesa-vulkan-drivers libvulkan1 vulkan-tools vulkan-validationlayers xvfb libxkbcommon-x11-0
