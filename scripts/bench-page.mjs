// Times the in-page optimisation of a bundle in headless Chromium (WebGPU on
// SwiftShader): `node scripts/bench-page.mjs BUNDLE.zip [resolution] [steps]`. Serves
// www/ (build it first: bash scripts/build-wasm.sh) and
// prints the steps, seconds per step and total time as JSON. With `steps`, it stops
// the run after that many steps (large bundles: time per step without a whole epoch).
// With `--no-frame-exposure`, the page's "A gain per frame" is unticked. With `--segment MODEL.onnx`, masks are computed in the page first ("Compute masks
// with a model…", TwinLiteNet's class map) and their time is printed as well.
// The click waits for the page's GPU warm-up (the next run's device and pipelines,
// made when the bundle is accepted), as a user who reads the summary first would;
// `gpu_warm_s` is its length. With `--cold`, the click comes at once.
import { openBench } from './bench-browser.mjs';

const args = process.argv.slice(2);
const noGains = args.indexOf('--no-frame-exposure');
if (noGains >= 0) args.splice(noGains, 1);
const coldAt = args.indexOf('--cold');
if (coldAt >= 0) args.splice(coldAt, 1);
const seg = args.indexOf('--segment');
const model = seg >= 0 ? args.splice(seg, 2)[1] : null;
const [bundle, resolution = '0.1', maxSteps] = args;
if (!bundle || (seg >= 0 && !model)) {
  console.error('usage: node scripts/bench-page.mjs BUNDLE.zip [resolution] [steps] [--segment MODEL.onnx]');
  process.exit(2);
}
const { base, bundleUrl, browser, close } = await openBench(bundle);
try {
  const page = await browser.newPage();
  await page.goto(`${base}/?url=${bundleUrl}`);
  await page.waitForSelector('#optimise:not([hidden])', { timeout: 120_000 });
  let segment = null;
  if (model) {
    await page.setInputFiles('#segment-model', model);
    await page.waitForFunction(() => ['done', 'failed'].includes(document.body.dataset.segment), null, { timeout: 3_600_000, polling: 500 });
    segment = { seconds: Number(await page.getAttribute('body', 'data-segment-seconds')), status: await page.textContent('#status') };
    console.error(JSON.stringify({ segment }));
    if (!segment.seconds) process.exit(1);
  }
  await page.selectOption('#set-resolution', resolution);
  if (noGains >= 0) {
    await page.evaluate(() => { document.getElementById('advanced').open = true; });
    await page.setChecked('#set-frame-exposure', false);
  }
  let gpuWarmS = null;
  if (coldAt < 0) {
    await page.waitForFunction(() => document.body.dataset.gpuWarmS !== undefined, null, { timeout: 600_000, polling: 100 });
    gpuWarmS = Number(await page.getAttribute('body', 'data-gpu-warm-s'));
  }
  const t0 = Date.now();
  await page.click('#run');
  if (maxSteps) {
    await page.waitForFunction((n) => Number(document.body.dataset.steps || 0) >= n, Number(maxSteps), { timeout: 3_600_000, polling: 500 });
    const text = await page.textContent('#progress-text');
    await page.click('#stop');
    const perStep = Number((text.match(/([\d.]+) s per step/) || [])[1]);
    console.log(JSON.stringify({ bundle, segment, resolution: Number(resolution), steps: Number(maxSteps), seconds_per_step: perStep, setup_and_steps_s: (Date.now() - t0) / 1000, progress: text }, null, 2));
    process.exit(0);
  }
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 3_600_000 });
  const total = (Date.now() - t0) / 1000;
  const steps = Number(await page.getAttribute('body', 'data-steps'));
  const text = await page.textContent('#progress-text');
  const perStep = Number((text.match(/([\d.]+) s per step/) || [])[1]);
  // Seconds from the click: the run started, trained, the map rendered, shown, and
  // its downloads made.
  const stages = await page.evaluate(() => Object.fromEntries(['startS', 'trainedS', 'finishS', 'mapShownS', 'exportsS', 'previewS']
    .map((k) => [k.replace(/S$/, '_s'), Number(document.body.dataset[k])])));
  // The engine's own stage timings (report.json's).
  const timings = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    return a ? (await (await fetch(a.href)).json()).timings : null;
  });
  console.log(JSON.stringify({ bundle, segment, resolution: Number(resolution), gpu_warm_s: gpuWarmS, steps, seconds_per_step: perStep, total_s: total, click_to: stages, timings, status: await page.textContent('#status'), metrics: await page.textContent('#metrics') }, null, 2));
} finally {
  await close();
}
