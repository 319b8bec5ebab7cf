// The page's segmentation ("Compute masks with a model…"): TwinLiteNet labels four
// frames of the real KITTI sample in a Web Worker through the engine's segmentation
// module; its labels agree with the native run's (`rogs segment`'s code, itself
// checked against onnxruntime in tests/segment.rs) on at least 99 % of pixels; the
// labelled bundle opens in the unlabelled one's place and can be saved; a damaged
// model is refused in words, the bundle kept, and the page stays alive.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { useBrowser, openPage, drop, fixtures } from './harness.mjs';

useBrowser();

// Pixels where the label images of two bundles agree, over every view, read in the
// page with its own zip reader and the browser's PNG decoder.
async function agreement(page, aUrl, bUrl) {
  return page.evaluate(async ([aUrl, bUrl]) => {
    const { blobSource, centralDirectory, readEntry } = await import('/zip.js');
    const open = async (url) => {
      const src = blobSource(await (await fetch(url)).blob(), url);
      const entries = await centralDirectory(src);
      const manifest = JSON.parse(new TextDecoder().decode(await readEntry(src, entries, 'manifest.json')));
      return { src, entries, manifest };
    };
    const grey = async (z, p) => {
      const bmp = await createImageBitmap(new Blob([await readEntry(z.src, z.entries, p)]), { colorSpaceConversion: 'none', premultiplyAlpha: 'none' });
      const c = new OffscreenCanvas(bmp.width, bmp.height).getContext('2d');
      c.drawImage(bmp, 0, 0);
      const d = c.getImageData(0, 0, bmp.width, bmp.height).data;
      return d.filter((_, i) => i % 4 === 0);
    };
    const [a, b] = [await open(aUrl), await open(bUrl)];
    let same = 0, all = 0, views = 0;
    const ids = new Set();
    for (const [f, frame] of a.manifest.frames.entries()) {
      for (const [v, view] of frame.views.entries()) {
        const [la, lb] = [await grey(a, view.label), await grey(b, b.manifest.frames[f].views[v].label)];
        if (la.length !== lb.length) return { error: `view ${f}/${v}: ${la.length} against ${lb.length} pixels` };
        for (let i = 0; i < la.length; i++) { same += la[i] === lb[i]; ids.add(la[i]); }
        all += la.length;
        views++;
      }
    }
    return { share: same / all, views, ids: [...ids].sort() };
  }, [aUrl, bUrl]);
}

test('a model labels an unlabelled drive in the page as natively; a damaged one is refused in words', async () => {
  const { page, errors } = await openPage();
  await drop(page, 'kitti-unlabelled.zip');
  await page.waitForSelector('#no-labels');

  // A damaged model: named, the bundle kept as it was, the page alive.
  await page.setInputFiles('#segment-model', path.join(fixtures, 'corrupt.onnx'));
  await page.waitForFunction(() => document.body.dataset.segment === 'failed', null, { timeout: 120_000 });
  const bad = await page.textContent('#status');
  assert.match(bad, /Could not compute masks: corrupt\.onnx: not an ONNX model/, bad);
  assert.equal(await page.locator('#no-labels').count(), 1);

  // The real model: every view labelled, the labelled bundle open in its place.
  await page.setInputFiles('#segment-model', path.join(fixtures, 'twinlitenet.onnx'));
  await page.waitForFunction(() => document.body.dataset.segment === 'done', null, { timeout: 600_000 });
  const done = await page.textContent('#status');
  assert.match(done, /4 views labelled by twinlitenet\.onnx in [\d.]+ s/, done);
  assert.equal(await page.locator('#no-labels').count(), 0);
  assert.match(await page.textContent('#classes'), /1 road \(road\)/);
  assert.match(await page.textContent('#summary-title'), /KITTI/);
  await page.waitForSelector('#optimise:not([hidden])');
  console.log(`segmentation in the page: ${await page.getAttribute('body', 'data-segment-seconds')} s for 4 views of 1241×376`);

  const saved = await page.getAttribute('#segment-download', 'href');
  assert.equal(await page.getAttribute('#segment-download', 'download'), 'kitti-unlabelled-labelled.zip');
  const r = await agreement(page, saved, '/fixtures/kitti-labelled-native.zip');
  assert.ok(!r.error, r.error);
  assert.equal(r.views, 4);
  assert.ok(r.ids.includes(1) && r.ids.includes(0), `classes found: ${r.ids}`);
  assert.ok(r.share >= 0.99, `the page's labels agree with the native run's on ${(100 * r.share).toFixed(3)} % of pixels`);
  console.log(`page against native labels: ${(100 * r.share).toFixed(3)} % of pixels agree`);
  assert.deepEqual(errors, []);
  await page.close();
});
