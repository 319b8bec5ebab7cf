#!/usr/bin/env bash
# The page's assets, shared by `npm start` and `npm run build`: installs what is
# missing, builds the engine for the browser (release) into www/pkg and the
# segmentation module into www/pkg-segment, and makes the
# demo scene with the wasm engine in Node the first time (no native build needed).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
echo "web: building the engine for the browser (wasm, release; a few minutes the first time)…"
bash scripts/build-wasm.sh
echo "web: building the segmentation module (fetched by the page when a model is dropped)…"
bash scripts/build-segment.sh
if [ ! -f www/demo/demo.zip ] || [ ! -f www/demo/demo-truth.rogsmap ]; then
  node scripts/make-demo.mjs
fi
