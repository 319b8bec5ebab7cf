// Page tests in headless Chromium (WebGPU on SwiftShader): the shell loads, WebGPU is
// found, dropped / picked / ?url= bundles show their summary or their named problems,
// and the page keeps working after an error. Screenshots go to target/screenshots/.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import path from 'node:path';
import { env, useBrowser, openPage, drop, dropMany, fixtures, shots, cspViolations } from './harness.mjs';

useBrowser();

test('WebGPU is found and the GPU self-test passes', async () => {
  const { page, errors } = await openPage();
  assert.match(await page.textContent('#gpu'), /self-test passed/);
  assert.equal(await page.isHidden('#webgpu'), true);
  assert.deepEqual(errors, []);
  await page.close();
});

test('a dropped valid bundle shows its summary; an invalid one its named problems; the page survives', async () => {
  const { page, errors, requests } = await openPage();
  await drop(page, 'valid.zip');
  await page.waitForSelector('#summary:not([hidden])');
  assert.match(await page.textContent('#status'), /valid\.zip is a valid bundle/);
  assert.equal(await page.textContent('dd[data-fact="trajectory"]'), '2.0 m');
  assert.match(await page.textContent('dd[data-fact="LiDAR"]'), /300 points in 3 sweeps/);
  assert.match(await page.textContent('#classes'), /lane_marking/);
  await page.screenshot({ path: path.join(shots, 'shell-summary.png'), fullPage: true });

  await drop(page, 'invalid.zip');
  await page.waitForSelector('#problems:not([hidden])');
  const problems = await page.textContent('#problem-list');
  assert.match(problems, /frames\[1\]\.views\[0\]\.image/);
  assert.match(problems, /images\/front\/000001\.png/);
  assert.match(problems, /frames\[2\]\.vehicle_to_world/);
  assert.match(problems, /label value 99/);
  assert.match(await page.textContent('#status'), /3 problem\(s\)/);
  assert.equal(await page.isHidden('#summary'), true);
  await page.screenshot({ path: path.join(shots, 'shell-problems.png'), fullPage: true });

  // Still alive: a file that is not a zip, then the valid bundle again through the picker.
  await page.evaluate(() => {
    const t = new DataTransfer();
    t.items.add(new File([new TextEncoder().encode('hello')], 'notes.txt'));
    window.dispatchEvent(new DragEvent('drop', { dataTransfer: t, cancelable: true }));
  });
  await page.waitForFunction(() => /not a readable zip/.test(document.getElementById('problem-list').textContent));
  await page.setInputFiles('#picker', path.join(fixtures, 'valid.zip'));
  await page.waitForSelector('#summary:not([hidden])');
  assert.deepEqual(errors, []);
  // No request leaves the page's own origin.
  assert.ok(requests.every((u) => u.startsWith(env.base)), requests.join('\n'));
  await page.close();
});

test('a Content-Security-Policy runs only the page\'s own code and connects only to its origin and the ?url= given', async () => {
  const { page, errors, requests } = await openPage('?url=fixtures/valid.zip');
  await page.waitForSelector('#summary:not([hidden])');
  assert.deepEqual(await cspViolations(page), []);
  assert.equal(await page.getAttribute('body', 'data-connect-src'), "connect-src 'self' blob:");
  // Enforced, not only written: an injected inline script and a request to another
  // origin (this server under another name; no-cors, which nothing but the policy
  // stops) are refused.
  const other = env.base.replace('127.0.0.1', 'localhost');
  const r = await page.evaluate(async (other) => {
    const s = document.createElement('script');
    s.textContent = 'window.inlineRan = true';
    document.head.append(s);
    const inlineRan = window.inlineRan === true;
    let fetched = false;
    try { await fetch(`${other}/fixtures/valid.zip`, { mode: 'no-cors' }); fetched = true; } catch { /* refused */ }
    return { inlineRan, fetched };
  }, other);
  assert.deepEqual(r, { inlineRan: false, fetched: false });
  await page.waitForFunction(() => window.cspViolations.length >= 2);
  const v = await cspViolations(page);
  assert.ok(v.some((x) => x.startsWith('connect-src') && x.includes('localhost')), v.join('\n'));
  assert.ok(v.some((x) => x.startsWith('script-src')), v.join('\n'));
  assert.ok(requests.every((u) => u.startsWith(env.base)), requests.join('\n'));
  assert.deepEqual(errors, []);
  await page.close();

  // A ?url= on another server is allowed, and only that server.
  const o = await openPage(`?url=${other}/fixtures/valid.zip`);
  await o.page.waitForSelector('#summary:not([hidden])');
  assert.equal(await o.page.getAttribute('body', 'data-connect-src'), `connect-src 'self' blob: ${other}`);
  assert.deepEqual(await cspViolations(o.page), []);
  assert.ok(o.requests.every((u) => u.startsWith(env.base) || u.startsWith(other)), o.requests.join('\n'));
  await o.page.close();
});

test('?url= loads a bundle from the server; a bad address is explained', async () => {
  const { page } = await openPage('?url=fixtures/valid.zip');
  await page.waitForSelector('#summary:not([hidden])');
  assert.equal(await page.textContent('dd[data-fact="frames"]'), '3 (3 views, 0.2 s)');
  await page.close();
  const bad = await openPage('?url=fixtures/missing.zip');
  await bad.page.waitForFunction(() => /Could not download/.test(document.getElementById('status').textContent));
  assert.match(await bad.page.textContent('#status'), /404/);
  await bad.page.close();
});

test('the example button opens the built-in example', async () => {
  const { page } = await openPage();
  await page.click('#example');
  await page.waitForSelector('#summary:not([hidden])');
  assert.equal(await page.textContent('#summary-title'), 'tiny example');
  await page.close();
});

test('the demo button opens the demo scene', async () => {
  const { page, errors } = await openPage();
  await page.click('#demo');
  await page.waitForSelector('#summary:not([hidden])');
  assert.match(await page.textContent('#summary-title'), /synthetic/);
  assert.match(await page.textContent('#classes'), /crosswalk/);
  assert.deepEqual(errors, []);
  await page.close();
});

test('the demo optimises in the page; layers, pan, zoom and exports work; errors keep it alive', async () => {
  const { page, errors, requests } = await openPage();
  await page.click('#demo');
  await page.waitForSelector('#optimise:not([hidden])');
  await page.selectOption('#set-resolution', '0.2');
  await page.fill('#set-epochs', '10');
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 170_000 });
  assert.ok(Number(await page.getAttribute('body', 'data-steps')) > 0, 'steps ran');
  assert.match(await page.textContent('#status'), /Map ready/);
  assert.match(await page.textContent('#progress-text'), /ETA/);
  assert.ok(Number(await page.getAttribute('body', 'data-previews')) >= 1, 'the map updated live');
  // The camera-view panel shows the rendered view beside the input image.
  await page.waitForFunction(() => document.getElementById('cam-rendered').width > 1);
  assert.equal(await page.getAttribute('#cam-rendered', 'width'), await page.getAttribute('#cam-input', 'width'));
  await page.check('[data-layer="trajectory"]');
  assert.equal(await page.getAttribute('#map', 'data-renderer'), 'webgpu');
  await page.screenshot({ path: path.join(shots, 'map.png'), fullPage: true });
  // Layers toggle.
  await page.check('[data-layer="elevation"]');
  await page.uncheck('[data-layer="rgb"]');
  await page.screenshot({ path: path.join(shots, 'map-elevation.png') });
  // Zoom and pan change the view.
  const before = await page.getAttribute('#map', 'data-view');
  await page.locator('#map').scrollIntoViewIfNeeded();
  const box = await page.locator('#map').boundingBox();
  await page.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
  // The value under the cursor with its x, y in the map frame, and a scale bar.
  await page.waitForFunction(() => /^x -?\d+\.\d\d m, y -?\d+\.\d\d m · elevation/.test(document.getElementById('cursor').textContent));
  const bar = Number(await page.getAttribute('#map-scale', 'data-metres'));
  assert.ok(bar > 0, `scale bar ${bar} m`);
  await page.mouse.wheel(0, -300);
  const zoomed = await page.getAttribute('#map', 'data-view');
  assert.notEqual(zoomed, before);
  await page.mouse.down();
  await page.mouse.move(box.x + box.width / 2 + 60, box.y + box.height / 2 + 20);
  await page.mouse.up();
  assert.notEqual(await page.getAttribute('#map', 'data-view'), zoomed);
  // The exported PNG decodes with the map's size.
  const size = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'rgb.png');
    const bmp = await createImageBitmap(await (await fetch(a.href)).blob());
    const report = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    const r = await (await fetch(report.href)).json();
    return [bmp.width, bmp.height, r.bev.width, r.bev.height, r.timings.gpu_setup_pipelines];
  });
  assert.deepEqual(size.slice(0, 2), size.slice(2, 4));
  assert.ok(size[0] > 10);
  // The run's device was warmed when the demo was accepted: its set-up compiled no
  // pipeline (SwiftShader's 4-5 s), and the next run's is warmed after it.
  assert.equal(size[4], 0, 'pipelines compiled by the set-up');
  await page.waitForFunction(() => Number(document.body.dataset.gpuWarmS) > 0);
  // Every export in one zip.
  await page.click('#exports-zip');
  const zip = await page.evaluate(async () => {
    const b = new Uint8Array(await (await fetch(document.getElementById('exports-zip').href)).arrayBuffer());
    return [b[0], b[1], b.length, new TextDecoder().decode(b).includes('elevation.tif')];
  });
  assert.deepEqual(zip.slice(0, 2), [0x50, 0x4b], 'a zip');
  assert.ok(zip[3], 'holds elevation.tif');
  // The run's own map in review: a frame clicked on its trajectory shows this run's
  // camera view in the panel.
  await page.click('#review-run');
  await page.waitForSelector('#review:not([hidden])');
  const t = await page.evaluate(() => window.rogsReview.state.a.map.index.trajectory[3]);
  const [sx, sy] = await page.evaluate(([x, y]) => {
    const c = document.getElementById('review-map');
    c.scrollIntoView({ block: 'nearest' });
    const r = c.getBoundingClientRect();
    const [a, b] = window.rogsReview.toScreen(x, y);
    return [r.left + a * (r.width / c.width), r.top + b * (r.height / c.height)];
  }, t);
  await page.mouse.click(sx, sy);
  await page.waitForFunction(() => document.getElementById('review-frame').dataset.frame === '3');
  assert.equal(await page.inputValue('#cam-frame'), '3');
  // and the map file's stored thumbnail of that frame's input image.
  await page.waitForSelector('#review-thumb-box:not([hidden])');
  assert.equal(await page.getAttribute('#review-thumb-box', 'data-frame'), '3');
  assert.ok(await page.evaluate(() => document.getElementById('review-thumb').naturalWidth === 320 || new Promise((r) => document.getElementById('review-thumb').onload = () => r(document.getElementById('review-thumb').naturalWidth === 320))));
  // A bad bundle afterwards is named, and the page keeps working.
  await drop(page, 'invalid.zip');
  await page.waitForSelector('#problems:not([hidden])');
  assert.equal(await page.isHidden('#optimise'), true);
  await drop(page, 'valid.zip');
  await page.waitForSelector('#summary:not([hidden])');
  assert.deepEqual(errors, []);
  // Only the page's own assets, and the in-memory blobs of the exports.
  assert.ok(requests.every((u) => u.startsWith(env.base) || u.startsWith(`blob:${env.base}`)), requests.join('\n'));
  await page.close();
});

test('the map is trained tile by tile in the page; a tile the machine fails is trained again', async () => {
  // ?fault_tile=1: the second tile fails once as a lost device would.
  const { page, errors } = await openPage('?fault_tile=1');
  await page.click('#demo');
  await page.waitForSelector('#optimise:not([hidden])');
  await page.selectOption('#set-resolution', '0.2');
  await page.fill('#set-tile', '4');
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 170_000 });
  assert.match(await page.textContent('#status'), /Map ready/);
  assert.ok(Number(await page.getAttribute('body', 'data-tiles')) > 1, 'several tiles');
  assert.equal(await page.getAttribute('body', 'data-retries'), '1', 'the failed tile was retried once');
  const r = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    return (await fetch(a.href)).json();
  });
  assert.equal(r.tiling.size_m, 4);
  assert.equal(r.stopped, null, 'the retried tile finished');
  assert.ok(r.tile_count > 1, JSON.stringify(r.tiles));
  assert.ok(r.tiles.filter((t) => t.steps > 0).length > 1, 'several tiles trained');
  assert.ok(r.seams.border_pairs > 0);
  assert.ok(r.metrics.psnr_db > 10, JSON.stringify(r.metrics));
  // The elevation without the poses' shared offset and tilt, beside the absolute one.
  const d = r.metrics.elevation_datum;
  assert.ok(d && d.rmse_m <= r.metrics.elevation_rmse_m + 1e-9, JSON.stringify(r.metrics));
  assert.match(await page.textContent('#metrics'), /cm without the poses' shared offset and tilt/);
  await page.screenshot({ path: path.join(shots, 'map-tiled.png'), fullPage: true });
  assert.deepEqual(errors, []);
  await page.close();
});

test('every setting of rogs reconstruct is in the page and reaches the run; a bad one is refused in words', async () => {
  const { page, errors } = await openPage();
  await page.click('#demo');
  await page.waitForSelector('#optimise:not([hidden])');
  await page.selectOption('#set-resolution', '0.2');
  // The advanced settings open and are reached by keyboard.
  await page.focus('#advanced summary');
  await page.keyboard.press('Enter');
  assert.equal(await page.getAttribute('#advanced', 'open'), '');
  await page.fill('#set-lr-z-start', '0');
  await page.click('#run');
  await page.waitForFunction(() => /Could not start: lr_z_start 0: expected a positive number/.test(document.getElementById('status').textContent));
  assert.equal(await page.isDisabled('#run'), false, 'the page stays usable');
  await page.fill('#set-lr-z-start', '0.002');
  await page.fill('#set-lr-z-end', '0.00002');
  await page.fill('#set-lidar-gate', '0.7');
  await page.fill('#set-lidar-band', '0.3');
  await page.fill('#set-max-steps', '12');
  await page.fill('#set-seed', '5');
  await page.fill('#set-holdout', '4');
  await page.uncheck('#set-traj');
  await page.uncheck('#set-frame-exposure');
  await page.selectOption('#set-adam', 'selective');
  await page.check('#set-refine-poses');
  await page.check('#set-pose-rig');
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 170_000 });
  assert.match(await page.textContent('#status'), /Map ready/);
  const r = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    return (await fetch(a.href)).json();
  });
  const t = r.settings.train;
  assert.ok(r.steps > 0 && r.steps <= 12, String(r.steps));
  assert.equal(t.max_steps, 12);
  assert.equal(t.seed, 5);
  assert.equal(t.holdout_every, 4);
  assert.ok(r.holdout_views > 0, 'frames were held out');
  assert.equal(t.loss.traj, 0);
  assert.equal(t.adam, 'selective');
  assert.equal(t.frame_exposure, false);
  assert.equal(r.frame_gains, null, 'no frame gains were measured');
  assert.ok(r.pose_refinement && r.pose_refinement.rig, 'camera mountings were refined: ' + JSON.stringify(r.pose_refinement));
  assert.ok(Math.abs(t.loss.lidar_gate_m - 0.7) < 1e-6 && Math.abs(t.loss.lidar_band_m - 0.3) < 1e-6, JSON.stringify(t.loss));
  assert.ok(Math.abs(t.lr.z_start - 0.002) < 1e-9 && Math.abs(t.lr.z_end - 0.00002) < 1e-9, JSON.stringify(t.lr));
  assert.deepEqual(errors, []);
  await page.close();
});

test('a bundle read lazily (?lazy=1) trains tile by tile holding one tile\'s files', async () => {
  const { page, errors } = await openPage('?lazy=1');
  await drop(page, 'demo.zip');
  await page.waitForSelector('body[data-lazy="true"]');
  assert.match(await page.textContent('#status'), /read lazily/);
  await page.selectOption('#set-resolution', '0.2');
  await page.fill('#set-tile', '4');
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 170_000 });
  assert.match(await page.textContent('#status'), /Map ready/);
  const size = (await import('node:fs')).statSync(path.join(fixtures, 'demo.zip')).size;
  const peak = Number(await page.getAttribute('body', 'data-held-peak'));
  assert.ok(peak > 0 && peak < size, `held at most ${peak} bytes of a ${size}-byte bundle`);
  const r = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    return (await fetch(a.href)).json();
  });
  assert.ok(r.tile_count > 1 && r.metrics.psnr_db > 10, JSON.stringify(r.metrics));
  // A damaged bundle read lazily is refused by name.
  await drop(page, 'invalid.zip');
  await page.waitForFunction(() => /not a valid bundle/.test(document.getElementById('status').textContent));
  assert.deepEqual(errors, []);
  await page.close();
});

test('the rasteriser benchmark runs in the page (scripts/bench-raster-page.mjs)', async () => {
  const { page, errors } = await openPage();
  const json = await page.evaluate(async () => {
    const m = await import('/pkg/rogs.js');
    await m.default();
    const bytes = new Uint8Array(await (await fetch('/demo/demo.zip')).arrayBuffer());
    return m.bench_raster(bytes, 3, 0, 1, 0.1);
  });
  const r = JSON.parse(json);
  assert.ok(r.surfels_in_view > 100 && r.surfels_in_view < r.surfels_total, json);
  assert.ok(r.pixel_surfel_pairs > 0 && r.forward_s > 0 && r.forward_backward_s > 0, json);
  // A frame the bundle does not have is refused in words.
  await assert.rejects(page.evaluate(async () => {
    const m = await import('/pkg/rogs.js');
    const bytes = new Uint8Array(await (await fetch('/demo/demo.zip')).arrayBuffer());
    return m.bench_raster(bytes, 100000, 0, 1, 0.1);
  }), /no frame 100000/);
  assert.deepEqual(errors, []);
  await page.close();
});

test('two drives dropped together make one map', async () => {
  const { page, errors } = await openPage();
  await dropMany(page, [['valid.zip', 'a.zip'], ['valid.zip', 'b.zip']]);
  await page.waitForSelector('body[data-drives="2"]');
  assert.match(await page.textContent('dd[data-fact="drives"]'), /a\.zip \(3 frames.*\+ b\.zip/);
  assert.match(await page.textContent('#status'), /2 drives ready/);
  await page.selectOption('#set-resolution', '0.2');
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 170_000 });
  const drives = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    return (await (await fetch(a.href)).json()).drives;
  });
  assert.deepEqual(drives.map((d) => d.name), ['a.zip', 'b.zip']);
  assert.deepEqual(errors, []);
  await page.close();
});

test('a drive without labels makes a map without a semantic layer', async () => {
  const { page, errors } = await openPage();
  await drop(page, 'unlabelled.zip');
  await page.waitForSelector('#summary:not([hidden])');
  assert.match(await page.textContent('#no-labels'), /No labels: a drive without masks/);
  await page.waitForSelector('#optimise:not([hidden])');
  await page.selectOption('#set-resolution', '0.2');
  await page.click('#run');
  await page.waitForSelector('#viewer:not([hidden]) #exports a', { timeout: 170_000 });
  const names = await page.evaluate(() => [...document.querySelectorAll('#exports a')].map((a) => a.download));
  assert.ok(names.includes('rgb.png') && names.includes('elevation.tif'), names.join(' '));
  assert.ok(!names.some((n) => n.startsWith('semantic') || n === 'surfels_semantic.ply'), names.join(' '));
  assert.equal(await page.locator('[data-layer="semantic"]').count(), 0, 'no semantic layer to show');
  assert.equal(await page.locator('[data-layer="rgb"]').count(), 1);
  const miou = await page.evaluate(async () => {
    const a = [...document.querySelectorAll('#exports a')].find((x) => x.download === 'report.json');
    return (await (await fetch(a.href)).json()).metrics.miou;
  });
  assert.equal(miou, null);
  assert.deepEqual(errors, []);
  await page.close();
});
