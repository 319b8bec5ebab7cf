// Map review in headless Chromium: map files open by drop and by ?map= (read by range
// requests, a map wider than any texture included), A/B swipe, side by side,
// difference layers and the overlap summary against values known by construction,
// a profile's plotted values against the map's elevation read natively, the URL
// round trip and the back button, keys, and damaged map files named.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { env, useBrowser, openPage, drop, fixtures, shots } from './harness.mjs';

useBrowser();

const points = () => JSON.parse(fs.readFileSync(path.join(fixtures, 'points.json'), 'utf8'));

// Waits until no tile is loading and the last frame has been drawn.
async function settle(page) {
  await page.waitForFunction(() => window.rogsReview && window.rogsReview.pending() === 0, null, { timeout: 60_000 });
  await page.evaluate(() => new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(r))));
  await page.waitForFunction(() => window.rogsReview.pending() === 0, null, { timeout: 60_000 });
}

// Page coordinates of world (x, y) on the review canvas (A's pane).
async function at(page, x, y) {
  return page.evaluate(([x, y]) => {
    const c = document.getElementById('review-map');
    c.scrollIntoView({ block: 'nearest' });
    const r = c.getBoundingClientRect();
    const [sx, sy] = window.rogsReview.toScreen(x, y);
    return [r.left + sx * (r.width / c.width), r.top + sy * (r.height / c.height)];
  }, [x, y]);
}

async function inspectAt(page, x, y) {
  await page.evaluate(() => { document.getElementById('review-inspect').dataset.values = ''; });
  const [px, py] = await at(page, x, y);
  await page.mouse.move(px, py);
  await page.waitForFunction(() => document.getElementById('review-inspect').dataset.values, null, { timeout: 30_000 });
  return {
    text: await page.textContent('#review-inspect'),
    values: JSON.parse(await page.getAttribute('#review-inspect', 'data-values')),
  };
}

// Moves a range input as a person would: input events while dragging, change at the end.
async function setRange(page, sel, value) {
  await page.$eval(sel, (el, v) => {
    el.value = v;
    el.dispatchEvent(new Event('input', { bubbles: true }));
    el.dispatchEvent(new Event('change', { bubbles: true }));
  }, String(value));
}

// Canvas pixel (RGBA) at world (x, y).
async function canvasPixel(page, x, y) {
  return page.evaluate(([x, y]) => {
    const [sx, sy] = window.rogsReview.toScreen(x, y);
    return [...document.getElementById('review-map').getContext('2d').getImageData(Math.round(sx), Math.round(sy), 1, 1).data];
  }, [x, y]);
}

test('a dropped map opens in review without re-running: values under the cursor, class areas', async () => {
  const { page, errors } = await openPage();
  await drop(page, 'truth.rogsmap');
  await page.waitForSelector('#review:not([hidden])');
  await settle(page);
  assert.match(await page.textContent('#status'), /demo truth: 747×288 px at 0\.05 m \(3 levels\), read tile by tile/);
  assert.equal(await page.isHidden('#optimise'), true, 'a map needs no optimisation');
  for (const p of points()) {
    const { text, values } = await inspectAt(page, p.x, p.y);
    assert.ok(Math.abs(values.elevation - p.z) < 1e-6, `elevation at (${p.x}, ${p.y}): ${values.elevation} vs ${p.z}`);
    assert.match(text, /class (road|lane_marking|crosswalk|stop_line|manhole)/);
  }
  const off = await inspectAt(page, 15.0, 6.0);
  assert.match(off.text, /nothing mapped here/);
  const classes = await page.$$eval('#review-classes tbody tr', (rows) => rows.map((r) => r.dataset.class));
  assert.ok(classes.includes('road') && classes.includes('lane_marking'), classes.join(','));
  const road = await page.textContent('#review-classes tr[data-class="road"]');
  assert.match(road, /\d+\.\d m²/);
  await page.screenshot({ path: path.join(shots, 'review.png'), fullPage: true });
  assert.deepEqual(errors, []);
  await page.close();
});

test('?map= reads a map wider than a texture by range requests and shows it at full resolution', async () => {
  const { page, errors } = await openPage();
  const ranges = [];
  page.on('request', (r) => { if (new URL(r.url()).pathname.endsWith('big.rogsmap')) ranges.push(r.headers().range || 'whole'); });
  const got = [];
  page.on('response', async (r) => { if (new URL(r.url()).pathname.endsWith('big.rogsmap')) got.push(Number(r.headers()['content-length'] || 0)); });
  await page.goto(`${env.base}/?map=fixtures/big.rogsmap`);
  await page.waitForSelector('#review:not([hidden])', { timeout: 60_000 });
  await settle(page);
  const ix = await page.evaluate(() => window.rogsReview.state.a.map.index);
  assert.ok(ix.width > 16384, `the map must be wider than a texture: ${ix.width}`);
  const first = Number(await page.getAttribute('#review-map', 'data-first-view-ms'));
  assert.ok(first > 0, 'the first view was drawn');
  // Zoom to level 0 in the middle of the drive: the full-resolution tiles there.
  const mid = ix.trajectory[Math.floor(ix.trajectory.length / 2)];
  await page.evaluate(([x, y]) => window.rogsReview.setView(x, y, 0.05), mid);
  await settle(page);
  assert.equal(await page.getAttribute('#review-map', 'data-level'), '0');
  const { values } = await inspectAt(page, mid[0], mid[1]);
  assert.ok(Number.isFinite(values.elevation) && values.class !== undefined, JSON.stringify(values));
  const px = await canvasPixel(page, mid[0], mid[1]);
  assert.ok(px[0] + px[1] + px[2] > 60, `the road is drawn at full resolution: ${px}`);
  const size = fs.statSync(path.join(fixtures, 'big.rogsmap')).size;
  assert.ok(ranges.every((r) => r.startsWith('bytes=')), ranges.join(' '));
  const read = got.reduce((s, v) => s + v, 0);
  assert.ok(read < 0.3 * size, `read ${read} of ${size} bytes`);
  await page.screenshot({ path: path.join(shots, 'review-big.png') });
  assert.deepEqual(errors, []);
  await page.close();
});

test('A/B: swipe, side by side, difference layers and the overlap summary', async () => {
  const { page, errors } = await openPage('?map=fixtures/truth.rogsmap&b=fixtures/raised.rogsmap');
  await page.waitForSelector('#review-compare:not([hidden]) dd[data-fact="rmse"]', { timeout: 60_000 });
  const s = JSON.parse(await page.getAttribute('#review-compare', 'data-summary'));
  // B is A with every elevation 3 cm higher: the summary must say exactly that.
  assert.ok(Math.abs(s.elevation_rmse_m - 0.03) < 1e-4, `RMSE ${s.elevation_rmse_m}`);
  assert.equal(s.class_agreement, 1);
  assert.ok(s.psnr_db > 100, `identical colours: ${s.psnr_db} dB`);
  assert.ok(s.overlap_m2 > 200 && s.overlap_m2 < 747 * 288 * 0.0025, `overlap ${s.overlap_m2} m²`);
  assert.equal(s.level, 0);
  assert.match(await page.textContent('dd[data-fact="rmse"]'), /3\.00 cm/);
  // Swipe: left of the divider is A, right of it B (3 cm higher).
  await page.check('input[name="review-mode"][value="swipe"]');
  await setRange(page, '#review-swipe', 0.5);
  await settle(page);
  const [p0, p1] = [points()[0], points()[2]];
  const [sx0] = await at(page, p0.x, p0.y);
  const [sx1] = await at(page, p1.x, p1.y);
  const mid = await page.evaluate(() => { const c = document.getElementById('review-map'); const r = c.getBoundingClientRect(); return r.left + r.width / 2; });
  assert.ok(sx0 < mid && sx1 > mid, 'one point each side of the divider');
  const left = await inspectAt(page, p0.x, p0.y);
  const right = await inspectAt(page, p1.x, p1.y);
  assert.match(left.text, /^A ·/);
  assert.match(right.text, /^B ·/);
  assert.ok(Math.abs(right.values.elevation - (p1.z + 0.03)) < 1e-5, `${right.values.elevation} vs ${p1.z} + 0.03`);
  await page.screenshot({ path: path.join(shots, 'review-swipe.png') });
  // Elevation difference: +3 cm on a ±5 cm scale is red-orange where both are mapped.
  await page.check('input[name="review-mode"][value="single"]');
  await page.selectOption('#review-diff', 'elevation');
  await settle(page);
  const d = await canvasPixel(page, p0.x, p0.y);
  assert.ok(d[0] > 200 && d[0] > d[2] + 60, `B − A = +3 cm is drawn red: ${d}`);
  await page.selectOption('#review-diff', 'class');
  await settle(page);
  const c = await canvasPixel(page, p0.x, p0.y);
  assert.ok(!(c[0] > 200 && c[1] < 80 && c[2] > 150), `no class changes: ${c}`);
  // Side by side: the right half shows B.
  await page.selectOption('#review-diff', '');
  await page.check('input[name="review-mode"][value="side"]');
  await settle(page);
  const w = await page.evaluate(() => { const c = document.getElementById('review-map'); c.scrollIntoView({ block: 'nearest' }); return c.getBoundingClientRect().toJSON(); });
  const side = await (async () => {
    await page.evaluate(() => { document.getElementById('review-inspect').dataset.values = ''; });
    await page.mouse.move(w.left + w.width * 0.75, w.top + w.height / 2);
    await page.waitForFunction(() => document.getElementById('review-inspect').dataset.values);
    return page.textContent('#review-inspect');
  })();
  assert.match(side, /^B ·/);
  await page.screenshot({ path: path.join(shots, 'review-side.png') });
  assert.deepEqual(errors, []);
  await page.close();
});

test('a profile plots the map elevation at its points; distances are measured', async () => {
  const { page, errors } = await openPage('?map=fixtures/truth.rogsmap');
  await page.waitForSelector('#review:not([hidden])');
  await settle(page);
  await page.check('input[name="review-tool"][value="profile"]');
  const pts = points();
  for (const p of pts) {
    const [x, y] = await at(page, p.x, p.y);
    await page.mouse.click(x, y);
  }
  await page.waitForFunction((n) => {
    const v = document.getElementById('review-profile-plot').dataset.profile;
    return v && JSON.parse(v).length === n && JSON.parse(v).every((s) => s.z !== null);
  }, pts.length, { timeout: 30_000 });
  const prof = JSON.parse(await page.getAttribute('#review-profile-plot', 'data-profile'));
  // Clicks land on whole screen pixels: compare with the map at the clicked points.
  for (const [i, v] of prof.entries()) {
    const z = await page.evaluate(([x, y]) => window.rogsReview.elevationAt(x, y), [v.x, v.y]);
    assert.equal(v.z, z);
    assert.ok(Math.abs(v.x - pts[i].x) < 0.2 && Math.abs(v.y - pts[i].y) < 0.2);
    // Against the native read of the same tile: the road's grade over a click's
    // rounding (a few cm) is a millimetre or two.
    assert.ok(Math.abs(v.z - pts[i].z) < 0.005, `profile ${v.z} vs map ${pts[i].z}`);
  }
  assert.ok(Number(await page.getAttribute('#review-profile-plot', 'data-samples')) > 50);
  await page.screenshot({ path: path.join(shots, 'review-profile.png'), fullPage: true });
  await page.check('input[name="review-tool"][value="measure"]');
  const [a, b] = [[20, -1.75], [30, -1.75]];
  for (const p of [a, b]) { const [x, y] = await at(page, ...p); await page.mouse.click(x, y); }
  const len = Number(await page.getAttribute('#review-measure', 'data-length'));
  assert.ok(Math.abs(len - 10) < 0.15, `10 m measured as ${len}`);
  await page.keyboard.press('Escape');
  assert.equal(await page.textContent('#review-measure'), '');
  assert.deepEqual(errors, []);
  await page.close();
});

test('the URL holds maps, layers and view; a link reopens it; keys pan and zoom; back works', async () => {
  const { page, errors } = await openPage('?map=fixtures/truth.rogsmap');
  await page.waitForSelector('#review:not([hidden])');
  await settle(page);
  const v0 = await page.getAttribute('#review-map', 'data-view');
  await page.focus('#review-map');
  await page.keyboard.press('ArrowRight');
  await page.keyboard.press('+');
  await settle(page);
  const v1 = (await page.getAttribute('#review-map', 'data-view')).split(',').map(Number);
  const [x0, , m0] = v0.split(',').map(Number);
  assert.ok(v1[0] > x0 && v1[2] < m0, `pan right and zoom in: ${v0} → ${v1}`);
  await page.keyboard.press('0');
  await settle(page);
  assert.equal(await page.getAttribute('#review-map', 'data-view'), v0, '0 fits the map again');
  await page.keyboard.press('-');
  await page.check('#review-layers [data-layer="semantic"]');
  await setRange(page, '#review-layers [data-opacity="semantic"]', 0.5);
  await page.waitForTimeout(400); // the view's URL update is debounced
  const url = page.url();
  assert.match(url, /map=fixtures%2Ftruth\.rogsmap/);
  assert.match(url, /layers=[^&]*semantic%3A0\.5/);
  const view = await page.getAttribute('#review-map', 'data-view');
  const again = await openPage(url.slice(env.base.length + 1));
  await again.page.waitForSelector('#review:not([hidden])');
  await settle(again.page);
  assert.equal(await again.page.getAttribute('#review-map', 'data-view'), view);
  assert.equal(await again.page.isChecked('#review-layers [data-layer="semantic"]'), true);
  assert.equal(await again.page.inputValue('#review-layers [data-opacity="semantic"]'), '0.5');
  await again.page.close();
  // Back: before the opacity change, then before the semantic layer was shown.
  await page.goBack();
  await page.goBack();
  await page.waitForFunction(() => !document.querySelector('#review-layers [data-layer="semantic"]').checked);
  assert.deepEqual(errors, []);
  await page.close();
});

test('damaged map files are named and the page stays usable', async () => {
  const { page, errors } = await openPage();
  await drop(page, 'bad-format.rogsmap');
  await page.waitForSelector('#map-problems:not([hidden])');
  assert.match(await page.textContent('#map-problem-list'), /map\.json: format.*found "rogs-bundle", expected "rogs-map"/s);
  await drop(page, 'truncated.rogsmap');
  await page.waitForFunction(() => /not a zip archive/.test(document.getElementById('map-problem-list').textContent));
  const bad = await openPage('?map=fixtures/missing.rogsmap');
  await bad.page.waitForSelector('#map-problems:not([hidden])');
  assert.match(await bad.page.textContent('#map-problem-list'), /404/);
  await bad.page.close();
  await page.screenshot({ path: path.join(shots, 'review-problems.png'), fullPage: true });
  await drop(page, 'truth.rogsmap');
  await page.waitForSelector('#review:not([hidden])');
  assert.equal(await page.isHidden('#map-problems'), true);
  assert.deepEqual(errors, []);
  await page.close();
});
