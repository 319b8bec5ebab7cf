# Environment for GPU work on machines without a GPU: Mesa's lavapipe through Vulkan.
# Sourced by the other scripts; harmless where a real GPU driver exists (an explicit
# VK_ICD_FILENAMES or WGPU_BACKEND from the caller wins).
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
if [ -z "${VK_ICD_FILENAMES:-}" ] && [ -e /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ] && [ -z "${ROGS_REAL_GPU:-}" ]; then
  export VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
fi
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/rogs-xdg-$(id -u)"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 0700 "$XDG_RUNTIME_DIR"
fi
export PATH="$HOME/.cargo/bin:$PATH"
# wasm-bindgen-test-runner gives the whole headless run 20 s by default; the GPU tests
# in Chromium (SwiftShader, debug wasm) take about that, so a busy machine timed out.
export WASM_BINDGEN_TEST_TIMEOUT="${WASM_BINDGEN_TEST_TIMEOUT:-300}"
