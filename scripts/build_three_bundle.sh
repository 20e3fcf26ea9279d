#!/usr/bin/env bash
# Rebuild modalfem/web/three.bundle.min.js: three.js (MIT) with its GLTFLoader and OrbitControls, bundled
# and minified into one classic script that defines the global THREE (what the self-contained pages of
# `modalfem export --html` inline). Needs node + npm and the npm registry; the result is committed, so
# nothing here runs at install or view time.
# Usage: scripts/build_three_bundle.sh [THREE_VERSION] [ESBUILD_VERSION]
set -euo pipefail
cd "$(dirname "$0")/.."
THREE_VERSION="${1:-0.187.0}"
ESBUILD_VERSION="${2:-0.28.2}"
OUT="$PWD/modalfem/web/three.bundle.min.js"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
npm init -y >/dev/null
npm install --no-audit --no-fund --silent "three@$THREE_VERSION" "esbuild@$ESBUILD_VERSION"
cat > entry.js <<'JS'
export * from 'three';
export { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
JS
{
  printf '/* three.js r%s (npm three@%s), with GLTFLoader and OrbitControls from its examples/jsm.\n' \
    "$(echo "$THREE_VERSION" | cut -d. -f2)" "$THREE_VERSION"
  printf ' * Copyright 2010-2026 three.js authors. MIT licence (full text: THREE_LICENSE beside this file).\n'
  printf ' * Bundled by scripts/build_three_bundle.sh with esbuild %s (IIFE, global THREE, minified). */\n' "$ESBUILD_VERSION"
  node_modules/.bin/esbuild entry.js --bundle --minify --format=iife --global-name=THREE \
    --legal-comments=none --target=es2020 --log-level=warning
} > "$OUT"
cp node_modules/three/LICENSE "$(dirname "$OUT")/THREE_LICENSE"
echo "wrote $OUT ($(wc -c < "$OUT") bytes) from three@$THREE_VERSION"
