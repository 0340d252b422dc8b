#!/usr/bin/env bash
# A second independent set for `r2human eval --scan` (issue 33), from a source and a format the project had not
# used: the characters of UFO: Alien Invasion (Debian's `ufoai-data`; its copyright file gives these models GPL-2
# or GPL-2+), MD2 bodies with their heads joined by the body's `tag_head`, posed at the `stand_menu` frame the
# game's menus show, written Y up and facing +z by `examples/md2_to_obj.rs` (textures as shipped, JPEG or PNG).
#
# Which characters (fixed before any number was looked at):
#   every body of models/civilians/{female,male} and models/soldiers/* that has an .anm and a .tag, with its own
#   head where the package names one after the body (sheik01 -> sheik_head01, soldier01 -> soldier01_head,
#   worker01 -> worker01_head, the male scientist01 -> sci_head01), otherwise the folder's first head
#   (civilians: head01a female, head01 male; soldiers: head01). Dropped as not human: the whole models/aliens
#   folder (ortnok, shevaar, taman, bloodspider, hovernet).
# Split (fixed before any number was looked at, the rule of `eval::scans::held_out`): sorted by name, every second
#   character (2nd, 4th, ...) is held out; decisions are taken on dev, held out says whether they carry over.
#
#   bash scripts/scan-ufoai.sh [OUT]          (default out/scan-ufoai; about 10 minutes in a release build, 512 px)
# Also run by scripts/scan-check.sh (into its OUT/ufoai). Writes OUT/characters/report.md (section "Scans
# together": dev, held-out and all), scans.csv (every character's values), sheet.png (every character's ground
# truth at yaw 0/90/180). Only the converted OBJs and their textures
# are written (OUT/files, about 10 MB); the package stays as apt installed it. Extra eval arguments go in
# R2HUMAN_SCAN_ARGS, as for scan-check.sh.
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$REPO/out/scan-ufoai}"
PK3=/usr/share/games/ufoai/base/0models.pk3
if [ ! -f "$PK3" ]; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  apt-get install -y --no-install-recommends ufoai-data
fi
cd "$REPO"
cargo build --release --quiet --bin r2human --example md2_to_obj --example scan_sheet
# NAME BODY HEAD (paths inside the pk3 without .md2).
CHARACTERS="
civ_female_body01 models/civilians/female/body01 models/civilians/female/head01a
civ_female_body02 models/civilians/female/body02 models/civilians/female/head01a
civ_female_body03 models/civilians/female/body03 models/civilians/female/head01a
civ_female_body05 models/civilians/female/body05 models/civilians/female/head01a
civ_female_scientist01 models/civilians/female/scientist01 models/civilians/female/head01a
civ_male_body01 models/civilians/male/body01 models/civilians/male/head01
civ_male_body02 models/civilians/male/body02 models/civilians/male/head01
civ_male_scientist01 models/civilians/male/scientist01 models/civilians/male/sci_head01
civ_male_sheik01 models/civilians/male/sheik01 models/civilians/male/sheik_head01
civ_male_soldier01 models/civilians/male/soldier01 models/civilians/male/soldier01_head
civ_male_worker01 models/civilians/male/worker01 models/civilians/male/worker01_head
soldier_female models/soldiers/female/body models/soldiers/female/head01
soldier_femalelight models/soldiers/femalelight/body models/soldiers/femalelight/head01
soldier_femalemedium models/soldiers/femalemedium/body models/soldiers/femalemedium/head01
soldier_femalepower models/soldiers/femalepower/body models/soldiers/femalepower/head01
soldier_male models/soldiers/male/body models/soldiers/male/head01
soldier_malelight models/soldiers/malelight/body models/soldiers/malelight/head01
soldier_malemedium models/soldiers/malemedium/body models/soldiers/malemedium/head01
soldier_malepower models/soldiers/malepower/body models/soldiers/malepower/head01
"
FILES="$OUT/files"
rm -rf "$FILES"
scans=()
while read -r name body head; do
  [ -n "$name" ] || continue
  "$REPO/target/release/examples/md2_to_obj" "$PK3" "$body" "$head" "$name" "$FILES/$name"
  scans+=("$FILES/$name/$name.obj")
done <<< "$CHARACTERS"
# shellcheck source=lib/evaluate-scans.sh
source "$REPO/scripts/lib/evaluate-scans.sh"
evaluate_scans "$OUT/characters" ufoai "## Scans together" "${scans[@]}"
