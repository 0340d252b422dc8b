#!/usr/bin/env bash
# A fourth independent set for `r2human eval --scan` (issue 33), from a source and a format the project had not
# used: the player characters of Nexuiz (Debian's `nexuiz-data`, GPL-2+), ZYMOTIC skeletal models inside the game's
# data.pk3, posed at the first pose of their `idle` scene and written Y up, facing +z, by `examples/zym_to_obj.rs`
# with their TGA skins (`textures.pk3`, from the
# package's dependency nexuiz-textures).
#
# Why Nexuiz: xonotic-data, sauerbraten-data and alien-arena-data are not in this machine's Debian; redeclipse-data
# has two player models; 0ad-data ships its art as .pmd/.dds in a 3.2 GB zip; openarena's players are already
# scan-check.sh's.
#
# Which characters (fixed before any model was converted or rendered, from the character files alone):
#   every character file models/player/*.txt of data.pk3 whose `species` line says `human` (the others are
#   `alien` mutants and reptiles or `robot_solid`/`robot_shiny` machines), one character per file, named as the
#   file. A character whose model fails to convert is dropped with its error printed (none is re-tried by hand).
#   9 characters: heroine insurrectionist lycanthrope marine nexus pyria shock skadi specop.
# Split (fixed before any model was converted or rendered, the rule of `eval::scans::held_out`): sorted by name,
#   every second character (2nd, 4th, ...) is held out. dev (5): heroine lycanthrope nexus shock specop. held out
#   (4): insurrectionist marine pyria skadi.
#   Decisions are taken on dev; the held-out half is evaluated once, when a decision is made.
#
#   bash scripts/scan-nexuiz.sh [OUT]              all 9
#   SPLIT=dev bash scripts/scan-nexuiz.sh OUT      the dev half only; SPLIT=held-out the held-out half only
# With SPLIT set, the eval sees one half only: read its "all" rows (the report's own dev/held-out split of a half
# is not this split). Writes OUT/characters/report.md (section "Scans together"), scans.csv, sheet.png (every
# character's ground truth at yaw 0/90/180). Only the converted OBJs and their textures are written (OUT/files);
# the package stays as apt installed it. Extra eval arguments go in R2HUMAN_SCAN_ARGS, as for scan-check.sh.
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$REPO/out/scan-nexuiz}"
SPLIT="${SPLIT:-all}"
DATA=/usr/share/games/nexuiz/data
if [ ! -f "$DATA/data.pk3" ] || [ ! -f "$DATA/textures.pk3" ]; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  apt-get install -y --no-install-recommends nexuiz-data
fi
cd "$REPO"
# shellcheck source=lib/evaluate-scans.sh
source "$REPO/scripts/lib/evaluate-scans.sh"
cargo build --release --quiet --bin r2human --example zym_to_obj --example scan_sheet
CHARACTERS="heroine insurrectionist lycanthrope marine nexus pyria shock skadi specop"
mapfile -t sorted < <(printf '%s\n' $CHARACTERS | LC_ALL=C sort)
FILES="$OUT/files"
rm -rf "$FILES"
scans=()
for i in "${!sorted[@]}"; do
  name="${sorted[$i]}"
  in_split "$i" || continue
  if "$REPO/target/release/examples/zym_to_obj" "$DATA" "$name" "$FILES/$name"; then
    scans+=("$FILES/$name/$name.obj")
  else
    echo "dropped $name: conversion failed" >&2
  fi
done
evaluate_scans "$OUT/characters" "nexuiz $SPLIT" "## Scans together" "${scans[@]}"
