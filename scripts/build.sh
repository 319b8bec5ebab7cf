#!/usr/bin/env bash
# Writes a self-contained static site to dist/: the page, the optimised wasm engine
# and the demo scene, all by relative paths, so that any static host serves it as it
# is (docs/PUBLISH.md). Prints the wasm's size, raw and gzipped.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/web.sh
rm -rf dist
mkdir -p dist/pkg dist/pkg-segment dist/demo
cp www/index.html www/style.css www/*.js dist/
cp www/pkg/rogs.js www/pkg/rogs_bg.wasm dist/pkg/
cp www/pkg-segment/rogs_segment.js www/pkg-segment/rogs_segment_bg.wasm dist/pkg-segment/
cp www/demo/demo.zip www/demo/demo-truth.rogsmap dist/demo/
raw=$(stat -c %s dist/pkg/rogs_bg.wasm)
gz=$(gzip -9 -c dist/pkg/rogs_bg.wasm | wc -c)
total=$(du -sb dist | cut -f1)
seg=$(stat -c %s dist/pkg-segment/rogs_segment_bg.wasm)
awk -v t="$total" -v r="$raw" -v g="$gz" -v s="$seg" 'BEGIN { printf "build: dist/ is ready (%.1f MiB in all); rogs_bg.wasm %.2f MB, %.2f MB gzipped; the segmentation module (fetched when a model is dropped) %.2f MB\n", t / 1048576, r / 1e6, g / 1e6, s / 1e6 }'
echo "build: serve it with any static server, e.g. node scripts/serve.mjs --root dist"
