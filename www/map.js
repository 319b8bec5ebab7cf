// The optimisation panel and the map viewer: runs the engine step by step (yielding
// to the browser between steps so the page stays responsive), then shows the BEV
// layers on a canvas with pan, zoom, visibility and opacity, and offers the exports.
import { start_reconstruction, start_reconstruction_drives, start_reconstruction_lazy, warm_gpu } from './pkg/rogs.js';
import { openLazyBundle, readerOf } from './bundle.js';
import { blobSource } from './zip.js';
import { createGpuView } from './gpu-view.js';
import { openReview, setFrameViewer } from './review.js';

const $ = (id) => document.getElementById(id);
const LAYERS = ['rgb', 'semantic', 'elevation', 'confidence', 'density', 'error'];
// Drawn in this order, the trajectory on top.
const ORDER = [...LAYERS, 'trajectory'];
let gpuView = null; // the WebGPU renderer of the map canvas, or null for 2D
let drives = []; // [{ name, bytes }]: one bundle, or several drives of one map
let classes = [];
let run = null; // { rec, paused, stopped }
let engineMemory = null; // the wasm instance's memory: its size after each run is kept on <body>
let runsDone = 0;

export function setEngineMemory(memory) {
  engineMemory = memory;
}

// Object URLs of the exports shown: revoked when the next run's replace them, so that
// a page used for many runs holds one run's files, not all of them.
const exportUrls = [];
function exportUrl(blob) {
  const u = URL.createObjectURL(blob);
  exportUrls.push(u);
  return u;
}
function revokeExports() {
  for (const u of exportUrls.splice(0)) URL.revokeObjectURL(u);
}
const view = { scale: 1, x: 0, y: 0, layers: {} };

export function offerOptimisation(list, bundleClasses, channels) {
  drives = list;
  classes = bundleClasses || [];
  $('optimise').hidden = false;
  $('run').disabled = false;
  if ('gpu' in navigator) warmGpu(channels || 1);
}

// The next run's GPU device with its pipelines compiled (`warm_gpu`), begun when a
// bundle is accepted and after each run: SwiftShader takes seconds over them, which
// pass while the user reads the summary instead of after the click. `gpuWarmS` on
// <body>: seconds the warm-up took.
let warm = null; // { channels, done: Promise }
function warmGpu(channels) {
  if (warm?.channels === channels) return;
  const t0 = performance.now();
  delete document.body.dataset.gpuWarmS;
  warm = {
    channels,
    done: warm_gpu(channels).then(
      () => { document.body.dataset.gpuWarmS = ((performance.now() - t0) / 1000).toFixed(2); },
      // A run without it makes its own device and says what is wrong with it.
      () => {},
    ),
  };
}

function settings() {
  return {
    resolution: Number($('set-resolution').value),
    epochs: Number($('set-epochs').value),
    lidar: $('set-lidar').checked,
    align: $('set-align').checked,
    ...($('set-refine-poses').checked ? { refine_poses: true } : {}),
    adaptive: $('set-adaptive').checked,
    init: $('set-init').value,
    half_width: Number($('set-half-width').value) || 4,
    ply_up: $('set-ply-up').value,
    ...(Number($('set-tile').value) > 0 ? { tile_m: Number($('set-tile').value) } : {}),
    tile_overlap_m: Number($('set-tile-overlap').value) || 0,
    ...($('set-traj').checked ? {} : { traj_loss: false }),
    ...($('set-frame-exposure').checked ? {} : { frame_exposure: false }),
    ...($('set-ipm').checked ? { baseline: 'ipm' } : {}),
    ...(Number($('set-holdout').value) > 0 ? { holdout_every: Number($('set-holdout').value) } : {}),
    ...optionalNumber('lr_z_start', 'set-lr-z-start'),
    ...optionalNumber('lr_z_end', 'set-lr-z-end'),
    ...optionalNumber('lidar_gate', 'set-lidar-gate'),
    ...optionalNumber('lidar_band', 'set-lidar-band'),
    ...optionalNumber('max_steps', 'set-max-steps'),
    seed: Number($('set-seed').value) || 0,
    adam: $('set-adam').value,
    ...($('set-pose-rig').checked ? { pose_rig: true } : {}),
    ...faultTile(),
  };
}

// An optional setting: absent when its field is empty, so that the engine's default holds.
function optionalNumber(key, id) {
  const v = $(id).value.trim();
  return v === '' ? {} : { [key]: Number(v) };
}

// Fault injection for tests: `?fault_tile=N` destroys the GPU device once as tile N starts.
function faultTile() {
  const v = new URLSearchParams(location.search).get('fault_tile');
  return v !== null && /^\d+$/.test(v) ? { fault_tile: Number(v) } : {};
}

function fmtTime(s) {
  if (!isFinite(s)) return '…';
  return s >= 60 ? `${Math.floor(s / 60)} min ${Math.round(s % 60)} s` : `${Math.round(s)} s`;
}

function drawLoss(losses) {
  const c = $('loss-curve');
  const g = c.getContext('2d');
  g.clearRect(0, 0, c.width, c.height);
  if (losses.length < 2) return;
  const max = Math.max(...losses), min = Math.min(...losses);
  g.strokeStyle = '#2b6cb0';
  g.beginPath();
  losses.forEach((l, i) => {
    const x = (i / (losses.length - 1)) * c.width;
    const y = c.height - ((l - min) / (max - min || 1)) * (c.height - 4) - 2;
    if (i) g.lineTo(x, y); else g.moveTo(x, y);
  });
  g.stroke();
}

async function optimise(setStatus) {
  // Seconds from the click to each stage, on the page's body for benchmarks.
  const tClick = performance.now();
  const mark = (k) => { document.body.dataset[k] = ((performance.now() - tClick) / 1000).toFixed(2); };
  for (const k of ['startS', 'trainedS', 'finishS', 'mapShownS', 'exportsS', 'previewS', 'previews']) delete document.body.dataset[k];
  $('run').disabled = true;
  $('pause').disabled = false;
  $('stop').disabled = false;
  $('viewer').hidden = true;
  setStatus('Preparing surfels on the GPU…');
  let rec;
  // The warm device goes to this run; the next run's is warmed after it.
  if (warm) await warm.done;
  const channels = warm?.channels;
  warm = null;
  try {
    if (drives.some((d) => d.lazy)) {
      // One lazily read drive makes every drive of the map read so.
      const lazy = await Promise.all(drives.map((d) => d.lazy || openLazyBundle(blobSource(new Blob([d.bytes]), d.name))));
      rec = await start_reconstruction_lazy(lazy.map((l) => l.manifest), lazy.map((l) => l.names),
        lazy.map((l) => l.sizes), drives.map((d) => d.name), readerOf(lazy), settings());
    } else {
      rec = drives.length > 1
        ? await start_reconstruction_drives(drives.map((d) => d.bytes), drives.map((d) => d.name), settings())
        : await start_reconstruction(drives[0].bytes, settings());
    }
  } catch (e) {
    setStatus(`Could not start: ${e}`, 'error');
    $('run').disabled = false;
    if (channels) warmGpu(channels);
    return;
  }
  // The previous run's engine state (its surfels, GPU buffers and files) goes now:
  // only one run is held at a time.
  const previous = run?.rec;
  run = { rec, paused: false, stopped: false };
  if (previous && previous !== rec) {
    view.rec = null;
    previous.free();
  }
  mark('startS');
  let total = rec.total_steps();
  const losses = [];
  const t0 = performance.now();
  let lastPreview = performance.now();
  let previewGap = 2000; // the first preview after 2 s, then every 4 s or 5× its cost
  resetViewer(rec);
  let error = null;
  const retried = new Set();
  while (!run.stopped) {
    if (run.paused) { await new Promise((r) => setTimeout(r, 100)); continue; }
    let loss;
    try {
      loss = await rec.step();
    } catch (e) {
      // A tile the machine failed (a lost device) is trained again once; the
      // finished tiles are kept either way.
      const tile = rec.tile();
      const lost = rec.device_lost();
      let again = false;
      if (!retried.has(tile)) {
        try { again = await rec.retry(); } catch (e2) { e = `${e}; a new GPU device could not be had: ${e2}`; }
      }
      if (again) {
        retried.add(tile);
        document.body.dataset.retries = String(retried.size);
        setStatus(lost
          ? `The GPU device was lost at tile ${tile + 1} (${e}). The finished tiles are kept; training tile ${tile + 1} again on a new device…`
          : `Tile ${tile + 1} failed (${e}); training it again…`, 'info');
        continue;
      }
      error = e;
      break;
    }
    if (loss === undefined) break;
    losses.push(loss);
    const done = rec.steps_done();
    total = rec.total_steps();
    const per = (performance.now() - t0) / 1000 / done;
    $('progress').value = done / total;
    const tiles = rec.tiles();
    const tile = tiles > 1 ? `tile ${rec.tile() + 1} / ${tiles} · ` : '';
    document.body.dataset.tiles = String(tiles);
    const held = rec.held_bytes();
    if (held > Number(document.body.dataset.heldPeak || 0)) document.body.dataset.heldPeak = String(held);
    const holding = held ? ` · holding ${(held / 1048576).toFixed(1)} MiB of the bundle` : '';
    $('progress-text').textContent = `${tile}step ${done} / ${total} · loss ${loss.toFixed(4)} · ${per.toFixed(2)} s per step · ETA ${fmtTime(per * (total - done))}${holding}`;
    document.body.dataset.steps = String(done);
    if (done % 5 === 0) drawLoss(losses);
    // A live preview of the map, throttled: it renders the whole map.
    if (done < total && performance.now() - lastPreview > previewGap) {
      const p0 = performance.now();
      try {
        setLayer('rgb', await rec.preview(), rec.width(), rec.height());
        $('viewer').hidden = false;
        draw();
        document.body.dataset.previews = String(Number(document.body.dataset.previews || 0) + 1);
      } catch (e) { /* a failed preview leaves the last one; the final map follows */ }
      lastPreview = performance.now();
      // Seconds spent on previews, on <body> for benchmarks.
      document.body.dataset.previewS = (Number(document.body.dataset.previewS || 0) + (lastPreview - p0) / 1000).toFixed(2);
      previewGap = Math.max(4000, 5 * (lastPreview - p0));
    }
    // Yield so the page repaints and the buttons respond.
    await new Promise((r) => setTimeout(r, 0));
  }
  drawLoss(losses);
  mark('trainedS');
  $('pause').disabled = true;
  $('stop').disabled = true;
  setStatus(error ? `Optimisation stopped: ${error}` : 'Rendering the map layers…', error ? 'error' : 'info');
  try {
    const report = JSON.parse(await rec.finish());
    mark('finishS');
    await showMap(rec, report, mark);
    if (!error) setStatus(`Map ready: ${rec.steps_done()} steps in ${fmtTime((performance.now() - t0) / 1000)}.`, 'ok');
  } catch (e) {
    const kept = listExports(rec).childElementCount > 0;
    if (kept) $('viewer').hidden = false;
    setStatus(`Could not render the map: ${e}${kept ? '. The trained surfels can still be downloaded (Exports).' : ''}`, 'error');
  }
  runsDone += 1;
  document.body.dataset.runs = String(runsDone);
  if (channels) warmGpu(channels);
  if (engineMemory) document.body.dataset.wasmBytes = String(engineMemory.buffer.byteLength);
  $('run').disabled = false;
}

function showMetrics(report) {
  const m = report.metrics;
  const a = report.pose_alignment;
  const aligned = a
    ? ` Poses aligned to the LiDAR: ${(a.height_rms_m * 100).toFixed(1)} cm and ${a.tilt_rms_deg.toFixed(2)}° RMS.`
    : '';
  const el = $('metrics');
  if (!m) { el.textContent = `No ground truth or LiDAR in this bundle: no metrics.${aligned}`; return; }
  const f = (v, d, u) => (v === null || v === undefined ? '–' : `${v.toFixed(d)}${u}`);
  // The poses' shared offset and tilt move the whole map and no input sees them.
  const d = m.elevation_datum;
  const datum = d ? ` (${f(d.rmse_m * 100, 1, ' cm')} without the poses' shared offset and tilt)` : '';
  el.textContent = `PSNR ${f(m.psnr_db, 2, ' dB')} · mIoU ${f(m.miou, 3, '')} · elevation RMSE ${f(m.elevation_rmse_m * 100, 1, ' cm')}${datum}.${aligned}`;
}

function setLayer(name, px, w, h) {
  let l = view.layers[name];
  if (!l) {
    const c = document.createElement('canvas');
    c.width = w; c.height = h;
    l = view.layers[name] = { canvas: c, visible: name === 'rgb', opacity: 1 };
    const li = document.createElement('li');
    li.innerHTML = `<label><input type="checkbox" data-layer="${name}" ${l.visible ? 'checked' : ''}> ${name}</label>
      <input type="range" min="0" max="1" step="0.05" value="1" data-opacity="${name}" aria-label="${name} opacity">`;
    li.querySelector('[data-layer]').addEventListener('change', (e) => { l.visible = e.target.checked; draw(); });
    li.querySelector('[data-opacity]').addEventListener('input', (e) => { l.opacity = Number(e.target.value); draw(); });
    $('layers').append(li);
  }
  if (px) l.canvas.getContext('2d').putImageData(new ImageData(new Uint8ClampedArray(px), w, h), 0, 0);
  if (gpuView) gpuView.setLayer(name, l.canvas);
}

// The trajectory as a raster layer of the map's size (red polyline).
function trajectoryLayer(t, w, h) {
  const c = document.createElement('canvas');
  c.width = w; c.height = h;
  const g = c.getContext('2d');
  g.strokeStyle = '#ff3b30';
  g.lineWidth = Math.max(2, w / 400);
  g.beginPath();
  for (let i = 0; i + 1 < t.length; i += 2) {
    if (i) g.lineTo(t[i], t[i + 1]); else g.moveTo(t[i], t[i + 1]);
  }
  g.stroke();
  return g.getImageData(0, 0, w, h).data;
}

// Download links for the run's files (after a failed BEV, the model's own files).
function listExports(rec) {
  const ex = $('exports');
  ex.innerHTML = '';
  revokeExports();
  for (const name of rec.file_names()) {
    const a = document.createElement('a');
    a.textContent = name;
    a.download = name;
    a.href = exportUrl(new Blob([rec.file(name)]));
    ex.append(a, ' ');
  }
  if (ex.childElementCount) {
    const all = document.createElement('a');
    all.textContent = 'all exports (.zip)';
    all.download = 'rogs-map.zip';
    all.id = 'exports-zip';
    all.href = '#';
    all.addEventListener('click', (e) => {
      if (all.href.startsWith('blob:')) return; // made once, then a plain download
      e.preventDefault();
      try {
        all.href = exportUrl(new Blob([rec.exports_zip()], { type: 'application/zip' }));
        all.click();
      } catch (err) {
        all.textContent = `all exports (.zip): ${err}`;
      }
    });
    ex.append(all, ' ');
  }
  return ex;
}

function resetViewer(rec) {
  view.layers = {};
  $('layers').innerHTML = '';
  $('exports').innerHTML = '';
  $('metrics').textContent = 'Optimising: the map below is a live preview.';
  $('camera-panel').hidden = true;
  view.rec = rec;
  view.trajectory = rec.trajectory();
  const canvas = $('map');
  const w = rec.width(), h = rec.height();
  view.scale = Math.min(canvas.width / w, canvas.height / h);
  view.x = (canvas.width - w * view.scale) / 2;
  view.y = (canvas.height - h * view.scale) / 2;
  setLayer('trajectory', trajectoryLayer(view.trajectory, w, h), w, h);
}

function showLegend(report, rec) {
  const el = $('legend');
  el.innerHTML = '';
  const sem = document.createElement('span');
  for (const c of classes.filter((c) => c.role === 'road')) {
    const s = document.createElement('span');
    s.className = 'swatch';
    s.style.background = `rgb(${c.color.join(',')})`;
    sem.append(s, ` ${c.name} `);
  }
  let geo = {};
  try { geo = JSON.parse(rec.bev_json()); } catch { /* no legend values */ }
  const elev = document.createElement('span');
  if (geo.elevation_min_m !== undefined) {
    elev.innerHTML = ` · elevation <span class="ramp"></span> ${geo.elevation_min_m.toFixed(2)} – ${geo.elevation_max_m.toFixed(2)} m · error 0 – 10 cm`;
  }
  if (classes.length) el.append('classes: ', sem);
  el.append(elev);
}

async function showCameraView() {
  const rec = view.rec;
  if (!rec) return;
  try {
    const r = await rec.camera_view(Number($('cam-frame').value), Number($('cam-view').value));
    for (const [id, px] of [['cam-rendered', r.rendered], ['cam-input', r.input]]) {
      const c = $(id);
      c.width = r.width; c.height = r.height;
      c.getContext('2d').putImageData(new ImageData(new Uint8ClampedArray(px), r.width, r.height), 0, 0);
    }
    $('cam-error').textContent = '';
  } catch (e) {
    $('cam-error').textContent = String(e);
  }
}

// The finished map on screen, then its downloads (encoded once the map is shown).
async function showMap(rec, report, mark) {
  const w = rec.width(), h = rec.height();
  for (const name of LAYERS) {
    let px;
    try { px = rec.layer(name); } catch { continue; }
    setLayer(name, px, w, h);
  }
  showMetrics(report);
  showLegend(report, rec);
  $('cam-frame').max = String(rec.frames() - 1);
  $('camera-panel').hidden = false;
  $('viewer').hidden = false;
  draw();
  mark('mapShownS');
  $('exports').textContent = 'Preparing the downloads…';
  // Let the map paint before the files are encoded.
  await new Promise((r) => requestAnimationFrame(() => setTimeout(r, 0)));
  let ex;
  try {
    ex = listExports(rec);
  } catch (e) {
    $('exports').textContent = `The downloads could not be made: ${e}`;
    return;
  }
  // The layers as shown (visible ones, with their opacity) at map resolution.
  const shown = document.createElement('a');
  shown.textContent = 'map as shown.png';
  shown.href = '#';
  shown.addEventListener('click', (e) => {
    e.preventDefault();
    const c = document.createElement('canvas');
    c.width = w; c.height = h;
    const g = c.getContext('2d');
    for (const name of ORDER) {
      const l = view.layers[name];
      if (!l || !l.visible) continue;
      g.globalAlpha = l.opacity;
      g.drawImage(l.canvas, 0, 0);
    }
    c.toBlob((b) => {
      const a = document.createElement('a');
      a.download = 'map-as-shown.png';
      a.href = exportUrl(b);
      a.click();
    });
  });
  ex.append(shown);
  const names = rec.file_names();
  if (names.includes('map.rogsmap')) {
    // The finished map in the review tools; its trajectory frames show this run's
    // camera views in the panel below.
    const review = document.createElement('button');
    review.type = 'button';
    review.id = 'review-run';
    review.textContent = 'Review this map';
    review.addEventListener('click', async () => {
      const file = new File([rec.file('map.rogsmap')], 'map.rogsmap');
      setFrameViewer(async (f) => {
        $('cam-frame').value = String(f);
        await showCameraView();
      });
      await openReview(file, { keepViewer: true });
    });
    ex.append(' ', review);
  }
  mark('exportsS');
  showCameraView();
}

// The finished map's georeference (bev.json), or null while optimising.
let geoCache = null;
function mapGeo() {
  if (!view.rec) return null;
  if (geoCache && geoCache.rec === view.rec) return geoCache.geo;
  let geo = null;
  try { geo = JSON.parse(view.rec.bev_json()); } catch { return null; }
  geoCache = { rec: view.rec, geo };
  return geo;
}

// The scale bar under the map: a round length about 100 CSS pixels long.
function drawScale() {
  const canvas = $('map');
  const rec = view.rec;
  const bar = $('map-scale');
  if (!rec) { bar.hidden = true; return; }
  const r = canvas.getBoundingClientRect();
  const mPerCss = rec.resolution() / (view.scale * (r.width / canvas.width || 1));
  const target = 100 * mPerCss;
  const e = 10 ** Math.floor(Math.log10(target));
  const len = [5, 2, 1].map((f) => f * e).find((v) => v <= target) || e;
  bar.hidden = false;
  bar.querySelector('div').style.width = `${Math.round(len / mPerCss)}px`;
  bar.querySelector('span').textContent = len >= 1 ? `${len} m` : `${Math.round(len * 100)} cm`;
  bar.dataset.metres = String(len);
}

function draw() {
  drawScale();
  const canvas = $('map');
  if (gpuView) {
    gpuView.draw(ORDER, view.layers, view);
    canvas.dataset.view = `${view.scale.toFixed(4)},${view.x.toFixed(1)},${view.y.toFixed(1)}`;
    return;
  }
  const g = canvas.getContext('2d');
  g.setTransform(1, 0, 0, 1, 0, 0);
  g.fillStyle = '#111';
  g.fillRect(0, 0, canvas.width, canvas.height);
  g.imageSmoothingEnabled = false;
  g.setTransform(view.scale, 0, 0, view.scale, view.x, view.y);
  for (const name of ORDER) {
    const l = view.layers[name];
    if (!l || !l.visible) continue;
    g.globalAlpha = l.opacity;
    g.drawImage(l.canvas, 0, 0);
  }
  g.globalAlpha = 1;
  canvas.dataset.view = `${view.scale.toFixed(4)},${view.x.toFixed(1)},${view.y.toFixed(1)}`;
}

export function wireMap(setStatus) {
  // WebGPU for the map when the browser gives a WebGPU canvas, else a 2D canvas.
  createGpuView($('map'))
    .then((v) => { gpuView = v; })
    .catch(() => { gpuView = null; })
    .finally(() => { $('map').dataset.renderer = gpuView ? 'webgpu' : '2d'; });
  $('run').addEventListener('click', () => optimise(setStatus));
  $('pause').addEventListener('click', () => {
    if (!run) return;
    run.paused = !run.paused;
    $('pause').textContent = run.paused ? 'Resume' : 'Pause';
  });
  $('stop').addEventListener('click', () => { if (run) run.stopped = true; });
  $('cam-frame').addEventListener('change', showCameraView);
  $('cam-view').addEventListener('change', showCameraView);
  const canvas = $('map');
  let drag = null;
  const pointers = new Map(); // for pinch zoom: two pointers' positions
  let pinch = null;
  const zoomAt = (mx, my, k) => {
    view.x = mx - (mx - view.x) * k; view.y = my - (my - view.y) * k; view.scale *= k;
    draw();
  };
  canvas.addEventListener('pointerdown', (e) => {
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
    drag = pointers.size === 1 ? { x: e.clientX, y: e.clientY } : null;
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener('pointermove', (e) => {
    if (!pointers.has(e.pointerId)) return;
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
    if (pointers.size !== 2) { pinch = null; return; }
    const [a, b] = [...pointers.values()];
    const d = Math.hypot(a[0] - b[0], a[1] - b[1]);
    const r = canvas.getBoundingClientRect();
    const mx = ((a[0] + b[0]) / 2 - r.left) * (canvas.width / r.width), my = ((a[1] + b[1]) / 2 - r.top) * (canvas.height / r.height);
    if (pinch) zoomAt(mx, my, d / pinch);
    pinch = d;
  });
  const release = (e) => { pointers.delete(e.pointerId); pinch = null; };
  canvas.addEventListener('pointercancel', release);
  canvas.addEventListener('pointerup', release);
  canvas.addEventListener('pointermove', (e) => {
    const r = canvas.getBoundingClientRect();
    const mx = (e.clientX - r.left) * (canvas.width / r.width), my = (e.clientY - r.top) * (canvas.height / r.height);
    const px = Math.floor((mx - view.x) / view.scale), py = Math.floor((my - view.y) / view.scale);
    const z = view.rec && px >= 0 && py >= 0 ? view.rec.elevation_at(px, py) : undefined;
    // x, y in the map's world frame once bev.json (the georeference) exists.
    const geo = mapGeo();
    const xy = geo && px >= 0 && py >= 0
      ? `x ${(geo.origin[0] + (px + 0.5) * geo.resolution).toFixed(2)} m, y ${(geo.origin[1] - (py + 0.5) * geo.resolution).toFixed(2)} m · `
      : '';
    $('cursor').textContent = z === undefined ? '' : `${xy}elevation under the cursor: ${z.toFixed(3)} m`;
    if (!drag) return;
    view.x += e.clientX - drag.x; view.y += e.clientY - drag.y;
    drag = { x: e.clientX, y: e.clientY };
    draw();
  });
  canvas.addEventListener('pointerup', () => { drag = null; });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    const r = canvas.getBoundingClientRect();
    const mx = (e.clientX - r.left) * (canvas.width / r.width), my = (e.clientY - r.top) * (canvas.height / r.height);
    zoomAt(mx, my, Math.exp(-e.deltaY * 0.002));
  }, { passive: false });
}
