#!/usr/bin/env bash
# The project's test command: sets up what is missing, then checks formatting and lints (clippy -D warnings) and
# runs the whole test suite (unit, integration, Vulkan parity on lavapipe, the XR client against Monado).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# Incremental caches are useless on a fresh CI checkout and take gigabytes beside ~25 linked binaries.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
cargo fmt --all -- --check
cargo clippy --all-targets -- -D warnings
cargo test --all-targets --no-fail-fast 2>&1 | tee target/test.log
