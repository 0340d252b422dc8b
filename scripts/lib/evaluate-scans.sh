# Sourced by the scan scripts (scan-check.sh, scan-ufoai.sh, scan-megaglest.sh, scan-nexuiz.sh); needs REPO (the checkout, with
# the release r2human and examples/scan_sheet built).
#
# evaluate_scans DIR LABEL SECTION FILE...: one `r2human eval` over the scans (Y up, facing +z) into DIR, with
# DIR/sheet.png of their ground truth at yaw 0/90/180, then prints DIR/report.md from the heading SECTION on.
# R2HUMAN_LOG (default warn,r2human::synth=info) and R2HUMAN_SCAN_ARGS (extra eval arguments) are read.
# in_split INDEX: whether the character at INDEX of the sorted list belongs to the half SPLIT names (dev: even
# indices, held-out: odd, all: every one); exits with 2 for any other SPLIT.
in_split() {
  case "$SPLIT" in
    dev) [ $(($1 % 2)) -eq 0 ] ;;
    held-out) [ $(($1 % 2)) -eq 1 ] ;;
    all) true ;;
    *) echo "SPLIT must be dev, held-out or all" >&2; exit 2 ;;
  esac
}

evaluate_scans() {
  local dir="$1" label="$2" section="$3"
  shift 3
  mkdir -p "$dir"
  "$REPO/target/release/examples/scan_sheet" "$dir/sheet.png" --up y --facing +z --size 256 "$@"
  local args=()
  for s in "$@"; do
    args+=(--scan "$s")
  done
  echo "== $label ($#)"
  # shellcheck disable=SC2086
  R2HUMAN_LOG="${R2HUMAN_LOG:-warn,r2human::synth=info}" "$REPO/target/release/r2human" eval "${args[@]}" \
    --up y --facing +z ${R2HUMAN_SCAN_ARGS:-} --out "$dir"
  sed -n "/^$section/,\$p" "$dir/report.md"
}
