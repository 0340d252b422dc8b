#!/usr/bin/env bash
# Frames against stills on real photos: each bundled photo scaled to 480 px high in a 640x480 grey frame, drawn by
# the frame path (`render --video` of a folder holding that frame) and by the still path (`render --image` of the
# same frame), both `--mode ar`, at the yaws given (default 0 and 80); prints the mask IoU of the two renders, each
# cut to its own mask's box (examples/render_mask_iou.rs). Usage: scripts/frames-vs-stills.sh OUT_DIR [YAW...]
# Needs a release build (`cargo build --release`) and ffmpeg.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:?usage: scripts/frames-vs-stills.sh OUT_DIR [YAW...]}"
shift
yaws=("${@:-0 80}")
read -r -a yaws <<< "${yaws[*]}"
bin=./target/release/r2human
cargo build --release --quiet --bin r2human --example render_mask_iou
iou=./target/release/examples/render_mask_iou
mkdir -p "$out"
printf '%-26s' "photo"; for y in "${yaws[@]}"; do printf ' yaw %-4s' "$y"; done; echo
for photo in assets/photos/*.png assets/photos/*.jpg; do
  stem=$(basename "${photo%.*}")
  mkdir -p "$out/$stem/frame"
  ffmpeg -loglevel error -y -i "$photo" -vf "scale=-2:480,pad=640:480:(ow-iw)/2:0:color=0x707070,format=rgb24" \
    -frames:v 1 "$out/$stem/frame/000.png"
  printf '%-26s' "$stem"
  for y in "${yaws[@]}"; do
    R2HUMAN_LOG=error "$bin" render --image "$out/$stem/frame/000.png" --yaw "$y" --mode ar --out "$out/$stem/still_$y.png" >/dev/null
    R2HUMAN_LOG=error "$bin" render --video "$out/$stem/frame" --yaw "$y" --mode ar --out "$out/$stem/video_$y" >/dev/null
    printf ' %8s' "$("$iou" "$out/$stem/still_$y.png" "$out/$stem/video_$y/frame_00000.png")"
  done
  echo
done
