#!/usr/bin/env bash
# Builds the engine for the browser (release) and serves the page on 127.0.0.1:8080.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
wasm-pack build --release --target web --out-dir www/pkg --mode no-install --no-typescript --no-pack
exec node scripts/serve.mjs --port "${PORT:-8080}"
