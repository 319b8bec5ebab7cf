#!/usr/bin/env bash
# Every test: format, lints (native and wasm32), native tests on lavapipe, wasm tests
# in headless Chromium (WebGPU on SwiftShader), the page tests with Playwright, and the
# tile jobs on a real local Ray cluster.
# A missing GPU adapter fails the run: GPU tests never skip.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. scripts/env.sh
step() { printf '\n\033[1m== %s\033[0m\n' "$*"; }
t0=$(date +%s)

step "cargo fmt --check"
cargo fmt --all -- --check
step "cargo clippy (native)"
cargo clippy --all-targets -- -D warnings
step "cargo clippy (wasm32)"
cargo clippy --target wasm32-unknown-unknown --all-targets -- -D warnings
step "cargo clippy (wasm32, the page's segmentation module)"
cargo clippy --target wasm32-unknown-unknown --features segmenter --lib -- -D warnings

step "native tests on $(WGPU_BACKEND=$WGPU_BACKEND echo "$WGPU_BACKEND")"
cargo build --bins --examples
./target/debug/rogs gpu
cargo test

step "tile jobs on a local Ray cluster"
.venv/bin/python -m unittest discover -s tests/ray -v

step "wasm tests in headless Chromium"
wasm-pack test --headless --chrome --chromedriver /usr/bin/chromedriver --mode no-install

step "the published site: release wasm and demo (npm run build)"
bash scripts/build.sh

step "page tests (Playwright, headless Chromium)"
wasm-pack build --dev --target web --out-dir www/pkg --mode no-install --no-typescript --no-pack
cargo run --quiet --example page_fixtures -- target/page-fixtures
node --test --test-reporter=spec tests/page/

echo "all tests passed in $(( $(date +%s) - t0 )) s"
