#!/usr/bin/env bash
# Builds the page's assets (scripts/web.sh: tools on first run, release wasm, the demo
# scene and its truth map) and serves the page on 127.0.0.1:8080.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/web.sh
exec node scripts/serve.mjs --port "${PORT:-8080}"
