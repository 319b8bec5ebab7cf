// "Compute masks with a model…": a road-segmentation network (an .onnx file, and a
// class map .json unless it is TwinLiteNet) labels every view of the open bundle in a
// Web Worker (segment-worker.js: the engine's segmentation module, fetched only now),
// and the labelled bundle opens in the bundle's place: the bundle a labelled drive
// would be (docs/SEGMENT.md). The page stays responsive and says what went wrong.
const $ = (id) => document.getElementById(id);

// `current()`: the open drives; `open(bytes, name)`: opens a bundle's bytes.
export function wireSegment(setStatus, current, open) {
  const input = $('segment-model');
  input.addEventListener('change', async (e) => {
    const files = [...e.target.files];
    e.target.value = '';
    await computeMasks(files, setStatus, current, open);
  });
}

// Whether a dropped file is a model or a class map for it (rather than a bundle).
export function isModelFile(file) {
  return /\.onnx$/i.test(file.name);
}

let running = false;

export async function computeMasks(files, setStatus, current, open) {
  const say = (text, kind = 'info') => {
    $('segment-status').textContent = text;
    setStatus(text, kind);
  };
  const model = files.find((f) => /\.onnx$/i.test(f.name));
  const map = files.find((f) => /\.json$/i.test(f.name));
  const drives = current();
  if (!model) { say('Choose an .onnx model (and, unless it is TwinLiteNet, its class map .json).', 'error'); return; }
  if (running) { say('Masks are being computed already: wait for them to finish.', 'error'); return; }
  if (drives.length !== 1) {
    say(drives.length ? 'Masks are computed for one drive at a time: open a single bundle first.' : 'Open a bundle first, then choose a model to compute its masks.', 'error');
    return;
  }
  const drive = drives[0];
  if (!drive.bytes) {
    say(`${drive.name} is read lazily (a large bundle): compute its masks with rogs segment (docs/SEGMENT.md); the page labels bundles it reads whole (up to 256 MiB).`, 'error');
    return;
  }
  running = true;
  document.body.dataset.segment = 'running';
  $('segment-download').hidden = true;
  const t0 = performance.now();
  const worker = new Worker(new URL('./segment-worker.js', import.meta.url), { type: 'module' });
  try {
    say(`Loading the segmentation module and ${model.name}…`);
    const classes = map ? await map.text() : 'twinlitenet';
    const out = await new Promise((resolve, reject) => {
      worker.onmessage = ({ data }) => {
        if (data.type === 'progress') {
          const s = (performance.now() - t0) / 1000;
          const eta = data.done ? ` · ETA ${Math.ceil((s / data.done) * (data.total - data.done))} s` : '';
          say(`Computing masks with ${model.name}: ${data.done}/${data.total} views (${Math.round((100 * data.done) / Math.max(1, data.total))} %)${eta}`);
        } else if (data.type === 'done') resolve(data);
        else reject(new Error(data.message));
      };
      worker.onerror = (e) => { e.preventDefault(); reject(new Error(e.message || 'the segmentation worker stopped')); };
      (async () => worker.postMessage({
        bundle: drive.bytes, bundleName: drive.name, model: new Uint8Array(await model.arrayBuffer()),
        modelName: model.name, classes, classesName: map ? map.name : 'twinlitenet',
      }))().catch(reject);
    });
    const s = ((performance.now() - t0) / 1000).toFixed(1);
    const name = drive.name.replace(/(\.zip)?$/i, '-labelled.zip');
    const link = $('segment-download');
    if (link.href) URL.revokeObjectURL(link.href);
    link.href = URL.createObjectURL(new Blob([out.bytes], { type: 'application/zip' }));
    link.download = name;
    document.body.dataset.segmentSeconds = s;
    await open(out.bytes, name);
    link.hidden = false;
    const notes = out.notes.length ? ` (${out.notes.join('; ')})` : '';
    say(`${out.views} views labelled by ${model.name} in ${s} s${notes}: ${name} is open; press Optimise to build its map.`, 'ok');
    document.body.dataset.segment = 'done';
  } catch (e) {
    say(`Could not compute masks: ${e.message || e}. The bundle is as it was.`, 'error');
    document.body.dataset.segment = 'failed';
  } finally {
    worker.terminate();
    running = false;
  }
}
