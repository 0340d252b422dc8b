#!/usr/bin/env bash
# The project's test command: sets up what is missing, then checks formatting and lints (clippy -D warnings) and
# runs the whole test suite (unit, integration, Vulkan parity on lavapipe, the XR client against Monado).
set -euo pipefail
cd "$(dirname "$0")/.."
# Disk first: the suite needs ~6 GB (target/debug ~4 GB with small debug info, the Monado root ~1.3 GB, temporary
# files); say how much there is, so that a run that dies of a full disk is recognised as such.
df -h . "${TMPDIR:-/tmp}" || true
bash scripts/setup.sh
# Incremental caches are useless on a fresh CI checkout and take gigabytes beside ~25 linked binaries.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
cargo fmt --all -- --check
cargo clippy --all-targets -- -D warnings
cargo test --all-targets --no-fail-fast 2>&1 | tee target/test.log
