// Shared by the browser benchmarks (bench-page.mjs, bench-raster-page.mjs): serves
// www/ and the bundle's folder under /bench/, and opens headless Chromium with WebGPU
// on SwiftShader.
import path from 'node:path';
import { chromium } from 'playwright-core';
import { createServer } from './serve.mjs';

/** { base, bundleUrl, browser, close } for the bundle at path `bundle`. */
export async function openBench(bundle) {
  const root = path.resolve(import.meta.dirname, '..');
  const server = createServer([['/bench/', path.dirname(path.resolve(bundle))], ['/', path.join(root, 'www')]]);
  await new Promise((r) => server.listen(0, '127.0.0.1', r));
  const base = `http://127.0.0.1:${server.address().port}`;
  const browser = await chromium.launch({
    executablePath: '/usr/bin/chromium',
    // ROGS_CHROMIUM_FLAGS adds flags (e.g. --disable-accelerated-2d-canvas).
    args: ['--no-sandbox', '--enable-unsafe-webgpu', '--enable-features=Vulkan', '--use-vulkan=swiftshader', '--use-angle=swiftshader',
      ...(process.env.ROGS_CHROMIUM_FLAGS || '').split(' ').filter(Boolean)],
  });
  const close = async () => {
    await browser.close();
    server.close();
  };
  return { base, bundleUrl: `bench/${path.basename(bundle)}`, browser, close };
}

/** The page's `bench_raster` (src/render/bench.rs) on one view of `bundle`, parsed. */
export async function benchRasterInPage(bundle, frame, view, runs, resolution) {
  return benchInPage(bundle, 'bench_raster', [Number(frame), Number(view), Number(runs), Number(resolution)]);
}

/** The page's `bench_step` (src/optim/bench.rs) on `bundle`, parsed. */
export async function benchStepInPage(bundle, steps, resolution, halfWidth) {
  return benchInPage(bundle, 'bench_step', [Number(steps), Number(resolution), Number(halfWidth)]);
}

/** The engine's export `name` called with the bundle's bytes and `args`, its JSON parsed. */
async function benchInPage(bundle, name, args) {
  const { base, bundleUrl, browser, close } = await openBench(bundle);
  try {
    const page = await browser.newPage();
    await page.goto(base);
    const json = await page.evaluate(async ([url, f, a]) => {
      const m = await import('/pkg/rogs.js');
      await m.default();
      const bytes = new Uint8Array(await (await fetch(url)).arrayBuffer());
      return m[f](bytes, ...a);
    }, [`/${bundleUrl}`, name, args]);
    return { browser: await browser.version(), ...JSON.parse(json) };
  } finally {
    await close();
  }
}
