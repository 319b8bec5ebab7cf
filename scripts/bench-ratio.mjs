// Browser against native in one run: `rogs bench raster` natively (lavapipe) and the
// same benchmark in headless Chromium (SwiftShader), one after the other on the same
// view, then the ratio browser / native of each figure: the platform probe (a dense
// blend with no lists, sort or atomics: the platform's own ratio), the forward pass,
// forward + backward, and each kernel.
//   node scripts/bench-ratio.mjs BUNDLE.zip [frame] [view] [runs] [resolution]
// With `step` first, `rogs bench step` and the page's `bench_step` instead: whole
// training steps, the host's part (target decoding) and each kernel, side by side.
//   node scripts/bench-ratio.mjs step BUNDLE.zip [steps] [resolution] [half-width]
// Needs the release binary (cargo build --release, or ROGS_BIN) and the release wasm
// (bash scripts/build-wasm.sh).
import { execFileSync } from 'node:child_process';
import path from 'node:path';
import { benchRasterInPage, benchStepInPage } from './bench-browser.mjs';

const stepMode = process.argv[2] === 'step';
const [bundle, frame = '0', view = '0', runs = '5', resolution = '0.1'] = process.argv.slice(2);
if (!bundle) {
  console.error('usage: node scripts/bench-ratio.mjs BUNDLE.zip [frame] [view] [runs] [resolution]');
  process.exit(2);
}
const root = path.resolve(import.meta.dirname, '..');
const bin = process.env.ROGS_BIN || path.join(root, 'target/release/rogs');

function nativeRun() {
  const out = execFileSync(bin, ['bench', 'raster', bundle, '--frame', frame, '--view', view,
    '--runs', runs, '--resolution', resolution], { encoding: 'utf8', env: { ...process.env, WGPU_BACKEND: process.env.WGPU_BACKEND || 'vulkan' } });
  return JSON.parse(out);
}

const row = (n, w) => ({ native: n, browser: w, ratio: w / n });
/** Each kernel both runs timed, side by side. */
function kernelRows(native, web) {
  const kernels = {};
  for (const k of Object.keys(native.kernels_ms || {})) {
    if (web.kernels_ms && k in web.kernels_ms) kernels[k] = row(native.kernels_ms[k], web.kernels_ms[k]);
  }
  return kernels;
}

if (stepMode) {
  const [b, steps = '8', res = '0.1', half = '8'] = process.argv.slice(3);
  if (!b) {
    console.error('usage: node scripts/bench-ratio.mjs step BUNDLE.zip [steps] [resolution] [half-width]');
    process.exit(2);
  }
  try {
    const native = JSON.parse(execFileSync(bin, ['bench', 'step', b, '--steps', steps, '--resolution', res, '--half-width', half],
      { encoding: 'utf8', env: { ...process.env, WGPU_BACKEND: process.env.WGPU_BACKEND || 'vulkan' } }));
    const web = await benchStepInPage(b, steps, res, half);
    const rest = (r) => r.seconds_per_step - (r.gpu_kernel_ms_per_step ?? 0) / 1e3;
    console.log(JSON.stringify({
      bundle: path.basename(b),
      adapters: { native: native.adapter, browser: `${web.adapter} (${web.browser})` },
      surfels: native.surfels,
      seconds_per_step: row(native.seconds_per_step, web.seconds_per_step),
      gpu_kernel_s_per_step: row(native.gpu_kernel_ms_per_step / 1e3, web.gpu_kernel_ms_per_step / 1e3),
      target_s_per_step: row(native.target_ms_per_step / 1e3, web.target_ms_per_step / 1e3),
      // Wall time outside the kernels: host work, submission and waiting.
      rest_s_per_step: row(rest(native), rest(web)),
      kernels_ms: kernelRows(native, web),
    }, null, 2));
  } catch (e) {
    console.error(`bench-ratio: ${e.message}`);
    process.exitCode = 1;
  }
  process.exit();
}

// GPU-timestamp seconds where both adapters have them, else wall seconds.
const pick = (r, key) => (r.gpu_timestamps ? r.gpu_timestamps[key] : r[key]);
try {
  const native = nativeRun();
  const web = await benchRasterInPage(bundle, frame, view, runs, resolution);
  const kernels = kernelRows(native, web);
  console.log(JSON.stringify({
    bundle: path.basename(bundle),
    view: native.view,
    adapters: { native: native.adapter, browser: `${web.adapter} (${web.browser})` },
    accumulation: { native: native.accumulation, browser: web.accumulation },
    timing: native.gpu_timestamps && web.gpu_timestamps ? 'gpu_timestamps' : 'wall',
    probe_s: row(native.probe.gpu_s ?? native.probe.wall_s, web.probe.gpu_s ?? web.probe.wall_s),
    forward_s: row(pick(native, 'forward_s'), pick(web, 'forward_s')),
    forward_backward_s: row(pick(native, 'forward_backward_s'), pick(web, 'forward_backward_s')),
    kernels_ms: kernels,
  }, null, 2));
} catch (e) {
  console.error(`bench-ratio: ${e.message}`);
  process.exitCode = 1;
}
