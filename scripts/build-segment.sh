#!/usr/bin/env bash
# Builds the page's segmentation module into www/pkg-segment: this crate with the
# `segmenter` feature (tract in wasm, only src/web/segment.rs's bindings), which the
# page fetches when a model is dropped on it (docs/SEGMENT.md). Used by `npm start`,
# `npm run build` and the page tests.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
wasm-pack build --profile segment-release --target web --out-dir www/pkg-segment \
  --out-name rogs_segment --mode no-install --no-typescript --no-pack -- --features segmenter
node scripts/strip-wasm.mjs www/pkg-segment/rogs_segment_bg.wasm
