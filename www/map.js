// The optimisation panel and the map viewer: runs the engine step by step (yielding
// to the browser between steps so the page stays responsive), then shows the BEV
// layers on a canvas with pan, zoom, visibility and opacity, and offers the exports.
import { start_reconstruction } from './pkg/rogs.js';

const $ = (id) => document.getElementById(id);
const LAYERS = ['rgb', 'semantic', 'elevation', 'confidence', 'density', 'error'];
let bundleBytes = null;
let run = null; // { rec, paused, stopped }
const view = { scale: 1, x: 0, y: 0, layers: {} };

export function offerOptimisation(bytes) {
  bundleBytes = bytes;
  $('optimise').hidden = false;
  $('run').disabled = false;
}

function settings() {
  return {
    resolution: Number($('set-resolution').value),
    epochs: Number($('set-epochs').value),
    lidar: $('set-lidar').checked,
    adaptive: $('set-adaptive').checked,
    init: $('set-init').value,
  };
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
  $('run').disabled = true;
  $('pause').disabled = false;
  $('stop').disabled = false;
  $('viewer').hidden = true;
  setStatus('Preparing surfels on the GPU…');
  let rec;
  try {
    rec = await start_reconstruction(bundleBytes, settings());
  } catch (e) {
    setStatus(`Could not start: ${e}`, 'error');
    $('run').disabled = false;
    return;
  }
  run = { rec, paused: false, stopped: false };
  const total = rec.total_steps();
  const losses = [];
  const t0 = performance.now();
  let error = null;
  while (!run.stopped) {
    if (run.paused) { await new Promise((r) => setTimeout(r, 100)); continue; }
    let loss;
    try {
      loss = await rec.step();
    } catch (e) {
      error = e;
      break;
    }
    if (loss === undefined) break;
    losses.push(loss);
    const done = rec.steps_done();
    const per = (performance.now() - t0) / 1000 / done;
    $('progress').value = done / total;
    $('progress-text').textContent = `step ${done} / ${total} · loss ${loss.toFixed(4)} · ${per.toFixed(2)} s per step · ETA ${fmtTime(per * (total - done))}`;
    document.body.dataset.steps = String(done);
    if (done % 5 === 0) drawLoss(losses);
    // Yield so the page repaints and the buttons respond.
    await new Promise((r) => setTimeout(r, 0));
  }
  drawLoss(losses);
  $('pause').disabled = true;
  $('stop').disabled = true;
  setStatus(error ? `Optimisation stopped: ${error}` : 'Rendering the map layers…', error ? 'error' : 'info');
  try {
    const report = JSON.parse(await rec.finish());
    showMap(rec, report);
    if (!error) setStatus(`Map ready: ${rec.steps_done()} steps in ${fmtTime((performance.now() - t0) / 1000)}.`, 'ok');
  } catch (e) {
    setStatus(`Could not render the map: ${e}`, 'error');
  }
  $('run').disabled = false;
}

function showMetrics(report) {
  const m = report.metrics;
  const el = $('metrics');
  if (!m) { el.textContent = 'No ground truth or LiDAR in this bundle: no metrics.'; return; }
  const f = (v, d, u) => (v === null || v === undefined ? '–' : `${v.toFixed(d)}${u}`);
  el.textContent = `PSNR ${f(m.psnr_db, 2, ' dB')} · mIoU ${f(m.miou, 3, '')} · elevation RMSE ${f(m.elevation_rmse_m * 100, 1, ' cm')}`;
}

function showMap(rec, report) {
  const w = rec.width(), h = rec.height();
  view.layers = {};
  const list = $('layers');
  list.innerHTML = '';
  for (const name of LAYERS) {
    let px;
    try { px = rec.layer(name); } catch { continue; }
    const c = document.createElement('canvas');
    c.width = w; c.height = h;
    c.getContext('2d').putImageData(new ImageData(new Uint8ClampedArray(px), w, h), 0, 0);
    view.layers[name] = { canvas: c, visible: name === 'rgb', opacity: 1 };
    const li = document.createElement('li');
    li.innerHTML = `<label><input type="checkbox" data-layer="${name}" ${name === 'rgb' ? 'checked' : ''}> ${name}</label>
      <input type="range" min="0" max="1" step="0.05" value="1" data-opacity="${name}" aria-label="${name} opacity">`;
    list.append(li);
  }
  list.querySelectorAll('[data-layer]').forEach((cb) => cb.addEventListener('change', () => {
    view.layers[cb.dataset.layer].visible = cb.checked; draw();
  }));
  list.querySelectorAll('[data-opacity]').forEach((r) => r.addEventListener('input', () => {
    view.layers[r.dataset.opacity].opacity = Number(r.value); draw();
  }));
  const canvas = $('map');
  view.scale = Math.min(canvas.width / w, canvas.height / h);
  view.x = (canvas.width - w * view.scale) / 2;
  view.y = (canvas.height - h * view.scale) / 2;
  const ex = $('exports');
  ex.innerHTML = '';
  for (const name of rec.file_names()) {
    const a = document.createElement('a');
    a.textContent = name;
    a.download = name;
    a.href = URL.createObjectURL(new Blob([rec.file(name)]));
    ex.append(a, ' ');
  }
  showMetrics(report);
  $('viewer').hidden = false;
  draw();
}

function draw() {
  const canvas = $('map');
  const g = canvas.getContext('2d');
  g.setTransform(1, 0, 0, 1, 0, 0);
  g.fillStyle = '#111';
  g.fillRect(0, 0, canvas.width, canvas.height);
  g.imageSmoothingEnabled = false;
  g.setTransform(view.scale, 0, 0, view.scale, view.x, view.y);
  for (const name of LAYERS) {
    const l = view.layers[name];
    if (!l || !l.visible) continue;
    g.globalAlpha = l.opacity;
    g.drawImage(l.canvas, 0, 0);
  }
  g.globalAlpha = 1;
  canvas.dataset.view = `${view.scale.toFixed(4)},${view.x.toFixed(1)},${view.y.toFixed(1)}`;
}

export function wireMap(setStatus) {
  $('run').addEventListener('click', () => optimise(setStatus));
  $('pause').addEventListener('click', () => {
    if (!run) return;
    run.paused = !run.paused;
    $('pause').textContent = run.paused ? 'Resume' : 'Pause';
  });
  $('stop').addEventListener('click', () => { if (run) run.stopped = true; });
  const canvas = $('map');
  let drag = null;
  canvas.addEventListener('pointerdown', (e) => { drag = { x: e.clientX, y: e.clientY }; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener('pointermove', (e) => {
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
    const k = Math.exp(-e.deltaY * 0.002);
    view.x = mx - (mx - view.x) * k; view.y = my - (my - view.y) * k; view.scale *= k;
    draw();
  }, { passive: false });
}
