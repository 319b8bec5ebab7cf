// Opens a long bundle lazily in headless Chromium and trains its first steps:
// `node scripts/bench-lazy.mjs BUNDLE.zip [steps] [resolution] [tile_m]`. The bundle is read
// by ?url= with range requests (a multi-GiB file cannot be dropped by a script).
// Prints as JSON: the time to a checked bundle, the bytes read to open it, the time
// to the first step, the wasm heap and the bundle bytes held at most while the
// steps run (a tile's files), the GPU buffers held at most, and the bytes read in all. ROGS_EAGER=1 reads the
// bundle whole instead (it must be under 256 MiB), for a side-by-side figure. Build the wasm first
// (bash scripts/build-wasm.sh).
import fs from 'node:fs';
import { openBench } from './bench-browser.mjs';
import { gpuAccountingScript } from '../tests/page/gpu-accounting.mjs';

const [bundle, steps = '40', resolution = '0.2', tileM = '96'] = process.argv.slice(2);
if (!bundle) {
  console.error('usage: node scripts/bench-lazy.mjs BUNDLE.zip [steps] [resolution] [tile_m]');
  process.exit(2);
}
const { base, bundleUrl, browser, close } = await openBench(bundle);
const size = fs.statSync(bundle).size;
const page = await browser.newPage();
const t0 = Date.now();
// The GPU buffers the page holds (an upper bound: see gpu-accounting.mjs), sampled.
await page.addInitScript(gpuAccountingScript);
// Whole stacks in a panic's message.
await page.addInitScript(() => { Error.stackTraceLimit = 60; });
let gpuPeak = 0;
let heapPeak = 0;
let said = '';
const sampler = setInterval(async () => {
  try {
    const [g, h, text] = await page.evaluate(async () => [window.gpuLiveBytes?.() || 0,
      (await import('/pkg/rogs.js')).wasm_memory_bytes?.() || 0,
      `${document.getElementById('status')?.textContent} | ${document.getElementById('progress-text')?.textContent}`]);
    (gpuPeak = Math.max(gpuPeak, g)), (heapPeak = Math.max(heapPeak, h));
    // What the page says, on stderr as it changes (a crash's last words).
    if (text !== said) console.error(`${((Date.now() - t0) / 1000).toFixed(1)} s: ${(said = text)} (heap ${(h / 2 ** 20).toFixed(0)} MiB, GPU ${(g / 2 ** 20).toFixed(0)} MiB)`);
  } catch { /* navigating */ }
}, 250);
page.on('crash', () => console.error('the page crashed (renderer gone)'));
page.on('pageerror', (e) => console.error(`page error: ${e}`));
page.on('console', (m) => m.type() === 'error' && console.error(`console: ${m.text()}`));
let read = 0;
page.on('response', async (r) => {
  if (r.url().includes('/bench/')) read += Number(r.headers()['content-length'] || 0);
});
// ROGS_EAGER=1: the same run reading the bundle whole, for comparison.
const eager = process.env.ROGS_EAGER === '1';
await page.goto(`${base}/?url=${bundleUrl}${eager ? '' : '&lazy=1'}`);
await page.waitForFunction(() => /valid bundle|not a valid|Could not/.test(document.getElementById('status').textContent), null, { timeout: 600_000 });
const openS = (Date.now() - t0) / 1000;
const status = await page.textContent('#status');
if (!/is a valid bundle/.test(status)) {
  console.error(status);
  process.exit(1);
}
const openRead = read;
await page.selectOption('#set-resolution', resolution);
await page.fill('#set-tile', tileM);
const t1 = Date.now();
await page.click('#run');
await page.waitForFunction(() => Number(document.body.dataset.steps || 0) >= 1, null, { timeout: 1_800_000, polling: 200 });
const firstStepS = (Date.now() - t1) / 1000;
await page.waitForFunction((n) => Number(document.body.dataset.steps || 0) >= n, Number(steps), { timeout: 1_800_000, polling: 500 });
const stepsS = (Date.now() - t1) / 1000;
const heap = await page.evaluate(async () => (await import('/pkg/rogs.js')).wasm_memory_bytes());
const out = {
  bundle, read: eager ? 'whole' : 'lazily', bundle_bytes: size, tile_m: Number(tileM), resolution: Number(resolution),
  open_s: openS, open_bytes_read: openRead,
  first_step_s: firstStepS, steps: Number(steps), steps_s: stepsS,
  tiles: Number(await page.getAttribute('body', 'data-tiles')),
  held_peak_bytes: Number(await page.getAttribute('body', 'data-held-peak')),
  wasm_heap_bytes: heap, wasm_heap_peak_bytes: heapPeak, gpu_peak_bytes: gpuPeak, bytes_read: read,
  progress: await page.textContent('#progress-text'),
};
clearInterval(sampler);
console.log(JSON.stringify(out, null, 2));
await close();
