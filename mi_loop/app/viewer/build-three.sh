#!/usr/bin/env bash
# Rebuild three.min.js: three.js (MIT, three.LICENSE) and its OrbitControls, only what three-entry.js
# exports, bundled by esbuild into one minified classic script that defines the global THREE. A report
# inlines it (a page opened from file:// cannot load ES modules). Needs node and npm; run from anywhere.
set -euo pipefail
THREE_VERSION=0.187.0
ESBUILD_VERSION=0.28.2
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
npm init -y >/dev/null
npm install --no-audit --no-fund "three@$THREE_VERSION" "esbuild@$ESBUILD_VERSION" >/dev/null
cp "$here/three-entry.js" entry.js
npx esbuild entry.js --bundle --minify --format=iife --global-name=THREE --legal-comments=eof \
    --target=es2020 --outfile="$here/three.min.js"
cp node_modules/three/LICENSE "$here/three.LICENSE"
