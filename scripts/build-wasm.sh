#!/usr/bin/env bash
# Builds the page's engine into www/pkg: wasm-pack with the wasm-release profile
# (Cargo.toml: fat LTO, the name section kept for wasm-bindgen), then the custom
# sections a browser never reads are removed (scripts/strip-wasm.mjs). Used by
# `npm start`, `npm run build` and the browser benchmarks.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
wasm-pack build --profile wasm-release --target web --out-dir www/pkg --mode no-install --no-typescript --no-pack
node scripts/strip-wasm.mjs www/pkg/rogs_bg.wasm
