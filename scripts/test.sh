#!/usr/bin/env bash
# The project's test command: sets up what is missing, then runs formatting, lint and the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
cargo fmt --all -- --check
cargo test --all-targets --no-fail-fast 2>&1 | tee target/test.log
