#!/usr/bin/env bash
# Builds the engine for the browser (release) and serves the page on 127.0.0.1:8080.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
wasm-pack build --release --target web --out-dir www/pkg --mode no-install --no-typescript --no-pack
# The embedded demo scene: a synthetic road with exact truth, and its truth as a map
# file to review and compare with, generated once.
if [ ! -f www/demo/demo.zip ] || [ ! -f www/demo/demo-truth.rogsmap ]; then
  cargo build --release --bin rogs
  mkdir -p www/demo
  ./target/release/rogs synth --preset demo --seed 1 --lidar --pose-noise-m 0.05 --pose-noise-deg 0.5 --out www/demo/demo.zip --truth-map www/demo/demo-truth.rogsmap
fi
exec node scripts/serve.mjs --port "${PORT:-8080}"
