// The page shell: loads the engine, checks WebGPU, takes a bundle (drop, picker,
// ?url=, example) and shows its summary or its problems in words. Nothing here
// sends user data anywhere: bundles are read in memory by the wasm engine.
import init, { inspect_bundle, inspect_lazy_bundle, example_bundle, gpu_info } from './pkg/rogs.js';
import { offerOptimisation, setEngineMemory, wireMap } from './map.js';
import { openReview, wireReview } from './review.js';
import { blobSource, urlSource, isMapFile } from './rogsmap.js';
import { LAZY_BYTES, lazyForced, openLazyBundle } from './bundle.js';
import { wireSegment, isModelFile, computeMasks } from './segment.js';

const $ = (id) => document.getElementById(id);
let engineReady = null;

function setStatus(text, kind = 'info') {
  const s = $('status');
  s.textContent = text;
  s.dataset.kind = kind;
}

function explainNoWebGPU(reason) {
  const box = $('webgpu');
  box.hidden = false;
  box.innerHTML = '';
  const h = document.createElement('h2');
  h.textContent = 'WebGPU is not available in this browser';
  const p = document.createElement('p');
  p.textContent = reason + ' Bundles can still be checked here, but optimising a map needs WebGPU: '
    + 'use a current Chrome or Edge (113 or newer) with hardware acceleration on. On Linux, start Chromium with '
    + '--enable-unsafe-webgpu --enable-features=Vulkan. Safari 26 and Firefox 141 or newer on Windows also work; '
    + 'in older Firefox set dom.webgpu.enabled in about:config.';
  box.append(h, p);
}

async function checkGpu() {
  if (!('gpu' in navigator)) {
    explainNoWebGPU('This browser has no navigator.gpu.');
    $('gpu').textContent = 'GPU: none';
    return;
  }
  try {
    const r = await gpu_info();
    $('gpu').textContent = `GPU: ${r.name || 'unnamed adapter'} (${r.backend}), ${Math.round(r.max_storage_buffer_binding_size / 1048576)} MiB per storage binding, accumulation ${r.accumulation}; self-test passed.`;
  } catch (e) {
    explainNoWebGPU(String(e));
    $('gpu').textContent = 'GPU: unavailable';
  }
}

function showProblems(problems) {
  $('summary').hidden = true;
  const list = $('problem-list');
  list.innerHTML = '';
  for (const p of problems) {
    const li = document.createElement('li');
    if (p.location) {
      const c = document.createElement('code');
      c.textContent = p.location;
      li.append(c, ' ');
    }
    // Messages start with their location; the code tag already shows it.
    const prefix = `${p.location}: `;
    li.append(p.location && p.message.startsWith(prefix) ? p.message.slice(prefix.length) : p.message);
    list.append(li);
  }
  $('problems').hidden = false;
}

function showSummary(s, source) {
  $('problems').hidden = true;
  $('summary-title').textContent = s.name || source;
  const facts = [
    ['source', source],
    ['frames', `${s.frames} (${s.views} views, ${s.duration_s.toFixed(1)} s)`],
    ['trajectory', `${s.trajectory_length_m.toFixed(1)} m`],
    ['cameras', String(s.cameras.length)],
    ['LiDAR', s.lidar_points ? `${s.lidar_points.toLocaleString('en')} points in ${s.lidar_sweeps} sweeps` : 'none'],
    ['ground truth', s.ground_truth ? `BEV ${s.ground_truth.width}×${s.ground_truth.height} at ${s.ground_truth.resolution_m} m` : 'none'],
    ['world frame', s.world_frame || 'local (the bundle names no dataset frame)'],
    ['corridor', s.corridor_half_width_m ? `${s.corridor_half_width_m} m either side (the bundle's)` : 'not given: 4 m either side'],
    // Fields rogs ignores (a misspelled optional field, with the nearest known name).
    ...(s.warnings?.length ? [['warnings', s.warnings.join('; ')]] : []),
  ];
  const dl = $('summary-facts');
  dl.innerHTML = '';
  for (const [k, v] of facts) {
    const dt = document.createElement('dt');
    dt.textContent = k;
    const dd = document.createElement('dd');
    dd.textContent = v;
    dd.dataset.fact = k;
    dl.append(dt, dd);
  }
  const tbody = $('cameras').querySelector('tbody');
  tbody.innerHTML = '';
  for (const c of s.cameras) {
    const tr = document.createElement('tr');
    for (const v of [c.name, `${c.width}×${c.height}`, c.fx.toFixed(1), c.fy.toFixed(1)]) {
      const td = document.createElement('td');
      td.textContent = v;
      tr.append(td);
    }
    tbody.append(tr);
  }
  const ul = $('classes');
  ul.innerHTML = '';
  for (const c of s.classes) {
    const li = document.createElement('li');
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = `rgb(${c.color.join(',')})`;
    li.append(sw, `${c.id} ${c.name} (${c.role})`);
    ul.append(li);
  }
  if (!s.labelled) {
    const li = document.createElement('li');
    li.id = 'no-labels';
    li.textContent = 'No labels: a drive without masks. The road plane below each camera\'s horizon is supervised and the map has no semantic layer.';
    ul.append(li);
  }
  $('summary').hidden = false;
}

// The drives of the map being prepared: one bundle, or several of the same streets
// (drop several, or "Add another drive"), merged into one map by the engine.
let drives = [];

function showDrives() {
  const dl = $('summary-facts');
  dl.querySelector('[data-fact="drives"]')?.previousElementSibling?.remove();
  dl.querySelector('[data-fact="drives"]')?.remove();
  if (drives.length < 2) return;
  const dt = document.createElement('dt');
  dt.textContent = 'drives';
  const dd = document.createElement('dd');
  dd.dataset.fact = 'drives';
  dd.textContent = drives.map((d) => `${d.name} (${d.summary.frames} frames, ${d.summary.trajectory_length_m.toFixed(1)} m)`).join(' + ')
    + ': merged into one map when you press Optimise';
  dl.prepend(dt, dd);
}

async function openBytes(bytes, source, add = false) {
  await engineReady;
  setStatus(`Checking ${source}…`);
  // Let the status paint before the (synchronous) validation runs.
  await new Promise((r) => setTimeout(r, 0));
  try {
    accept(inspect_bundle(bytes), { name: source, bytes }, add);
  } catch (e) {
    setStatus(`Could not read ${source}: ${e}`, 'error');
  }
}

// A bundle read lazily (bundle.js): its directory and manifest now, the files of a
// tile when the run trains it.
async function openLazy(src, source, add = false) {
  await engineReady;
  setStatus(`Reading the directory of ${source}…`);
  try {
    const lazy = await openLazyBundle(src);
    accept(inspect_lazy_bundle(lazy.manifest, lazy.names, lazy.sizes), { name: source, lazy }, add);
  } catch (e) {
    if (e.problems) {
      showProblems(e.problems);
      $('optimise').hidden = true;
      setStatus(`${source} is not a valid bundle: ${e.problems.length} problem(s).`, 'error');
    } else {
      setStatus(`Could not read ${source}: ${e.message || e}`, 'error');
    }
  }
}

function accept(r, drive, add) {
  const source = drive.name;
  if (r.status === 'valid') {
    drive.summary = r.summary;
    if (add && drives.length) {
      drives.push(drive);
    } else {
      drives = [drive];
      showSummary(r.summary, source);
      // The corridor the bundle asks for (its importer's), unless changed by hand.
      $('set-half-width').value = String(r.summary.corridor_half_width_m || 4);
    }
    showDrives();
    // A drive without labels' map has no classes to show (its table, if any, is the truth's).
    offerOptimisation(drives, r.summary.labelled ? r.summary.classes : [], r.summary.channels);
    document.body.dataset.drives = String(drives.length);
    document.body.dataset.lazy = String(drives.some((d) => d.lazy));
    const how = drive.lazy ? ` It is read lazily: ${(drive.lazy.size / 1048576).toFixed(1)} MiB on disk, a tile's files at a time in memory.` : '';
    setStatus(drives.length > 1
      ? `${drives.length} drives ready (${drives.map((d) => d.name).join(', ')}): press Optimise to build one map of them.${how}`
      : `${source} is a valid bundle: press Optimise to build its map.${how}`, 'ok');
  } else {
    showProblems(r.problems);
    $('optimise').hidden = true;
    setStatus(`${source} is not a valid bundle: ${r.problems.length} problem(s).`, 'error');
  }
}

async function openFile(file, add = false) {
  if (!file) return;
  // Map files open in review, read lazily; everything else is a bundle.
  if (/\.rogsmap$/i.test(file.name) || await isMapFile(blobSource(file))) {
    await openReview(file);
    return;
  }
  $('review').hidden = true;
  $('map-problems').hidden = true;
  // A long drive is never read whole: its zip's directory, then a tile at a time.
  if (file.size > LAZY_BYTES || lazyForced()) {
    await openLazy(blobSource(file, file.name), file.name, add);
    return;
  }
  try {
    const bytes = new Uint8Array(await file.arrayBuffer());
    await openBytes(bytes, file.name, add);
  } catch (e) {
    setStatus(`Could not read ${file.name}: ${e}`, 'error');
  }
}

// The body of a response, with the download's progress in the status line.
async function readWithProgress(res, url) {
  const total = Number(res.headers.get('content-length')) || 0;
  if (!res.body) return new Uint8Array(await res.arrayBuffer());
  const reader = res.body.getReader();
  const parts = [];
  let got = 0;
  let shown = 0;
  const t0 = performance.now();
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    parts.push(value);
    got += value.length;
    if (performance.now() - shown > 200) {
      shown = performance.now();
      const mib = (v) => (v / 1048576).toFixed(1);
      const rate = got / Math.max(1e-3, (shown - t0) / 1000);
      const eta = total ? ` · ETA ${Math.ceil((total - got) / rate)} s` : '';
      setStatus(`Downloading ${url}: ${mib(got)}${total ? ` of ${mib(total)}` : ''} MiB${total ? ` (${Math.round((100 * got) / total)} %)` : ''}${eta}`);
      document.body.dataset.download = String(got);
    }
  }
  const out = new Uint8Array(got);
  let o = 0;
  for (const p of parts) { out.set(p, o); o += p.length; }
  return out;
}

async function openUrl(url) {
  setStatus(`Downloading ${url}…`);
  try {
    // A large bundle on a server that answers range requests is read lazily.
    const src = await urlSource(url).catch(() => null);
    if (src?.lazy && (src.size > LAZY_BYTES || lazyForced())) {
      await openLazy(src, url);
      return;
    }
    const res = await fetch(url);
    if (!res.ok) {
      const hint = url === 'demo/demo.zip' ? ' (npm start generates the demo scene)' : '';
      throw new Error(`the server answered ${res.status} ${res.statusText}${hint}`);
    }
    await openBytes(await readWithProgress(res, url), url);
  } catch (e) {
    setStatus(`Could not download ${url}: ${e.message || e}. Check the address, or drop the file instead.`, 'error');
  }
}

function wireInputs() {
  $('picker').addEventListener('change', (e) => openFile(e.target.files[0]));
  wireSegment(setStatus, () => drives, (bytes, name) => openBytes(bytes, name));
  $('add-drive').addEventListener('change', async (e) => {
    for (const f of e.target.files) await openFile(f, true);
    e.target.value = '';
  });
  $('demo').addEventListener('click', () => openUrl('demo/demo.zip'));
  $('demo-map').addEventListener('click', () => openReview(null, { url: 'demo/demo-truth.rogsmap' }));

  $('example').addEventListener('click', async () => {
    await engineReady;
    try {
      await openBytes(example_bundle(), 'tiny example');
    } catch (e) {
      setStatus(`Could not build the example: ${e}`, 'error');
    }
  });
  let depth = 0;
  const overlay = $('drop-overlay');
  window.addEventListener('dragenter', (e) => { e.preventDefault(); depth++; overlay.hidden = false; });
  window.addEventListener('dragleave', () => { depth = Math.max(0, depth - 1); if (!depth) overlay.hidden = true; });
  window.addEventListener('dragover', (e) => e.preventDefault());
  window.addEventListener('drop', (e) => {
    e.preventDefault();
    depth = 0;
    overlay.hidden = true;
    const files = e.dataTransfer ? [...e.dataTransfer.files] : [];
    // A model (with its class map) labels the open bundle.
    if (files.some(isModelFile)) { computeMasks(files, setStatus, () => drives, (bytes, name) => openBytes(bytes, name)); return; }
    // Several bundles dropped at once are drives of one map.
    if (files.length) (async () => { for (const [i, f] of files.entries()) await openFile(f, i > 0); })();
    else setStatus('Nothing to open: drop a bundle (.zip), a map (.rogsmap) or a segmentation model (.onnx).', 'error');
  });
}

// The second half of the page's Content-Security-Policy (index.html): connections to
// the page's own origin and to the servers the query names, nothing else. Policies
// add up (a request must pass each), so a meta added now narrows the static one.
function narrowConnections(q) {
  const allowed = new Set(["'self'", 'blob:']);
  for (const key of ['url', 'map', 'b']) {
    const v = q.get(key);
    if (!v) continue;
    try {
      const origin = new URL(v, location.href).origin;
      if (origin !== location.origin) allowed.add(origin);
    } catch { /* a bad address is explained when it is opened */ }
  }
  const m = document.createElement('meta');
  m.httpEquiv = 'Content-Security-Policy';
  m.content = `connect-src ${[...allowed].join(' ')}`;
  document.head.append(m);
  document.body.dataset.connectSrc = m.content;
}

async function main() {
  narrowConnections(new URLSearchParams(location.search));
  wireInputs();
  wireMap(setStatus);
  wireReview(setStatus);
  engineReady = init().then((engine) => setEngineMemory(engine.memory));
  try {
    await engineReady;
  } catch (e) {
    setStatus(`The engine failed to load: ${e}. Reload the page; if it persists, this browser may lack WebAssembly.`, 'error');
    return;
  }
  setStatus('Ready: drop a bundle.');
  document.body.dataset.ready = 'true';
  await checkGpu();
  document.body.dataset.gpuChecked = 'true';
  const q = new URLSearchParams(location.search);
  if (q.get('map')) await openReview(null, { url: q.get('map'), b: q.get('b'), query: q });
  else if (q.get('url')) await openUrl(q.get('url'));
}

main();
