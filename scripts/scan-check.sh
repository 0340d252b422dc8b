#!/usr/bin/env bash
# Independent check of `r2human eval --scan` on real third-party characters (not MakeHuman, not made by this
# project), as a new user would bring them: Debian's `assimp-testmodels` (BSD-3-clause, the assimp test models)
# ships Mr. Fixit (IQM, a textured game character in T-pose, facing +x, with separate body and head textures);
# `assimp-utils`' `assimp export` turns it into formats r2human reads (OBJ+MTL with two JPEG textures, GLB with
# embedded textures), untouched otherwise: orientation, T-pose and materials are left to `eval --scan`. Writes OUT/<name>/report.md (and the scored views with --save-views).
#   bash scripts/scan-check.sh [OUT]          (default out/scan-check; about a minute per scan in a release build)
# Extra arguments for every eval go in R2HUMAN_SCAN_ARGS (e.g. "--no-neural --size 256").
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$REPO/out/scan-check}"
MODELS=/usr/share/assimp/models
if [ ! -d "$MODELS/IQM" ] || ! command -v assimp >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  apt-get install -y --no-install-recommends assimp-testmodels assimp-utils
fi
cd "$REPO"
cargo build --release --quiet
WORK="$OUT/files"
mkdir -p "$WORK"
cp "$MODELS/IQM/mrfixit.iqm" "$MODELS/IQM/Body.jpg" "$MODELS/IQM/Head.jpg" "$WORK/"
(
  cd "$WORK"
  assimp export mrfixit.iqm mrfixit.obj >/dev/null
  assimp export mrfixit.iqm mrfixit.glb >/dev/null
  # The same character written Z-up (Blender's convention), to exercise the up-axis detection.
  awk '$1 == "v" { print "v", $2, -$4, $3; next } { print }' mrfixit.obj > mrfixit_zup.obj
)
for file in mrfixit.obj mrfixit.glb mrfixit_zup.obj; do
  name="${file%.*}_${file##*.}"
  echo "== $name"
  # shellcheck disable=SC2086
  R2HUMAN_LOG="${R2HUMAN_LOG:-warn,r2human::synth=info}" ./target/release/r2human eval --scan "$WORK/$file" \
    ${R2HUMAN_SCAN_ARGS:-} --out "$OUT/$name"
done
