#!/usr/bin/env bash
# Independent check of `r2human eval --scan` on real third-party characters (not MakeHuman, not made by this
# project), installed from Debian packages by this script:
#
# 1. Mr. Fixit, as a new user would bring him: Debian's `assimp-testmodels` (BSD-3-clause, the assimp test models)
#    ships him as IQM (a textured game character in T-pose, facing +x, separate body and head textures);
#    `assimp-utils`' `assimp export` turns him into formats r2human reads (OBJ+MTL with two JPEG textures, GLB with
#    embedded textures, and the OBJ written Z-up), untouched otherwise: orientation, T-pose and materials are left to
#    `eval --scan`'s detection. Writes OUT/mrfixit_obj, OUT/mrfixit_glb, OUT/mrfixit_zup_obj (report.md each).
# 2. A set of characters in natural standing poses, evaluated together with every geometry and renderer the eval
#    has: Debian's `openarena-081-players` (GPL-2+; the OpenArena player models, MD3) converted by
#    `examples/md3_to_obj.rs` (three parts joined by their tags at the first frames of TORSO_STAND and LEGS_IDLE,
#    written Y up and facing +z), Mr. Fixit's OBJ turned to face +z and Sydney (Irrlicht's MD2 character in
#    `assimp-testmodels`, zlib-style Irrlicht licence; exported by `assimp export`, turned to face +z). One `eval` with `--up y --facing +z` over
#    all of them writes OUT/characters/report.md with the aggregate section "Scans together": per method the mean
#    over characters of the volumetric IoU, the divergent mask IoU and the whole-frame PSNR at close and divergent
#    views, for a dev half, a held-out half and all (`src/eval/scans.rs`); OUT/characters/scans.csv has every
#    character's values, scans_summary.csv the means, sheet.png every character's ground truth at yaw 0/90/180.
#    Held-out rule (fixed before any number was looked at): sorted by name, every second character (2nd, 4th, ...)
#    is held out. Characters dropped as not human, from their renders: gargoyle and faerie (wings), liz (a reptile: snout and
#    tail), merman (a fish tail instead of legs), skelebot (a robot skeleton). The players dmo and slshish named in
#    the package have no model in it (empty folders).
#
# 3. Three more characters kept apart from every choice: they are read once, after `--geometry auto` was chosen on
#    the others: neko from OpenArena 0.8.8 (`openarena-088-data`, GPL-2+) and angelyss and ayumi from the 0.8.1
#    "mature" players (`openarena-081-players-mature`, GPL-2+), converted like the others. Left out: arachna (a
#    spider below the waist) and sorceress (no default skin). Evaluated in an eval of their own, OUT/fresh/report.md,
#    so the ten's dev / held-out split stays as it was fixed.
#
# 4. The characters of UFO: Alien Invasion (19 civilians and soldiers, MD2 bodies and heads joined by their tags),
#    with a dev / held-out split of their own fixed before any number was looked at: `scripts/scan-ufoai.sh`, run
#    last into OUT/ufoai (OUT/ufoai/characters/report.md). It is the set `--geometry auto` is decided on
#    (docs/geometry.md, "Which geometry wins where").
#
#   bash scripts/scan-check.sh [OUT]          (default out/scan-check; about 15 minutes in a release build, 512 px)
# Extra arguments for every eval go in R2HUMAN_SCAN_ARGS (e.g. "--save-views", or "--size 256"). Note that
# "--no-neural" also leaves out the FOF net and the body prior (both run networks): only billboard, 2.5d,
# inflation and ground-truth rows remain.
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$REPO/out/scan-check}"
MODELS=/usr/share/assimp/models
OA_PK3=/usr/share/games/openarena/baseoa/pak2-players.pk3
OA_PLAYERS="assassin beret kyonshi major penguin sergei smarine tony"
OA_088_PK3=/usr/share/games/openarena/baseoa/pak6-patch088.pk3
OA_MATURE_PK3=/usr/share/games/openarena/baseoa/pak2-players-mature.pk3
need=()
if [ ! -d "$MODELS/IQM" ] || ! command -v assimp >/dev/null 2>&1; then
  need+=(assimp-testmodels assimp-utils)
fi
if [ ! -f "$OA_PK3" ]; then
  need+=(openarena-081-players)
fi
if [ ! -f "$OA_088_PK3" ]; then
  need+=(openarena-088-data)
fi
if [ ! -f "$OA_MATURE_PK3" ]; then
  need+=(openarena-081-players-mature)
fi
if [ "${#need[@]}" -gt 0 ]; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update
  apt-get install -y --no-install-recommends "${need[@]}"
fi
cd "$REPO"
cargo build --release --quiet --bin r2human --example md3_to_obj --example scan_sheet
R2HUMAN="$REPO/target/release/r2human"
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
log="${R2HUMAN_LOG:-warn,r2human::synth=info}"
for file in mrfixit.obj mrfixit.glb mrfixit_zup.obj; do
  name="${file%.*}_${file##*.}"
  echo "== $name"
  # shellcheck disable=SC2086
  R2HUMAN_LOG="$log" "$R2HUMAN" eval --scan "$WORK/$file" ${R2HUMAN_SCAN_ARGS:-} --out "$OUT/$name"
done

# The characters, each in its own folder named after it (the scan's name in the report is its file stem).
CHARS="$WORK/characters"
rm -rf "$CHARS"
# face_plus_z SRC.obj DST.obj: a Y-up OBJ facing +x turned by -90 degrees about y, (x, y, z) -> (-z, y, x), a
# rotation (normals too); the numbers are moved as written (awk's arithmetic would round them to 6 digits).
face_plus_z() {
  mkdir -p "$(dirname "$2")"
  awk 'function neg(s) { return substr(s, 1, 1) == "-" ? substr(s, 2) : "-" s }
       $1 == "v" || $1 == "vn" { print $1, neg($4), $3, $2; next } { print }' "$1" > "$2"
}
# Mr. Fixit (IQM) faces +x.
face_plus_z "$WORK/mrfixit.obj" "$CHARS/mrfixit/mrfixit.obj"
cp "$WORK/mrfixit.mtl" "$WORK/Body.jpg" "$WORK/Head.jpg" "$CHARS/mrfixit/"
# Sydney (Irrlicht's MD2 character, also in assimp-testmodels; its first frame stands) faces +x too. assimp
# writes no texture name for MD2 (map_Kd $texture_dummy.bmp): her skin is sydney.bmp next to the model. (The
# package's other MD2 character, faerie, has wings: left out.)
cp "$MODELS/MD2/sydney.md2" "$MODELS/MD2/sydney.bmp" "$WORK/"
(cd "$WORK" && assimp export sydney.md2 sydney.obj >/dev/null)
face_plus_z "$WORK/sydney.obj" "$CHARS/sydney/sydney.obj"
sed 's/^map_Kd .*/map_Kd sydney.bmp/' "$WORK/sydney.mtl" > "$CHARS/sydney/sydney.mtl"
cp "$WORK/sydney.bmp" "$CHARS/sydney/"
scans=("$CHARS/mrfixit/mrfixit.obj" "$CHARS/sydney/sydney.obj")
for player in $OA_PLAYERS; do
  "$REPO/target/release/examples/md3_to_obj" "$OA_PK3" "$player" "$CHARS/$player"
  scans+=("$CHARS/$player/$player.obj")
done
# shellcheck source=lib/evaluate-scans.sh
source "$REPO/scripts/lib/evaluate-scans.sh"
evaluate_scans "$OUT/characters" characters "## Scans together" "${scans[@]}"

# The three new characters, on their own.
FRESH="$WORK/fresh"
rm -rf "$FRESH"
"$REPO/target/release/examples/md3_to_obj" "$OA_088_PK3" neko "$FRESH/neko"
for player in angelyss ayumi; do
  "$REPO/target/release/examples/md3_to_obj" "$OA_MATURE_PK3" "$player" "$FRESH/$player"
done
evaluate_scans "$OUT/fresh" fresh "### all" "$FRESH/angelyss/angelyss.obj" "$FRESH/ayumi/ayumi.obj" "$FRESH/neko/neko.obj"

# The UFO: Alien Invasion characters (their own split, their own eval).
bash "$REPO/scripts/scan-ufoai.sh" "$OUT/ufoai"
