// Soak: ten reconstructions in a row in one page. After each, the wasm memory and the
// GPU bytes the page holds (every buffer counted until it or its device is destroyed)
// are read; from the second run on neither may grow (the GPU's within a run's jitter). docs/RELIABILITY.md has the figures.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { useBrowser, openPage, root } from './harness.mjs';

useBrowser();

test('ten reconstructions in one page hold no more wasm or GPU memory than the second', async () => {
  const { page, errors } = await openPage('?url=fixtures/valid.zip', { gpuAccounting: true });
  await page.waitForSelector('#optimise:not([hidden])');
  await page.selectOption('#set-resolution', '0.2');
  await page.fill('#set-epochs', '1');
  const rows = [];
  for (let i = 1; i <= 10; i++) {
    await page.click('#run');
    await page.waitForSelector(`body[data-runs="${i}"]`, { timeout: 120_000 });
    assert.match(await page.textContent('#status'), /Map ready/);
    // The next run's device, warmed after each run, is held as well (its pipelines
    // and a few small buffers).
    await page.waitForFunction(() => document.body.dataset.gpuWarmS !== undefined, null, { timeout: 60_000 });
    rows.push(await page.evaluate(() => ({
      wasm: Number(document.body.dataset.wasmBytes),
      gpu: window.gpuLiveBytes(),
      devices: window.gpuDevices(),
    })));
  }
  const out = path.join(root, 'target/soak.json');
  fs.writeFileSync(out, JSON.stringify(rows, null, 1));
  const table = rows.map((r, i) => `${i + 1}: wasm ${r.wasm} B, GPU ${r.gpu} B on ${r.devices} device(s)`).join('\n');
  // The GPU figure varies a little from run to run (seen: 16 858 188, 17 155 456 and
  // 17 192 320 B in any order on SwiftShader: buffers sized by the pairs a view makes,
  // which float atomics change by a few), never in a trend. A run's engine state is
  // about 16 MiB, so a leaked run would add MiBs at once: from run 2 on, the GPU
  // bytes stay within 1 MiB of run 2's (a slow leak of 150 KiB a run passes that by
  // run 10), and the wasm memory does not grow at all.
  const slack = 1 << 20;
  for (const r of rows.slice(2)) {
    assert.ok(r.wasm <= rows[1].wasm, `wasm memory grew after run 2:\n${table}`);
    assert.ok(r.gpu <= rows[1].gpu + slack, `GPU memory grew after run 2:\n${table}`);
    assert.ok(r.devices <= rows[1].devices, `GPU devices pile up:\n${table}`);
  }
  assert.ok(rows[0].gpu > 0, 'the accounting saw the engine\'s buffers');
  console.log(table);
  assert.deepEqual(errors, []);
  await page.close();
});
