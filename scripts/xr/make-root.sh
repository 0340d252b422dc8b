#!/usr/bin/env bash
# Builds (once) a Debian trixie root with the Monado OpenXR runtime, lavapipe and the validation layers, in which
# the OpenXR client is tested (Debian bookworm has no OpenXR runtime; Monado's client library needs trixie's glibc).
#
# Usage: scripts/xr/make-root.sh [ROOT]      (default ROOT: <checkout>/.tools/xr-root, git-ignored; about 1 GB)
# Needs root and network access to the Debian mirror (override with XR_ROOT_MIRROR). Idempotent: a finished root
# carries a stamp file and is left alone; an unfinished one is removed and rebuilt.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/lib.sh"

ROOT=${1:-$(xr_default_root)}
MIRROR=${XR_ROOT_MIRROR:-http://deb.debian.org/debian}
STAMP_CONTENT="r2human-xr-root v2"
PACKAGES="monado-service libopenxr1-monado libopenxr-loader1 libopenxr-utils mesa-vulkan-drivers
openxr-layer-corevalidation vulkan-validationlayers xvfb x11-apps netpbm libxkbcommon-x11-0"

if [ "$(id -u)" != 0 ]; then
    echo "make-root.sh: needs root (debootstrap, mount, chroot)" >&2
    exit 2
fi
mkdir -p "$(dirname "$ROOT")"
ROOT=$(cd "$(dirname "$ROOT")" && pwd -P)/$(basename "$ROOT")
STAMP="$ROOT/.r2human-xr-root"

if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$STAMP_CONTENT" ]; then
    echo "make-root.sh: $ROOT is ready"
    exit 0
fi
if ! command -v debootstrap >/dev/null; then
    echo "make-root.sh: debootstrap is missing: run scripts/setup.d/xr.sh (apt-get install debootstrap)" >&2
    exit 2
fi

xr_unmount_all "$ROOT"
trap 'xr_unmount_all "$ROOT"' EXIT

if [ ! -x "$ROOT/usr/bin/apt-get" ] || [ -d "$ROOT/debootstrap" ]; then
    # Missing or half-bootstrapped: start from scratch (all mounts below ROOT were removed above).
    if [ -n "$(xr_mounts_under "$ROOT")" ]; then
        echo "make-root.sh: refusing to delete $ROOT: something is still mounted below it" >&2
        exit 1
    fi
    rm -rf "$ROOT"
    echo "make-root.sh: debootstrap trixie into $ROOT (a few minutes)"
    debootstrap --variant=minbase trixie "$ROOT" "$MIRROR"
fi

# No services may start inside the root during package installation.
printf '#!/bin/sh\nexit 101\n' > "$ROOT/usr/sbin/policy-rc.d"
chmod +x "$ROOT/usr/sbin/policy-rc.d"
cp -L /etc/resolv.conf "$ROOT/etc/resolv.conf" 2>/dev/null || true
xr_mount_system "$ROOT"
# shellcheck disable=SC2086
chroot "$ROOT" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME=/root DEBIAN_FRONTEND=noninteractive \
    sh -c "apt-get update -q && apt-get install -y -q --no-install-recommends $(echo $PACKAGES) && apt-get clean"
chroot "$ROOT" test -e /usr/share/openxr/1/openxr_monado.json
echo "$STAMP_CONTENT" > "$STAMP"
echo "make-root.sh: $ROOT is ready"
