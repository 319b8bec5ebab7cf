// The rasteriser benchmark (`rogs bench raster`) in headless Chromium (WebGPU on
// SwiftShader): `node scripts/bench-raster-page.mjs BUNDLE.zip [frame] [view] [runs]
// [resolution]`. Serves www/ (build it first: bash scripts/build-wasm.sh), calls the wasm export `bench_raster` in the page and prints its
// JSON: pixel×surfel pairs per second forward and forward+backward, median of the runs.
import { benchRasterInPage } from './bench-browser.mjs';

const [bundle, frame = '0', view = '0', runs = '7', resolution = '0.05'] = process.argv.slice(2);
if (!bundle) {
  console.error('usage: node scripts/bench-raster-page.mjs BUNDLE.zip [frame] [view] [runs] [resolution]');
  process.exit(2);
}
try {
  console.log(JSON.stringify(await benchRasterInPage(bundle, frame, view, runs, resolution), null, 2));
} catch (e) {
  console.error(`bench-raster-page: ${e.message}`);
  process.exitCode = 1;
}
