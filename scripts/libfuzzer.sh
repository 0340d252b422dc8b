#!/usr/bin/env bash
# Runs the cargo-fuzz targets of fuzz/ (one per loader, `r2human::fuzzing::Target`) under libFuzzer for a bounded
# time each, on the stable toolchain: cargo-fuzz passes a few unstable flags that stable rustc accepts with
# RUSTC_BOOTSTRAP=1, and `--sanitizer none` needs no sanitizer runtime (libFuzzer itself is C++ that libfuzzer-sys
# compiles with the system compiler). Without a sanitizer a crash is a panic, an abort, a timeout or the RSS limit;
# memory errors inside C libraries go unseen (a nightly toolchain adds AddressSanitizer: fuzz/README.md).
#
# Usage: scripts/libfuzzer.sh [--seconds N] [--targets a,b,...] [--release]
#   --seconds N   fuzzing time per target (default 120)
#   --targets     comma-separated subset of the targets (default: all of fuzz/fuzz_targets/)
#   --release     optimised build (cargo fuzz's default; much slower to build on 2 cores); default: --dev
# Installs cargo-fuzz (crates.io, pinned) into ~/.cargo/bin when missing, writes the starting corpus
# (tests/fuzz.rs export_cargo_fuzz_corpus: generated seeds + tests/corpus/) into fuzz/corpus/<target>/, and prints
# one line per target: runs, seconds, coverage, new inputs, corpus size, peak RSS, crashes. Crashing inputs land in fuzz/artifacts/<target>/; keep
# one as a regression in tests/corpus/<target>/ (the stable harness runs every file there). Logs and the summary:
# target/libfuzzer/. Exits non-zero when a target crashed or did not build.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_PER_TARGET=120
TARGETS=""
MODE=--dev
CARGO_FUZZ_VERSION=0.13.2
while [ $# -gt 0 ]; do
    case "$1" in
        --seconds) SECONDS_PER_TARGET=$2; shift 2 ;;
        --targets) TARGETS=$2; shift 2 ;;
        --release) MODE=--release; shift ;;
        *) echo "unknown option $1 (see the header of $0)" >&2; exit 2 ;;
    esac
done
if [ -z "$TARGETS" ]; then
    TARGETS=$(cd fuzz/fuzz_targets && ls -- *.rs | sed 's/\.rs$//' | paste -sd, -)
fi
if ! cargo fuzz --version 2>/dev/null | grep -q "$CARGO_FUZZ_VERSION"; then
    cargo install cargo-fuzz --locked --version "$CARGO_FUZZ_VERSION"
fi
OUT=$PWD/target/libfuzzer
mkdir -p "$OUT"
cargo test --test fuzz export_cargo_fuzz_corpus -- --ignored --nocapture > "$OUT/corpus-export.log"
export RUSTC_BOOTSTRAP=1
cd fuzz
cargo fuzz build "$MODE" --sanitizer none 2>&1 | tail -n 3
# The targets run from the binaries just built (`cargo fuzz run` would rebuild first, each time).
BUILT=target/x86_64-unknown-linux-gnu/$([ "$MODE" = --release ] && echo release || echo debug)
# Files under a folder (0 when it does not exist yet).
count_files() { if [ -d "$1" ]; then find "$1" -type f | wc -l; else echo 0; fi; }
FAILED=0
SUMMARY=$OUT/summary.txt
echo "target,runs,seconds,edges,features,new_inputs,corpus_files,peak_rss_mb,crashes" > "$OUT/summary.csv"
: > "$SUMMARY"
for t in ${TARGETS//,/ }; do
    log=$OUT/$t.log
    status=0
    before=$(count_files "artifacts/$t")
    # -timeout: the stable harness's per-case bound; -rss_limit_mb: what a hostile file may make a loader hold.
    mkdir -p "corpus/$t" "artifacts/$t"
    "$BUILT/$t" -artifact_prefix="artifacts/$t/" -max_len=1048576 -timeout=20 -rss_limit_mb=4096 \
        -max_total_time="$SECONDS_PER_TARGET" -print_final_stats=1 "corpus/$t" > "$log" 2>&1 || status=$?
    stat() { awk -v key="stat::$1:" '$1 == key {v = $2} END {print v}' "$log"; }
    runs=$(stat number_of_executed_units)
    secs=$(awk '/^Done [0-9]+ runs in [0-9]+ second/ {s = $5} END {print s}' "$log")
    # Coverage: the edges (cov) and features (ft) libFuzzer counts at the end (DONE, or the last status line).
    cov=$(awk '{for (i = 1; i < NF; i++) {if ($i == "cov:") c = $(i + 1); if ($i == "ft:") f = $(i + 1)}}
        END {print c "," f}' "$log")
    files=$(count_files "corpus/$t")
    crashes=$(( $(count_files "artifacts/$t") - before ))
    line="$t: ${runs:-?} runs in ${secs:-?} s, coverage ${cov%%,*} edges / ${cov##*,} features, $(stat new_units_added) new"
    line="$line inputs (corpus ${files} files), peak RSS $(stat peak_rss_mb) MB, ${crashes} new crash files (exit status $status)"
    echo "$line" | tee -a "$SUMMARY"
    echo "$t,${runs:-},${secs:-},${cov:-,},$(stat new_units_added),$files,$(stat peak_rss_mb),$crashes" >> "$OUT/summary.csv"
    if [ "$status" != 0 ] || [ "$crashes" != 0 ]; then FAILED=1; fi
done
exit "$FAILED"
