#!/usr/bin/env bash
# glTF export checks (src/pipeline/export.rs, tests/export.rs): the Khronos glTF validator, the npm package
# `gltf-validator` 2.0.0-dev.3.10 (Apache-2.0), installed into the project's git-ignored `.tools/gltf-validator`.
# scripts/gltf-validate.mjs runs it on a file: `node scripts/gltf-validate.mjs person.glb` prints the report
# (JSON) and exits non-zero when the file has errors. Idempotent, non-interactive, runs as root.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
DEST="$ROOT/.tools/gltf-validator"
VERSION="2.0.0-dev.3.10"
if [ -f "$DEST/node_modules/gltf-validator/package.json" ] &&
    grep -q "\"version\": \"$VERSION\"" "$DEST/node_modules/gltf-validator/package.json"; then
    echo "gltf.sh: gltf-validator $VERSION present in $DEST"
    exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update
    apt-get install -y --no-install-recommends nodejs npm
fi
mkdir -p "$DEST"
npm install --prefix "$DEST" --no-audit --no-fund --no-save "gltf-validator@$VERSION"
echo "gltf.sh: gltf-validator $VERSION installed in $DEST"
