// The published site (`npm run build` → dist/) in headless Chromium: the release
// engine (the wasm-release profile, its names stripped after wasm-bindgen) loads, its
// GPU self-test passes, the embedded demo opens and a bundle is optimised into a map.
// The release build is what `npm start` and every static host serve; the other page
// tests use a debug build. Needs dist/ (scripts/test.sh builds it first).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { root, useBrowser, openPage, drop } from './harness.mjs';

const dist = path.join(root, 'dist');
// The engine's size budget (docs/PUBLISH.md): fail when it grows past it unnoticed.
const WASM_BUDGET_BYTES = 2.3e6;

useBrowser({ site: 'dist' });

test('dist/ holds the release engine within its size budget, without a name section', () => {
  const wasm = path.join(dist, 'pkg/rogs_bg.wasm');
  assert.ok(fs.existsSync(wasm), 'dist/ is missing: run `npm run build` (scripts/build.sh) first');
  const bytes = fs.readFileSync(wasm);
  assert.ok(bytes.length < WASM_BUDGET_BYTES, `rogs_bg.wasm is ${bytes.length} bytes, the budget ${WASM_BUDGET_BYTES}`);
  assert.deepEqual(customSections(bytes), [], 'custom sections were not stripped');
});

test('dist/ holds the segmentation module the page fetches when a model is dropped, stripped too', () => {
  const wasm = path.join(dist, 'pkg-segment/rogs_segment_bg.wasm');
  assert.ok(fs.existsSync(wasm) && fs.existsSync(path.join(dist, 'pkg-segment/rogs_segment.js')) && fs.existsSync(path.join(dist, 'segment-worker.js')),
    'dist/ lacks the segmentation module: run `npm run build` (scripts/build.sh)');
  assert.deepEqual(customSections(fs.readFileSync(wasm)), [], 'custom sections were not stripped');
});

/** The names of a wasm module's custom sections. */
function customSections(bytes) {
  const leb = (pos) => {
    let v = 0;
    for (let shift = 0; ; shift += 7) {
      const b = bytes[pos++];
      v += (b & 0x7f) * 2 ** shift;
      if (!(b & 0x80)) return [v, pos];
    }
  };
  const names = [];
  for (let pos = 8; pos < bytes.length;) {
    const id = bytes[pos];
    const [size, body] = leb(pos + 1);
    if (id === 0) {
      const [len, at] = leb(body);
      names.push(bytes.subarray(at, at + len).toString());
    }
    pos = body + size;
  }
  return names;
}

test('the release engine loads, opens the demo and optimises a bundle', async () => {
  const { page, errors } = await openPage();
  assert.match(await page.textContent('#gpu'), /self-test passed/);
  await page.click('#demo');
  await page.waitForSelector('#summary:not([hidden])');
  assert.match(await page.textContent('#summary-title'), /synthetic/);
  await drop(page, 'valid.zip');
  await page.waitForFunction(() => /valid\.zip is a valid bundle/.test(document.getElementById('status').textContent));
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 300_000 });
  assert.deepEqual(errors, []);
  await page.close();
});
