#!/usr/bin/env bash
# Installs whatever the build and the tests need, only when it is missing, so that a
# second run takes seconds. Idempotent; safe to run by hand.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/env.sh
say() { printf '\033[1msetup:\033[0m %s\n' "$*"; }

apt_missing=()
[ -e /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ] || apt_missing+=(mesa-vulkan-drivers)
ldconfig -p 2>/dev/null | grep -q 'libvulkan.so.1' || apt_missing+=(libvulkan1)
command -v chromium >/dev/null || apt_missing+=(chromium)
command -v chromedriver >/dev/null || apt_missing+=(chromium-driver)
# GDAL reads our GeoTIFFs back in the tests (a real GIS reader, not our own).
command -v gdalinfo >/dev/null || apt_missing+=(gdal-bin)
if [ ${#apt_missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ]; then
    say "installing ${apt_missing[*]} (apt)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${apt_missing[@]}" >/dev/null
  else
    echo "missing system packages: ${apt_missing[*]}" >&2
    echo "install them with: sudo apt-get install -y ${apt_missing[*]}" >&2
    exit 1
  fi
fi

if ! rustup target list --installed | grep -q '^wasm32-unknown-unknown$'; then
  say "adding the wasm32-unknown-unknown target"
  rustup target add wasm32-unknown-unknown
fi
for c in clippy rustfmt; do
  rustup component list --installed | grep -q "^$c" || rustup component add "$c"
done
if ! command -v wasm-pack >/dev/null; then
  say "installing wasm-pack (about 8 minutes, once)"
  cargo install wasm-pack --locked
fi
if ! wasm-bindgen --version 2>/dev/null | grep -q ' 0.2.130'; then
  # --locked fails: the registry lacks one of its locked dependency versions.
  say "installing wasm-bindgen-cli 0.2.130 (about 5 minutes, once)"
  cargo install wasm-bindgen-cli --version 0.2.130 --force
fi
# Ray runs the tile jobs in the distributed-path test (a real local cluster), from a
# virtual environment of its own (.venv; scripts/ray_map.py runs with any Python that has ray).
if ! .venv/bin/python -c 'import ray' 2>/dev/null; then
  say "installing Ray into .venv (about 30 s, once)"
  python3 -m venv .venv
  .venv/bin/pip install --quiet --disable-pip-version-check "ray==2.60.0"
fi
# onnxruntime is the independent run `rogs segment` is checked against (tests/segment.rs).
if ! .venv/bin/python -c 'import onnxruntime' 2>/dev/null; then
  say "installing onnxruntime into .venv (about 20 s, once)"
  .venv/bin/pip install --quiet --disable-pip-version-check "onnxruntime==1.32.0"
fi
if [ ! -d node_modules/playwright-core ] || [ ! -d node_modules/@playcanvas/splat-transform ]; then
  say "installing npm packages"
  npm ci --no-audit --no-fund
fi
