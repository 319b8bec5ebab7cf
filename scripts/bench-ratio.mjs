// Browser against native in one run: `rogs bench raster` natively (lavapipe) and the
// same benchmark in headless Chromium (SwiftShader), one after the other on the same
// view, then the ratio browser / native of each figure: the platform probe (a dense
// blend with no lists, sort or atomics: the platform's own ratio), the forward pass,
// forward + backward, and each kernel.
//   node scripts/bench-ratio.mjs BUNDLE.zip [frame] [view] [runs] [resolution]
// Needs the release binary (cargo build --release, or ROGS_BIN) and the release wasm
// (bash scripts/build-wasm.sh).
import { execFileSync } from 'node:child_process';
import path from 'node:path';
import { benchRasterInPage } from './bench-browser.mjs';

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

// GPU-timestamp seconds where both adapters have them, else wall seconds.
const pick = (r, key) => (r.gpu_timestamps ? r.gpu_timestamps[key] : r[key]);
try {
  const native = nativeRun();
  const web = await benchRasterInPage(bundle, frame, view, runs, resolution);
  const row = (n, w) => ({ native: n, browser: w, ratio: w / n });
  const kernels = {};
  for (const k of Object.keys(native.kernels_ms || {})) {
    if (web.kernels_ms && k in web.kernels_ms) kernels[k] = row(native.kernels_ms[k], web.kernels_ms[k]);
  }
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
