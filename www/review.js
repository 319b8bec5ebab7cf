// Map review: opens finished maps (.rogsmap) without the engine, draws them tile by
// tile from their pyramids (only the tiles in view are read, at the level the zoom
// needs), compares two (swipe, side by side, difference layers, a summary of the
// overlap), and inspects them: values under the cursor, scale bar, distance,
// elevation profile, area per class, error histogram, trajectory frames. The view
// lives in the URL, so a link reopens it; keys pan and zoom.
import { blobSource, urlSource, openMap, MapError, isPresent, tilesOf, tileSize } from './rogsmap.js';

const $ = (id) => document.getElementById(id);
const LAYERS = ['rgb', 'semantic', 'elevation', 'confidence', 'density', 'error'];
const DIFF = { elevation: 'elevation difference', class: 'class changes', colour: 'colour difference' };
const CACHE_TILES = 600; // decoded tiles kept (about 150 MiB at most)
const MAX_LOADS = 8; // tile reads in flight

const rv = {
  a: null, b: null, // { map, url }
  mode: 'single', swipe: 0.5, diff: '', diffScale: 0.05, tool: 'inspect',
  layers: { rgb: { on: true, op: 1 }, trajectory: { on: true, op: 1 } },
  view: { cx: 0, cy: 0, mpp: 1 },
  points: [], profile: null, frame: null,
  stats: { draws: 0, tilesDrawn: 0, loads: 0, level: 0, firstViewMs: null, openedAt: 0 },
};
let setStatus = () => {};
let frameViewer = null; // (frame) => Promise<void>, set by the optimiser for its own run
// Least recently used first: a Map keeps insertion order, and a use re-inserts.
const cache = new Map(); // key → { v }
const loading = new Map(); // key → Promise
const queue = [];
let inflight = 0;
let drawQueued = false;

// ---- tiles: cached, loaded a few at a time, newest requests first -----------------
function cached(key) {
  const e = cache.get(key);
  if (!e) return undefined;
  cache.delete(key);
  cache.set(key, e);
  return e.v;
}
function remember(key, v) {
  cache.set(key, { v });
  while (cache.size > CACHE_TILES) {
    const [k, e] = cache.entries().next().value;
    e.v?.close?.();
    cache.delete(k);
  }
}
function pump() {
  while (inflight < MAX_LOADS && queue.length) {
    const job = queue.pop();
    inflight++;
    job.run().finally(() => { inflight--; pump(); });
  }
}
// Loads `key` with `fn` once; resolves to its value. `urgent` jobs jump the queue.
function load(key, fn) {
  if (cache.has(key)) return Promise.resolve(cached(key));
  if (loading.has(key)) return loading.get(key);
  const p = new Promise((resolve) => {
    queue.push({
      run: async () => {
        let v = null;
        try { v = await fn(); } catch (e) { reportTileError(e); }
        rv.stats.loads++;
        remember(key, v);
        loading.delete(key);
        resolve(v);
        requestDraw();
      },
    });
  });
  loading.set(key, p);
  pump();
  return p;
}
const shownErrors = new Set();
function reportTileError(e) {
  const msg = e instanceof MapError ? e.problems.map((p) => p.message).join('; ') : String(e.message || e);
  if (shownErrors.has(msg)) return;
  shownErrors.add(msg);
  setStatus(`Part of the map cannot be shown: ${msg}`, 'error');
}

const mapKey = (m) => (m === rv.a?.map ? 'a' : 'b');
const tileKey = (m, layer, k, c, r) => `${mapKey(m)}:${layer}:${k}:${c}:${r}`;
const valuesOf = (m, name, k, c, r) => load(`${mapKey(m)}:v:${name}:${k}:${c}:${r}`, () => m.values(name, k, c, r));
async function pixelsOf(m, layer, k, c, r) {
  return load(`${mapKey(m)}:px:${layer}:${k}:${c}:${r}`, async () => {
    const bmp = await m.tile(layer, k, c, r);
    if (!bmp) return null;
    const cv = new OffscreenCanvas(bmp.width, bmp.height);
    const g = cv.getContext('2d', { willReadFrequently: true });
    g.drawImage(bmp, 0, 0);
    bmp.close();
    return g.getImageData(0, 0, cv.width, cv.height).data;
  });
}

// ---- geometry -----------------------------------------------------------------------
// Panes: one (single, swipe) or two halves (side by side), each with its own centre.
function panes(canvas) {
  const { width: W, height: H } = canvas;
  if (rv.mode === 'side' && rv.b) {
    return [{ map: rv.a.map, x: 0, w: W / 2, h: H, clip: [0, W / 2] }, { map: rv.b.map, x: W / 2, w: W / 2, h: H, clip: [W / 2, W] }];
  }
  return [{ map: rv.a.map, x: 0, w: W, h: H, clip: [0, W] }];
}
function toScreen(p, x, y) {
  const v = rv.view;
  return [p.x + p.w / 2 + (x - v.cx) / v.mpp, p.h / 2 - (y - v.cy) / v.mpp];
}
function toWorld(p, sx, sy) {
  const v = rv.view;
  return [v.cx + (sx - p.x - p.w / 2) * v.mpp, v.cy - (sy - p.h / 2) * v.mpp];
}
function paneAt(canvas, sx) {
  const ps = panes(canvas);
  return ps.find((p) => sx >= p.clip[0] && sx < p.clip[1]) || ps[0];
}
// The map a reviewer sees at screen x: B right of the swipe divider or in the right pane.
function mapAt(canvas, sx) {
  if (rv.mode === 'swipe' && rv.b && sx >= rv.swipe * canvas.width) return rv.b.map;
  return paneAt(canvas, sx).map;
}
const levelFor = (ix) => Math.max(0, Math.min(ix.levels - 1, Math.floor(Math.log2(rv.view.mpp / ix.resolution) + 1e-9)));

// Level-0 pixel of world (x, y) in a map, or null outside it.
function pixelOf(ix, x, y, k = 0) {
  const rk = ix.resolution * 2 ** k;
  const i = Math.floor((x - ix.origin[0]) / rk), j = Math.floor((ix.origin[1] - y) / rk);
  const [w, h] = [Math.ceil(ix.width / 2 ** k), Math.ceil(ix.height / 2 ** k)];
  return i >= 0 && j >= 0 && i < w && j < h ? [i, j] : null;
}

// ---- drawing ------------------------------------------------------------------------
export function requestDraw() {
  if (drawQueued) return;
  drawQueued = true;
  requestAnimationFrame(() => { drawQueued = false; draw(); });
}

function visibleTiles(m, p, k) {
  const ix = m.index;
  const rk = ix.resolution * 2 ** k, span = 256 * rk;
  const [x0, y1] = toWorld(p, p.x, 0), [x1, y0] = toWorld(p, p.x + p.w, p.h);
  const [tx, ty] = tilesOf(ix, k);
  const c0 = Math.max(0, Math.floor((x0 - ix.origin[0]) / span)), c1 = Math.min(tx - 1, Math.floor((x1 - ix.origin[0]) / span));
  const r0 = Math.max(0, Math.floor((ix.origin[1] - y1) / span)), r1 = Math.min(ty - 1, Math.floor((ix.origin[1] - y0) / span));
  const out = [];
  for (let r = r0; r <= r1; r++) for (let c = c0; c <= c1; c++) if (isPresent(ix, k, c, r)) out.push([c, r]);
  return out;
}

// Draws one layer of a map: the tiles of the zoom's level, and where one is still
// loading, the part of a coarser tile that covers it.
function drawLayer(g, m, p, layer, fetchTile) {
  const ix = m.index;
  const k = levelFor(ix);
  rv.stats.level = k;
  const rk = ix.resolution * 2 ** k;
  for (const [c, r] of visibleTiles(m, p, k)) {
    const [tw, th] = tileSize(ix, k, c, r);
    const wx = ix.origin[0] + c * 256 * rk, wy = ix.origin[1] - r * 256 * rk;
    const [sx0, sy0] = toScreen(p, wx, wy), [sx1, sy1] = toScreen(p, wx + tw * rk, wy - th * rk);
    const dx = Math.round(sx0), dy = Math.round(sy0), dw = Math.round(sx1) - dx, dh = Math.round(sy1) - dy;
    const key = tileKey(m, layer, k, c, r);
    const bmp = cached(key);
    if (bmp) { g.drawImage(bmp, dx, dy, dw, dh); rv.stats.tilesDrawn++; continue; }
    if (bmp === undefined) load(key, () => fetchTile(k, c, r));
    for (let d = 1; k + d < ix.levels; d++) {
      const pc = c >> d, pr = r >> d;
      const up = cached(tileKey(m, layer, k + d, pc, pr));
      if (!up) continue;
      const s = 256 / 2 ** d;
      g.drawImage(up, c * s - pc * 256, r * s - pr * 256, tw / 2 ** d, th / 2 ** d, dx, dy, dw, dh);
      break;
    }
  }
}

function drawTrajectory(g, m, p, colour) {
  const t = m.index.trajectory;
  if (!t.length) return;
  g.strokeStyle = colour;
  g.lineWidth = 2;
  g.beginPath();
  t.forEach(([x, y], i) => { const [sx, sy] = toScreen(p, x, y); if (i) g.lineTo(sx, sy); else g.moveTo(sx, sy); });
  g.stroke();
  g.fillStyle = colour;
  const every = Math.max(1, Math.ceil(12 * rv.view.mpp)); // a dot about every 12 px at 1 m per frame
  for (let i = 0; i < t.length; i += every) {
    const [sx, sy] = toScreen(p, t[i][0], t[i][1]);
    g.fillRect(sx - 1.5, sy - 1.5, 3, 3);
  }
  if (rv.frame !== null && t[rv.frame] && m === rv.a.map) {
    const [sx, sy] = toScreen(p, t[rv.frame][0], t[rv.frame][1]);
    g.strokeStyle = '#fff';
    g.beginPath(); g.arc(sx, sy, 7, 0, 2 * Math.PI); g.stroke();
  }
}

function drawMap(g, m, p, clip) {
  g.save();
  g.beginPath();
  g.rect(clip[0], 0, clip[1] - clip[0], p.h);
  g.clip();
  const magnified = rv.view.mpp < m.index.resolution;
  g.imageSmoothingEnabled = !magnified;
  for (const layer of LAYERS) {
    const l = rv.layers[layer];
    if (!l?.on || !m.index.layers.includes(layer)) continue;
    g.globalAlpha = l.op;
    drawLayer(g, m, p, layer, (k, c, r) => m.tile(layer, k, c, r));
  }
  if (rv.diff && rv.b && m === rv.a.map) {
    g.globalAlpha = rv.layers.diff?.op ?? 1;
    drawLayer(g, m, p, `diff-${rv.diff}-${rv.diffScale}`, (k, c, r) => diffTile(rv.diff, k, c, r));
  }
  g.globalAlpha = 1;
  if (rv.layers.trajectory?.on) drawTrajectory(g, m, p, m === rv.a.map ? '#ff3b30' : '#ffcc00');
  g.restore();
}

function niceLength(m) {
  const e = 10 ** Math.floor(Math.log10(m));
  return [5, 2, 1].map((f) => f * e).find((v) => v <= m) || e;
}

function drawOverlay(g, canvas) {
  // Scale bar, bottom left.
  const len = niceLength(120 * rv.view.mpp), px = len / rv.view.mpp;
  g.fillStyle = '#000a';
  g.fillRect(8, canvas.height - 30, px + 16, 22);
  g.fillStyle = '#fff';
  g.fillRect(16, canvas.height - 14, px, 3);
  g.font = '12px system-ui, sans-serif';
  g.fillText(len >= 1000 ? `${len / 1000} km` : len >= 1 ? `${len} m` : `${Math.round(len * 100)} cm`, 16, canvas.height - 18);
  // Measure or profile polyline.
  if (rv.points.length) {
    const p = panes(canvas)[0];
    g.strokeStyle = rv.tool === 'profile' ? '#00e5ff' : '#ffeb3b';
    g.fillStyle = g.strokeStyle;
    g.lineWidth = 2;
    g.beginPath();
    rv.points.forEach(([x, y], i) => { const [sx, sy] = toScreen(p, x, y); if (i) g.lineTo(sx, sy); else g.moveTo(sx, sy); });
    g.stroke();
    for (const [x, y] of rv.points) { const [sx, sy] = toScreen(p, x, y); g.fillRect(sx - 3, sy - 3, 6, 6); }
  }
  if (rv.mode === 'swipe' && rv.b) {
    const x = Math.round(rv.swipe * canvas.width);
    g.fillStyle = '#fff';
    g.fillRect(x - 1, 0, 2, canvas.height);
    g.fillText('A', x - 16, 16);
    g.fillText('B', x + 8, 16);
  }
  if (rv.mode === 'side' && rv.b) {
    g.fillStyle = '#fff';
    g.fillRect(canvas.width / 2 - 1, 0, 2, canvas.height);
    g.fillText(`A: ${rv.a.map.name}`, 8, 16);
    g.fillText(`B: ${rv.b.map.name}`, canvas.width / 2 + 8, 16);
  }
}

export function draw() {
  if (!rv.a) return;
  const canvas = $('review-map');
  // A CPU-backed canvas (willReadFrequently): drawing a few dozen tiles a frame is
  // then 3× faster where the GPU is emulated (42 against 14 frames per second on
  // SwiftShader, docs/PERFORMANCE.md), and the inspector's pixel reads are cheap.
  const g = canvas.getContext('2d', { willReadFrequently: true });
  const t0 = performance.now();
  rv.stats.tilesDrawn = 0;
  g.setTransform(1, 0, 0, 1, 0, 0);
  g.globalAlpha = 1;
  g.fillStyle = '#111';
  g.fillRect(0, 0, canvas.width, canvas.height);
  for (const p of panes(canvas)) drawMap(g, p.map, p, p.clip);
  if (rv.mode === 'swipe' && rv.b) {
    const p = panes(canvas)[0];
    drawMap(g, rv.b.map, p, [rv.swipe * canvas.width, canvas.width]);
  }
  drawOverlay(g, canvas);
  rv.stats.draws++;
  rv.stats.lastDrawMs = performance.now() - t0;
  canvas.dataset.level = String(rv.stats.level);
  canvas.dataset.view = `${rv.view.cx.toFixed(2)},${rv.view.cy.toFixed(2)},${rv.view.mpp.toPrecision(4)}`;
  const settled = loading.size === 0;
  canvas.dataset.settled = String(settled);
  if (settled && rv.stats.firstViewMs === null) {
    rv.stats.firstViewMs = performance.now() - rv.stats.openedAt;
    canvas.dataset.firstViewMs = rv.stats.firstViewMs.toFixed(0);
  }
}

// ---- difference layers and the overlap summary --------------------------------------
// Viridis at six stops, as the engine's ramp (src/export/colour.rs).
const RAMP = [[68, 1, 84], [65, 68, 135], [42, 120, 142], [34, 168, 132], [122, 209, 81], [253, 231, 37]];
export function ramp(t) {
  const x = Math.min(1, Math.max(0, Number.isFinite(t) ? t : 0)) * (RAMP.length - 1);
  const i = Math.min(RAMP.length - 2, Math.floor(x)), f = x - i;
  return [0, 1, 2].map((c) => Math.round(RAMP[i][c] * (1 - f) + RAMP[i + 1][c] * f));
}
// Blue (B lower) – white – red (B higher).
function diverging(t) {
  const s = Math.min(1, Math.abs(t));
  return t < 0 ? [255 * (1 - s), 255 * (1 - s * 0.6), 255] : [255, 255 * (1 - s * 0.8), 255 * (1 - s)];
}

// Samples of a map at level k over a world box: loads the tiles it needs, then answers
// world (x, y) → value (or null) synchronously.
async function sampler(m, kind, k, box) {
  const ix = m.index;
  const rk = ix.resolution * 2 ** k, span = 256 * rk;
  const [tx, ty] = tilesOf(ix, k);
  const c0 = Math.max(0, Math.floor((box[0] - ix.origin[0]) / span)), c1 = Math.min(tx - 1, Math.floor((box[2] - ix.origin[0]) / span));
  const r0 = Math.max(0, Math.floor((ix.origin[1] - box[3]) / span)), r1 = Math.min(ty - 1, Math.floor((ix.origin[1] - box[1]) / span));
  const tiles = new Map();
  const jobs = [];
  for (let r = r0; r <= r1; r++) {
    for (let c = c0; c <= c1; c++) {
      const p = kind === 'rgb' ? pixelsOf(m, 'rgb', k, c, r) : valuesOf(m, kind, k, c, r);
      jobs.push(p.then((v) => tiles.set(`${c},${r}`, v)));
    }
  }
  await Promise.all(jobs);
  return (x, y) => {
    const ij = pixelOf(ix, x, y, k);
    if (!ij) return null;
    const [c, r] = [ij[0] >> 8, ij[1] >> 8];
    const t = tiles.get(`${c},${r}`);
    if (!t) return null;
    const w = tileSize(ix, k, c, r)[0];
    const o = (ij[1] - r * 256) * w + (ij[0] - c * 256);
    if (kind === 'rgb') return t[4 * o + 3] ? [t[4 * o], t[4 * o + 1], t[4 * o + 2]] : null;
    return Number.isFinite(t[o]) ? t[o] : null;
  };
}
// B's level whose pixels are nearest in size to A's level k.
function levelOfB(k) {
  const a = rv.a.map.index, b = rv.b.map.index;
  return Math.max(0, Math.min(b.levels - 1, Math.round(Math.log2((a.resolution * 2 ** k) / b.resolution))));
}
function tileBox(ix, k, c, r) {
  const rk = ix.resolution * 2 ** k;
  const [tw, th] = tileSize(ix, k, c, r);
  const x0 = ix.origin[0] + c * 256 * rk, y1 = ix.origin[1] - r * 256 * rk;
  return [x0, y1 - th * rk, x0 + tw * rk, y1];
}
// Both maps' samples at the centres of A's tile (k, c, r): [x, y, a, b] where both have one.
async function pairs(kind, k, c, r) {
  const A = rv.a.map, B = rv.b.map;
  const box = tileBox(A.index, k, c, r);
  const [sa, sb] = await Promise.all([sampler(A, kind, k, box), sampler(B, kind, levelOfB(k), box)]);
  const [tw, th] = tileSize(A.index, k, c, r);
  const rk = A.index.resolution * 2 ** k;
  const out = new Array(tw * th).fill(null);
  for (let j = 0; j < th; j++) {
    for (let i = 0; i < tw; i++) {
      const x = box[0] + (i + 0.5) * rk, y = box[3] - (j + 0.5) * rk;
      const a = sa(x, y), b = a === null ? null : sb(x, y);
      if (a !== null && b !== null) out[j * tw + i] = [a, b];
    }
  }
  return { out, tw, th };
}
async function diffTile(kind, k, c, r) {
  const source = kind === 'colour' ? 'rgb' : kind;
  const { out, tw, th } = await pairs(source, k, c, r);
  const px = new Uint8ClampedArray(4 * tw * th);
  out.forEach((ab, i) => {
    if (!ab) return;
    const [a, b] = ab;
    let col, alpha = 255;
    if (kind === 'elevation') col = diverging((b - a) / rv.diffScale);
    else if (kind === 'class') { col = a === b ? [90, 90, 90] : [255, 0, 220]; alpha = a === b ? 110 : 255; }
    else col = ramp((Math.abs(a[0] - b[0]) + Math.abs(a[1] - b[1]) + Math.abs(a[2] - b[2])) / 3 / 255 / 0.25);
    px.set([col[0], col[1], col[2], alpha], 4 * i);
  });
  return createImageBitmap(new ImageData(px, tw, th));
}

// The overlap of A and B, at the finest level with at most `budget` tiles of A (level 0
// for maps of a few hundred metres): area, elevation-difference RMSE, class agreement,
// PSNR of B's colours against A's.
export async function compareSummary(budget = 48) {
  const ix = rv.a.map.index;
  let k = 0;
  const count = (k) => { const [tx, ty] = tilesOf(ix, k); let n = 0; for (let r = 0; r < ty; r++) for (let c = 0; c < tx; c++) if (isPresent(ix, k, c, r)) n++; return n; };
  while (k < ix.levels - 1 && count(k) > budget) k++;
  const [tx, ty] = tilesOf(ix, k);
  let n = 0, se = 0, nc = 0, agree = 0, nrgb = 0, sq = 0;
  const hasClass = rv.a.map.index.values.includes('class') && rv.b.map.index.values.includes('class');
  for (let r = 0; r < ty; r++) {
    for (let c = 0; c < tx; c++) {
      if (!isPresent(ix, k, c, r)) continue;
      const [z, cl, rgb] = await Promise.all([
        pairs('elevation', k, c, r),
        hasClass ? pairs('class', k, c, r) : null,
        pairs('rgb', k, c, r),
      ]);
      for (const ab of z.out) if (ab) { n++; se += (ab[1] - ab[0]) ** 2; }
      if (cl) for (const ab of cl.out) if (ab) { nc++; if (ab[0] === ab[1]) agree++; }
      for (const ab of rgb.out) if (ab) { nrgb++; for (let q = 0; q < 3; q++) sq += ((ab[0][q] - ab[1][q]) / 255) ** 2; }
    }
  }
  const px = (ix.resolution * 2 ** k) ** 2;
  return {
    level: k,
    pixel_m: ix.resolution * 2 ** k,
    overlap_m2: n * px,
    elevation_rmse_m: n ? Math.sqrt(se / n) : null,
    class_agreement: nc ? agree / nc : null,
    psnr_db: nrgb ? 10 * Math.log10(1 / Math.max(1e-12, sq / (3 * nrgb))) : null,
  };
}

async function showCompare() {
  const box = $('review-compare');
  if (!rv.b) { box.hidden = true; return; }
  box.hidden = false;
  const dl = $('review-compare-facts');
  dl.textContent = 'computing…';
  try {
    const s = await compareSummary();
    const f = (v, d, u = '') => (v === null ? '–' : `${v.toFixed(d)}${u}`);
    dl.innerHTML = '';
    for (const [k, label, v] of [
      ['overlap', 'overlap', `${f(s.overlap_m2, 0, ' m²')}`],
      ['rmse', 'elevation difference RMSE', f(s.elevation_rmse_m === null ? null : s.elevation_rmse_m * 100, 2, ' cm')],
      ['agreement', 'class agreement', f(s.class_agreement === null ? null : 100 * s.class_agreement, 1, ' %')],
      ['psnr', 'PSNR of B against A', f(s.psnr_db, 2, ' dB')],
      ['level', 'computed at', `${(s.pixel_m * 100).toFixed(0)} cm pixels (level ${s.level})`],
    ]) {
      const dt = document.createElement('dt'); dt.textContent = label;
      const dd = document.createElement('dd'); dd.textContent = v; dd.dataset.fact = k;
      dl.append(dt, dd);
    }
    box.dataset.summary = JSON.stringify(s);
  } catch (e) {
    dl.textContent = `Could not compare: ${e.message || e}`;
  }
}

// ---- inspect, measure, profile, tables ----------------------------------------------
async function valuesAt(m, x, y) {
  const ix = m.index;
  const ij = pixelOf(ix, x, y);
  if (!ij) return null;
  const [c, r] = [ij[0] >> 8, ij[1] >> 8];
  const w = tileSize(ix, 0, c, r)[0];
  const o = (ij[1] - r * 256) * w + (ij[0] - c * 256);
  const out = {};
  await Promise.all(ix.values.map(async (name) => {
    const t = await valuesOf(m, name, 0, c, r);
    const v = t ? t[o] : NaN;
    if (Number.isFinite(v)) out[name] = v;
  }));
  return out;
}
// Elevation of A at world (x, y) (level 0, nearest pixel), or null.
export async function elevationAt(x, y) {
  const v = await valuesAt(rv.a.map, x, y);
  return v && v.elevation !== undefined ? v.elevation : null;
}

let inspectSeq = 0;
async function inspect(canvas, sx, sy) {
  const seq = ++inspectSeq;
  const m = mapAt(canvas, sx);
  const [x, y] = toWorld(paneAt(canvas, sx), sx, sy);
  const v = await valuesAt(m, x, y);
  if (seq !== inspectSeq) return;
  const parts = [`${m === rv.a.map ? 'A' : 'B'} · x ${x.toFixed(2)} m, y ${y.toFixed(2)} m`];
  if (!v || !Object.keys(v).length) parts.push('nothing mapped here');
  else {
    if (v.class !== undefined) parts.push(`class ${m.classNames.get(Math.round(v.class))?.name ?? Math.round(v.class)}`);
    if (v.elevation !== undefined) parts.push(`elevation ${v.elevation.toFixed(3)} m`);
    if (v.confidence !== undefined) parts.push(`confidence ${v.confidence.toFixed(2)}`);
    if (v.density !== undefined) parts.push(`density ${v.density.toFixed(2)}`);
    if (v.error !== undefined) parts.push(`error ${(v.error * 100).toFixed(1)} cm`);
  }
  const el = $('review-inspect');
  el.textContent = parts.join(' · ');
  el.dataset.values = JSON.stringify({ x, y, ...(v || {}) });
}

function polylineLength(pts) {
  let s = 0;
  for (let i = 1; i < pts.length; i++) s += Math.hypot(pts[i][0] - pts[i - 1][0], pts[i][1] - pts[i - 1][1]);
  return s;
}
function fmtLen(m) { return m >= 1000 ? `${(m / 1000).toFixed(3)} km` : `${m.toFixed(2)} m`; }

async function updateProfile() {
  const box = $('review-profile');
  if (rv.tool !== 'profile' || rv.points.length < 2) { box.hidden = true; rv.profile = null; return; }
  box.hidden = false;
  const pts = rv.points;
  const total = polylineLength(pts);
  const step = Math.max(rv.a.map.index.resolution, total / 400);
  const samples = [];
  let d0 = 0;
  for (let i = 1; i < pts.length; i++) {
    const [a, b] = [pts[i - 1], pts[i]];
    const len = Math.hypot(b[0] - a[0], b[1] - a[1]);
    const n = Math.max(1, Math.round(len / step));
    for (let q = i === 1 ? 0 : 1; q <= n; q++) {
      const t = q / n;
      samples.push({ d: d0 + t * len, x: a[0] + t * (b[0] - a[0]), y: a[1] + t * (b[1] - a[1]), vertex: q === 0 || q === n });
    }
    d0 += len;
  }
  await Promise.all(samples.map(async (s) => { s.z = await elevationAt(s.x, s.y); }));
  rv.profile = samples;
  plotProfile(samples, total);
}

function plotProfile(samples, total) {
  const c = $('review-profile-plot');
  const g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  const zs = samples.map((s) => s.z).filter((z) => z !== null);
  const text = $('review-profile-text');
  c.dataset.profile = JSON.stringify(samples.filter((s) => s.vertex).map((s) => ({ d: s.d, x: s.x, y: s.y, z: s.z })));
  c.dataset.samples = String(samples.length);
  if (!zs.length) { text.textContent = 'The line crosses no mapped pixel.'; return; }
  const lo = Math.min(...zs), hi = Math.max(...zs), pad = Math.max(0.01, (hi - lo) * 0.1);
  const L = 56, R = 10, T = 10, B = 26;
  const X = (d) => L + (d / (total || 1)) * (c.width - L - R);
  const Y = (z) => T + (1 - (z - lo + pad) / (hi - lo + 2 * pad)) * (c.height - T - B);
  g.strokeStyle = '#ccc'; g.fillStyle = '#333'; g.font = '11px system-ui, sans-serif';
  g.strokeRect(L, T, c.width - L - R, c.height - T - B);
  g.fillText(`${(hi + pad).toFixed(2)} m`, 2, T + 10);
  g.fillText(`${(lo - pad).toFixed(2)} m`, 2, c.height - B);
  g.fillText('0', L, c.height - 8);
  g.fillText(fmtLen(total), c.width - R - 60, c.height - 8);
  g.strokeStyle = '#00838f'; g.lineWidth = 1.5;
  g.beginPath();
  let pen = false;
  for (const s of samples) {
    if (s.z === null) { pen = false; continue; }
    if (pen) g.lineTo(X(s.d), Y(s.z)); else g.moveTo(X(s.d), Y(s.z));
    pen = true;
  }
  g.stroke();
  text.textContent = `${samples.length} samples over ${fmtLen(total)}; elevation ${lo.toFixed(3)} – ${hi.toFixed(3)} m (range ${((hi - lo) * 100).toFixed(1)} cm).`;
}

function updateMeasure() {
  const el = $('review-measure');
  if (!rv.points.length) { el.textContent = ''; return; }
  const len = polylineLength(rv.points);
  el.textContent = rv.tool === 'measure'
    ? `Distance: ${fmtLen(len)} over ${rv.points.length} point(s).`
    : `Profile line: ${fmtLen(len)}, ${rv.points.length} point(s).`;
  el.dataset.length = String(len);
}

function showTables(m) {
  const tb = $('review-classes').querySelector('tbody');
  tb.innerHTML = '';
  const st = m.index.stats;
  if (!st) {
    const tr = document.createElement('tr');
    tr.innerHTML = '<td colspan="3">this map file holds no statistics</td>';
    tb.append(tr);
  } else {
    const total = st.classes.reduce((s, c) => s + c.area_m2, 0) || 1;
    for (const c of [...st.classes].sort((a, b) => b.area_m2 - a.area_m2)) {
      const tr = document.createElement('tr');
      tr.dataset.class = c.name;
      const colour = m.classNames.get(c.id)?.color || [0, 0, 0];
      for (const v of [null, `${c.area_m2.toFixed(1)} m²`, `${(100 * c.area_m2 / total).toFixed(1)} %`]) {
        const td = document.createElement('td');
        if (v === null) {
          const sw = document.createElement('span');
          sw.className = 'swatch';
          sw.style.background = `rgb(${colour.join(',')})`;
          td.append(sw, c.name);
        } else td.textContent = v;
        tr.append(td);
      }
      tb.append(tr);
    }
  }
  const h = st?.error_histogram;
  $('review-hist-box').hidden = !h;
  if (!h) return;
  const c = $('review-hist');
  const g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  const max = Math.max(...h.counts, 1), n = h.counts.length, bw = (c.width - 20) / n;
  g.fillStyle = '#2b6cb0';
  h.counts.forEach((v, i) => { const bh = (v / max) * (c.height - 30); g.fillRect(10 + i * bw, c.height - 20 - bh, bw - 1, bh); });
  g.fillStyle = '#333'; g.font = '11px system-ui, sans-serif';
  g.fillText('0', 10, c.height - 6);
  g.fillText(`${((n - 1) * h.bin_m * 100).toFixed(0)} cm`, 10 + (n - 1) * bw - 10, c.height - 6);
  g.fillText('more', 10 + (n - 1) * bw - 2, c.height - 22 - (h.counts[n - 1] / max) * (c.height - 30));
  const total = h.counts.reduce((s, v) => s + v, 0);
  let acc = 0, median = null;
  h.counts.forEach((v, i) => { acc += v; if (median === null && acc >= total / 2) median = (i + 1) * h.bin_m; });
  c.setAttribute('aria-label', `histogram of the elevation error: half the pixels within ${(median * 100).toFixed(1)} cm`);
}

// ---- layers and legend --------------------------------------------------------------
function layerList() {
  const ul = $('review-layers');
  ul.innerHTML = '';
  const names = [...rv.a.map.index.layers, 'trajectory'];
  if (rv.diff && rv.b) names.push('diff');
  for (const name of names) {
    const l = rv.layers[name] || (rv.layers[name] = { on: name === 'diff', op: name === 'diff' ? 0.85 : 1 });
    const li = document.createElement('li');
    const label = name === 'diff' ? DIFF[rv.diff] : name;
    li.innerHTML = `<label><input type="checkbox" data-layer="${name}" ${l.on ? 'checked' : ''}> ${label}</label>
      <input type="range" min="0" max="1" step="0.05" value="${l.op}" data-opacity="${name}" aria-label="${label} opacity">`;
    li.querySelector('[data-layer]').addEventListener('change', (e) => { l.on = e.target.checked; changed(true); });
    // While dragging only redraw; the change at the end is the history entry.
    li.querySelector('[data-opacity]').addEventListener('input', (e) => { l.op = Number(e.target.value); requestDraw(); });
    li.querySelector('[data-opacity]').addEventListener('change', () => changed(true));
    ul.append(li);
  }
  const ix = rv.a.map.index;
  const leg = $('review-legend');
  const er = ix.elevation_range;
  leg.innerHTML = '';
  leg.append(er ? `elevation ` : '');
  if (er) {
    const s = document.createElement('span'); s.className = 'ramp'; leg.append(s, ` ${er[0].toFixed(2)} – ${er[1].toFixed(2)} m`);
  }
  if (ix.layers.includes('error')) leg.append(' · error 0 – 10 cm');
  if (rv.diff === 'elevation' && rv.b) leg.append(` · B − A: blue −${rv.diffScale * 100} cm, white 0, red +${rv.diffScale * 100} cm`);
  if (rv.diff === 'class' && rv.b) leg.append(' · magenta: the classes differ, grey: they agree');
  if (rv.diff === 'colour' && rv.b) leg.append(' · colour difference 0 – 25 % on the ramp');
}

// ---- URL state ------------------------------------------------------------------------
function stateQuery() {
  const q = new URLSearchParams();
  if (rv.a?.url) q.set('map', rv.a.url);
  if (rv.b?.url) q.set('b', rv.b.url);
  if (rv.b && rv.mode !== 'single') q.set('mode', rv.mode);
  if (rv.mode === 'swipe') q.set('swipe', rv.swipe.toFixed(2));
  if (rv.diff) q.set('diff', rv.diff);
  if (rv.diff === 'elevation') q.set('scale', String(rv.diffScale));
  q.set('layers', Object.entries(rv.layers).filter(([, l]) => l.on).map(([n, l]) => (l.op === 1 ? n : `${n}:${l.op}`)).join(','));
  const v = rv.view;
  q.set('view', `${v.cx.toFixed(2)},${v.cy.toFixed(2)},${v.mpp.toPrecision(4)}`);
  return q;
}
let viewTimer = null;
let pendingUrl = null; // the current entry's URL, not yet written (pans, zooms)
// Records the state: `true` adds a history entry (a deliberate change), `false`
// rewrites the current one a moment later (pans and zooms), 'now' rewrites it at once.
// A new entry first writes out the current one, so back returns to where it was.
function changed(push) {
  requestDraw();
  if (!rv.a) return;
  const url = `${location.pathname}?${stateQuery()}`;
  $('review-link').href = url;
  $('review-link-note').textContent = rv.a.url && (!rv.b || rv.b.url) ? '' : '(maps opened from files are not in the link: open them by ?map=URL to share)';
  clearTimeout(viewTimer);
  const flush = () => { if (pendingUrl) history.replaceState({ review: true }, '', pendingUrl); pendingUrl = null; };
  if (push === true) { flush(); history.pushState({ review: true }, '', url); return; }
  pendingUrl = url;
  if (push === 'now') flush();
  else viewTimer = setTimeout(flush, 250);
}

function applyQuery(q) {
  if (q.get('mode')) rv.mode = q.get('mode');
  if (q.get('swipe')) rv.swipe = Math.min(1, Math.max(0, Number(q.get('swipe'))));
  rv.diff = q.get('diff') && DIFF[q.get('diff')] ? q.get('diff') : '';
  if (q.get('scale')) rv.diffScale = Number(q.get('scale')) || 0.05;
  if (q.get('layers') !== null) {
    for (const l of Object.values(rv.layers)) l.on = false;
    for (const item of q.get('layers').split(',').filter(Boolean)) {
      const [name, op] = item.split(':');
      rv.layers[name] = { on: true, op: op === undefined ? 1 : Math.min(1, Math.max(0, Number(op))) };
    }
  }
  const v = (q.get('view') || '').split(',').map(Number);
  if (v.length === 3 && v.every(Number.isFinite) && v[2] > 0) rv.view = { cx: v[0], cy: v[1], mpp: v[2] };
  else fit();
  syncControls();
}

function syncControls() {
  for (const r of document.querySelectorAll('input[name="review-mode"]')) r.checked = r.value === rv.mode;
  $('review-swipe').value = String(rv.swipe);
  $('review-diff').value = rv.diff;
  $('review-diff-scale').value = String(rv.diffScale);
  $('review-mode').disabled = !rv.b;
  $('review-diff').disabled = !rv.b;
  if (rv.a) layerList();
}

function fit() {
  const ix = rv.a.map.index, c = $('review-map');
  const w = ix.width * ix.resolution, h = ix.height * ix.resolution;
  const paneW = rv.mode === 'side' && rv.b ? c.width / 2 : c.width;
  rv.view = { cx: ix.origin[0] + w / 2, cy: ix.origin[1] - h / 2, mpp: 1.05 * Math.max(w / paneW, h / c.height) };
}

// ---- opening --------------------------------------------------------------------------
function showMapProblems(problems, source) {
  const list = $('map-problem-list');
  list.innerHTML = '';
  for (const p of problems) {
    const li = document.createElement('li');
    const code = document.createElement('code');
    code.textContent = p.location;
    const prefix = `${p.location}: `;
    li.append(code, ' ', p.message.startsWith(prefix) ? p.message.slice(prefix.length) : p.message);
    list.append(li);
  }
  $('map-problems').hidden = false;
  setStatus(`${source} is not a usable map: ${problems.length} problem(s).`, 'error');
}

async function openSource(makeSource, label) {
  try {
    const src = await makeSource();
    return await openMap(src);
  } catch (e) {
    showMapProblems(e instanceof MapError ? e.problems : [{ location: label, message: `${label}: ${e.message || e}` }], label);
    return null;
  }
}

function resetCaches(which) {
  for (const k of [...cache.keys()]) if (k.startsWith(`${which}:`) || k.includes(':diff-')) { cache.get(k).v?.close?.(); cache.delete(k); }
  shownErrors.clear();
}

// Opens map A (a file or a URL) with map B (a URL) if given; `query` restores a shared
// view; `keepViewer` keeps the optimiser's map and camera panel (a run's own map).
export async function openReview(input, { url = null, b = null, query = null, keepViewer = false } = {}) {
  if (!keepViewer) frameViewer = null;
  rv.stats.openedAt = performance.now();
  rv.stats.firstViewMs = null;
  delete $('review-map').dataset.firstViewMs;
  $('map-problems').hidden = true;
  const label = url || input?.name || 'map';
  setStatus(`Opening ${label}…`);
  const map = await openSource(() => (url ? urlSource(url) : blobSource(input, input.name)), label);
  if (!map) return false;
  resetCaches('a');
  resetCaches('b');
  rv.a = { map, url };
  rv.b = null;
  rv.points = []; rv.frame = null; rv.profile = null;
  $('review-thumb-box').hidden = true;
  if (b) {
    const mb = await openSource(() => urlSource(b), b);
    if (mb) rv.b = { map: mb, url: b };
  }
  for (const id of ['summary', 'problems', ...(keepViewer ? [] : ['optimise', 'viewer'])]) $(id).hidden = true;
  $('review').hidden = false;
  if (query) applyQuery(query); else { rv.mode = rv.b ? 'swipe' : 'single'; fit(); syncControls(); }
  names();
  showTables(map);
  showCompare();
  updateMeasure();
  updateProfile();
  changed(query ? 'now' : true);
  const ix = map.index;
  setStatus(`${map.name}: ${ix.width}×${ix.height} px at ${ix.resolution} m (${ix.levels} levels)${map.src.lazy ? ', read tile by tile' : ''}.`, 'ok');
  document.body.dataset.review = 'open';
  $('review-map').scrollIntoView({ block: 'nearest' });
  return true;
}

export async function openReviewB(input, url = null) {
  if (!rv.a) return;
  const label = url || input?.name || 'map B';
  const map = await openSource(() => (url ? urlSource(url) : blobSource(input, input.name)), label);
  if (!map) return;
  resetCaches('b');
  rv.b = { map, url };
  rv.mode = 'swipe';
  syncControls();
  names();
  showCompare();
  changed(true);
  setStatus(`Comparing ${rv.a.map.name} (A) with ${map.name} (B).`, 'ok');
}

function names() {
  const el = $('review-names');
  el.textContent = `A: ${rv.a.map.name}` + (rv.b ? ` · B: ${rv.b.map.name}` : '');
}

// The optimiser hands its own run's camera views here (frame → shows them).
export function setFrameViewer(fn) { frameViewer = fn; }

async function pickFrame(canvas, sx, sy) {
  const p = paneAt(canvas, sx);
  const t = rv.a.map.index.trajectory;
  let best = -1, bd = 10;
  t.forEach(([x, y], i) => { const [fx, fy] = toScreen(p, x, y); const d = Math.hypot(fx - sx, fy - sy); if (d < bd) { bd = d; best = i; } });
  if (best < 0) return false;
  rv.frame = best;
  const el = $('review-frame');
  el.textContent = `Frame ${best} at (${t[best][0].toFixed(2)}, ${t[best][1].toFixed(2)}) m.` + (frameViewer ? ' Its camera view is in the camera panel below.' : '');
  el.dataset.frame = String(best);
  if (frameViewer) frameViewer(best);
  // The stored thumbnail of the input image, when the map file has one near it.
  const box = $('review-thumb-box');
  try {
    const th = await rv.a.map.thumbnail(best);
    if (th) {
      const img = $('review-thumb');
      if (img.src.startsWith('blob:')) URL.revokeObjectURL(img.src);
      img.src = th.url;
      img.alt = `input image of frame ${th.frame}, first camera`;
      $('review-thumb-caption').textContent = `input image, frame ${th.frame} (first camera)` + (th.frame !== best ? `: the stored one nearest to frame ${best}` : '');
      box.dataset.frame = String(th.frame);
    }
    box.hidden = !th;
  } catch (e) {
    box.hidden = true;
    reportTileError(e);
  }
  requestDraw();
  return true;
}

// ---- wiring -------------------------------------------------------------------------
export function wireReview(status) {
  setStatus = status;
  const canvas = $('review-map');
  const pos = (e) => {
    const r = canvas.getBoundingClientRect();
    return [(e.clientX - r.left) * (canvas.width / r.width), (e.clientY - r.top) * (canvas.height / r.height)];
  };
  const zoomAt = (sx, sy, k) => {
    const p = paneAt(canvas, sx);
    const [x, y] = toWorld(p, sx, sy);
    rv.view.mpp /= k;
    const [x2, y2] = toWorld(p, sx, sy);
    rv.view.cx += x - x2; rv.view.cy += y - y2;
    changed(false);
  };
  let drag = null, moved = 0, queued = null;
  canvas.addEventListener('pointerdown', (e) => { drag = pos(e); moved = 0; canvas.setPointerCapture(e.pointerId); canvas.focus(); });
  canvas.addEventListener('pointermove', (e) => {
    if (!rv.a) return;
    const [sx, sy] = pos(e);
    if (drag) {
      const dx = sx - drag[0], dy = sy - drag[1];
      moved += Math.abs(dx) + Math.abs(dy);
      rv.view.cx -= dx * rv.view.mpp; rv.view.cy += dy * rv.view.mpp;
      drag = [sx, sy];
      changed(false);
      return;
    }
    if (!queued) requestAnimationFrame(() => { inspect(canvas, ...queued); queued = null; });
    queued = [sx, sy];
  });
  canvas.addEventListener('pointerup', async (e) => {
    const was = drag;
    drag = null;
    if (!was || moved > 4 || !rv.a) return;
    const [sx, sy] = pos(e);
    if (rv.tool === 'inspect') { if (!(await pickFrame(canvas, sx, sy))) inspect(canvas, sx, sy); return; }
    rv.points.push(toWorld(paneAt(canvas, sx), sx, sy));
    updateMeasure();
    updateProfile();
    requestDraw();
  });
  canvas.addEventListener('wheel', (e) => { e.preventDefault(); const [sx, sy] = pos(e); zoomAt(sx, sy, Math.exp(-e.deltaY * 0.002)); }, { passive: false });
  canvas.addEventListener('keydown', (e) => {
    if (!rv.a) return;
    const v = rv.view, step = canvas.width * v.mpp / 8;
    const keys = {
      ArrowLeft: () => { v.cx -= step; }, ArrowRight: () => { v.cx += step; },
      ArrowUp: () => { v.cy += step; }, ArrowDown: () => { v.cy -= step; },
      '+': () => zoomAt(canvas.width / 2, canvas.height / 2, 1.25), '=': () => zoomAt(canvas.width / 2, canvas.height / 2, 1.25),
      '-': () => zoomAt(canvas.width / 2, canvas.height / 2, 0.8), 0: () => fit(),
      Escape: () => clearTool(),
    };
    const f = keys[e.key];
    if (!f) return;
    e.preventDefault();
    f();
    changed(false);
  });
  const clearTool = () => { rv.points = []; updateMeasure(); updateProfile(); requestDraw(); };
  $('review-clear').addEventListener('click', clearTool);
  for (const r of document.querySelectorAll('input[name="review-tool"]')) {
    r.addEventListener('change', () => { rv.tool = r.value; clearTool(); });
  }
  for (const r of document.querySelectorAll('input[name="review-mode"]')) {
    r.addEventListener('change', () => { rv.mode = r.value; changed(true); });
  }
  $('review-swipe').addEventListener('input', (e) => { rv.swipe = Number(e.target.value); changed(false); });
  $('review-diff').addEventListener('change', (e) => { rv.diff = e.target.value; layerList(); changed(true); });
  $('review-diff-scale').addEventListener('change', (e) => { rv.diffScale = Number(e.target.value); layerList(); changed(true); });
  $('review-b-picker').addEventListener('change', (e) => { if (e.target.files[0]) openReviewB(e.target.files[0]); });
  window.addEventListener('popstate', async () => {
    const q = new URLSearchParams(location.search);
    if (!q.get('map') && !rv.a) return;
    if (q.get('map') && q.get('map') !== rv.a?.url) { await openReview(null, { url: q.get('map'), b: q.get('b'), query: q }); return; }
    if (rv.a) { applyQuery(q); requestDraw(); }
  });
  // For tests and benchmarks: the view, conversions and the summary.
  window.rogsReview = {
    state: rv,
    toScreen: (x, y) => toScreen(panes(canvas)[0], x, y),
    toWorld: (sx, sy) => toWorld(panes(canvas)[0], sx, sy),
    setView: (cx, cy, mpp) => { rv.view = { cx, cy, mpp }; draw(); },
    draw, elevationAt, compareSummary,
    pending: () => loading.size,
  };
}
