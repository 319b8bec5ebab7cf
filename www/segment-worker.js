// The page's segmentation worker: runs the engine's segmentation module
// (pkg-segment, scripts/build-segment.sh; tract, a pure-Rust ONNX runtime) off the
// page's thread, so that the page stays responsive while a model labels every view.
// Messages in: {bundle, bundleName, model, modelName, classes, classesName}; out:
// {type: 'progress', done, total}, {type: 'done', bytes, views, notes} or
// {type: 'error', message}.
let ready = null;

self.onmessage = async ({ data }) => {
  let mod;
  try {
    ready ??= import('./pkg-segment/rogs_segment.js').then(async (m) => { await m.default(); return m; });
    mod = await ready;
  } catch (e) {
    ready = null;
    self.postMessage({ type: 'error', message: `the segmentation module did not load (${e.message || e}); it is built by npm start and npm run build (scripts/build-segment.sh)` });
    return;
  }
  try {
    const out = mod.label_bundle_zip(data.bundle, data.bundleName, data.model, data.modelName,
      data.classes, data.classesName, (done, total) => self.postMessage({ type: 'progress', done, total }));
    self.postMessage({ type: 'done', bytes: out.bytes, views: out.views, notes: out.notes }, [out.bytes.buffer]);
  } catch (e) {
    self.postMessage({ type: 'error', message: String(e?.message ?? e) });
  }
};
