// Times map review in headless Chromium: `node scripts/bench-review.mjs MAP.rogsmap
// [frames]`. Opens the map by ?map= (range requests) and by the file picker
// (File.slice), reports the time to the first complete view, then pans along the
// trajectory at full resolution and zooms in and out for `frames` animation frames
// each, and prints frames per second, draw times, tiles read and bytes fetched as
// JSON. Serves www/ (build the wasm first: bash scripts/build-wasm.sh).
import fs from 'node:fs';
import path from 'node:path';
import { openBench } from './bench-browser.mjs';

const [map, frames = '240'] = process.argv.slice(2);
if (!map) {
  console.error('usage: node scripts/bench-review.mjs MAP.rogsmap [frames]');
  process.exit(2);
}
const { base, bundleUrl, browser, close } = await openBench(map);
const size = fs.statSync(map).size;

async function settle(page) {
  await page.waitForFunction(() => window.rogsReview && window.rogsReview.state.a && window.rogsReview.pending() === 0, null, { timeout: 600_000, polling: 20 });
  await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
}

// Animates `n` frames of a view path in the page; returns fps and draw times.
function animate(page, kind, n) {
  return page.evaluate(async ([kind, n]) => {
    const r = window.rogsReview, s = r.state, ix = s.a.map.index, t = ix.trajectory;
    const draws = [];
    const loads0 = s.stats.loads;
    const t0 = performance.now();
    for (let f = 0; f < n; f++) {
      await new Promise((res) => requestAnimationFrame(res));
      const u = f / n;
      let cx, cy, mpp;
      if (kind === 'pan') {
        // Along the trajectory at the map's resolution: 20 px per frame.
        const i = Math.min(t.length - 1, Math.floor(t.length * 0.3 + f * 20 * ix.resolution));
        [cx, cy] = t[i]; mpp = ix.resolution;
      } else {
        // From the whole map down to full resolution and back, around the middle.
        const m = t[Math.floor(t.length / 2)];
        [cx, cy] = m;
        const fitMpp = 1.05 * ix.width * ix.resolution / 900;
        const a = Math.abs(2 * u - 1);
        mpp = Math.exp(Math.log(ix.resolution) * (1 - a) + Math.log(fitMpp) * a);
      }
      const d0 = performance.now();
      r.setView(cx, cy, mpp);
      draws.push(performance.now() - d0);
    }
    const secs = (performance.now() - t0) / 1000;
    draws.sort((a, b) => a - b);
    return {
      frames: n, fps: n / secs, draw_ms_median: draws[Math.floor(n / 2)], draw_ms_p95: draws[Math.floor(n * 0.95)],
      tiles_read: s.stats.loads - loads0,
    };
  }, [kind, n]);
}

try {
  const out = { map: path.basename(map), bytes: size };
  const page = await browser.newPage({ viewport: { width: 1100, height: 800 } });
  let fetched = 0;
  page.on('response', (r) => { if (new URL(r.url()).pathname.endsWith(path.basename(map))) fetched += Number(r.headers()['content-length'] || 0); });
  const t0 = Date.now();
  await page.goto(`${base}/?map=${bundleUrl}`);
  await page.waitForSelector('#review:not([hidden])', { timeout: 600_000 });
  await settle(page);
  out.index = await page.evaluate(() => { const i = window.rogsReview.state.a.map.index; return { width: i.width, height: i.height, resolution: i.resolution, levels: i.levels, entries: window.rogsReview.state.a.map.entries.size }; });
  out.url_first_view_ms = Number(await page.getAttribute('#review-map', 'data-first-view-ms'));
  out.url_page_load_to_first_view_ms = Date.now() - t0;
  out.url_bytes_to_first_view = fetched;
  out.pan = await animate(page, 'pan', Number(frames));
  await settle(page);
  out.zoom = await animate(page, 'zoom', Number(frames));
  await settle(page);
  out.bytes_fetched_in_all = fetched;
  await page.close();

  const p2 = await browser.newPage({ viewport: { width: 1100, height: 800 } });
  await p2.goto(`${base}/`);
  await p2.waitForSelector('body[data-ready="true"]', { timeout: 120_000 });
  const t1 = Date.now();
  await p2.setInputFiles('#picker', map);
  await p2.waitForSelector('#review:not([hidden])', { timeout: 600_000 });
  await settle(p2);
  out.file_first_view_ms = Number(await p2.getAttribute('#review-map', 'data-first-view-ms'));
  out.file_pick_to_first_view_ms = Date.now() - t1;
  console.log(JSON.stringify(out, null, 2));
} finally {
  await close();
}
