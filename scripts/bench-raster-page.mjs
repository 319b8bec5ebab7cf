// The rasteriser benchmark (`rogs bench raster`) in headless Chromium (WebGPU on
// SwiftShader): `node scripts/bench-raster-page.mjs BUNDLE.zip [frame] [view] [runs]
// [resolution]`. Serves www/ (build it first: bash scripts/build-wasm.sh), calls the wasm export `bench_raster` in the page and prints its
// JSON: pixel×surfel pairs per second forward and forward+backward, median of the runs.
import { openBench } from './bench-browser.mjs';

const [bundle, frame = '0', view = '0', runs = '7', resolution = '0.05'] = process.argv.slice(2);
if (!bundle) {
  console.error('usage: node scripts/bench-raster-page.mjs BUNDLE.zip [frame] [view] [runs] [resolution]');
  process.exit(2);
}
const { base, bundleUrl, browser, close } = await openBench(bundle);
try {
  const page = await browser.newPage();
  await page.goto(base);
  const json = await page.evaluate(async ([url, f, v, n, res]) => {
    const m = await import('/pkg/rogs.js');
    await m.default();
    const bytes = new Uint8Array(await (await fetch(url)).arrayBuffer());
    return m.bench_raster(bytes, f, v, n, res);
  }, [`/${bundleUrl}`, Number(frame), Number(view), Number(runs), Number(resolution)]);
  console.log(JSON.stringify({ browser: await browser.version(), ...JSON.parse(json) }, null, 2));
} catch (e) {
  console.error(`bench-raster-page: ${e.message}`);
  process.exitCode = 1;
} finally {
  await close();
}
