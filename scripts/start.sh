#!/usr/bin/env bash
# Builds the engine for the browser (release) and serves the page on 127.0.0.1:8080.
# Each step says what it does; the first run also installs the tools (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
echo "start: building the engine for the browser (wasm, release; a few minutes the first time)…"
wasm-pack build --release --target web --out-dir www/pkg --mode no-install --no-typescript --no-pack
# The embedded demo scene: a synthetic road with exact truth, and its truth as a map
# file to review and compare with, generated once by the wasm engine in Node (no
# native build needed).
if [ ! -f www/demo/demo.zip ] || [ ! -f www/demo/demo-truth.rogsmap ]; then
  node scripts/make-demo.mjs
fi
exec node scripts/serve.mjs --port "${PORT:-8080}"
