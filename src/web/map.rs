//! The page's reconstruction API (wasm32 only): start a session on a bundle, step it
//! (the page yields to the browser between steps), finish it, and fetch layers and
//! export files. Errors reach JavaScript as sentences; nothing panics.

use crate::bev::BevGeometry;
use crate::bundle::{Bundle, LazyFiles, Limits};
use crate::gpu::GpuContext;
use crate::reconstruct::{Outcome, Session};
use crate::settings::{self, Settings};
use crate::tiles::{TileConfig, TiledRun};
use wasm_bindgen::prelude::*;

fn err(e: impl std::fmt::Display) -> JsValue {
    JsValue::from_str(&e.to_string())
}

/// A lazily read drive above this size is tiled even when its corridor is small.
const LAZY_UNTILED_BYTES: u64 = 512 << 20;

#[wasm_bindgen]
pub struct Reconstruction {
    bundle: Bundle,
    run: TiledRun,
    /// The map's geometry, known from the start so that previews line up with it.
    geometry: BevGeometry,
    outcome: Option<Outcome>,
    /// The export files: the model's once training ends, the map's made on first
    /// use (`ensure_files`), so that the map shows before they are encoded.
    files: Vec<(String, Vec<u8>)>,
    /// Whether the map's files are in `files` yet.
    map_files: bool,
    /// report.json of the finished map.
    report: Option<String>,
    ply_up: crate::export::ply::Up,
    /// For a bundle read lazily: its stores and the page's reader.
    lazy: Option<(LazyFiles, js_sys::Function)>,
}

/// Opens a bundle, prepares the surfels and uploads them to the GPU.
#[wasm_bindgen]
pub async fn start_reconstruction(
    bytes: Vec<u8>,
    settings: JsValue,
) -> Result<Reconstruction, JsValue> {
    let bundle = Bundle::from_zip_bytes(bytes, Limits::default()).map_err(err)?;
    start(bundle, settings, None).await
}

/// Several drives of the same streets (zip bytes each, with their names for
/// messages) merged into one map, as `rogs reconstruct a.zip b.zip` does.
#[wasm_bindgen]
pub async fn start_reconstruction_drives(
    drives: js_sys::Array,
    names: Vec<String>,
    settings: JsValue,
) -> Result<Reconstruction, JsValue> {
    let mut bundles = Vec::new();
    for (k, d) in drives.iter().enumerate() {
        let bytes = js_sys::Uint8Array::new(&d).to_vec();
        let b = Bundle::from_zip_bytes(bytes, Limits::default()).map_err(|e| {
            let name = names
                .get(k)
                .cloned()
                .unwrap_or_else(|| format!("drive {}", k + 1));
            err(format!("{name}: {e}"))
        })?;
        bundles.push(b);
    }
    let bundle = Bundle::merge(bundles, &names).map_err(err)?;
    start(bundle, settings, None).await
}

/// Drives read lazily (`www/bundle.js`): for each, its manifest.json bytes and its
/// zip's entry names and uncompressed sizes; `reader([[drive, path], …])` resolves
/// to the files' bytes. Only the files of the tile being trained are held.
#[wasm_bindgen]
pub async fn start_reconstruction_lazy(
    manifests: js_sys::Array,
    entry_names: js_sys::Array,
    entry_sizes: js_sys::Array,
    names: Vec<String>,
    reader: js_sys::Function,
    settings: JsValue,
) -> Result<Reconstruction, JsValue> {
    let mut bundles = Vec::new();
    let mut stores = Vec::new();
    for k in 0..manifests.length() {
        let name = names
            .get(k as usize)
            .cloned()
            .unwrap_or_else(|| format!("drive {}", k + 1));
        let manifest = js_sys::Uint8Array::new(&manifests.get(k)).to_vec();
        let list: Vec<String> = js_sys::Array::from(&entry_names.get(k))
            .iter()
            .map(|v| v.as_string().unwrap_or_default())
            .collect();
        let sizes: Vec<f64> = js_sys::Array::from(&entry_sizes.get(k))
            .iter()
            .map(|v| v.as_f64().unwrap_or(f64::NAN))
            .collect();
        let (b, store) =
            super::lazy::open(manifest, list, sizes).map_err(|e| err(format!("{name}: {e}")))?;
        bundles.push(b);
        stores.push(store);
    }
    let bundle = if bundles.len() == 1 {
        bundles.pop().ok_or_else(|| err("no drive"))?
    } else {
        Bundle::merge(bundles, &names).map_err(err)?
    };
    start(bundle, settings, Some((LazyFiles { stores }, reader))).await
}

thread_local! {
    /// The device `warm_gpu` set up for the next run, its pipelines compiled.
    static WARM: std::cell::RefCell<Option<GpuContext>> = const { std::cell::RefCell::new(None) };
}

/// Sets up a GPU device for the next run and compiles its training pipelines for
/// a bundle of `channels` logit channels (the summary's `channels`), so that the
/// run started next (`start_reconstruction*`) finds them compiled: the page calls
/// it when a bundle is accepted, and SwiftShader's 4–5 s of compiling pass while
/// its user looks at the summary and the settings. Resolves when they are
/// compiled (the page waits for it before it starts a run). A bundle of other
/// channels compiles the pipelines that differ when its run starts.
#[wasm_bindgen]
pub async fn warm_gpu(channels: u32) -> Result<(), JsValue> {
    let ctx = GpuContext::new().await.map_err(err)?;
    if let Err(e) = crate::optim::train::warm_up(&ctx, channels).await {
        ctx.release();
        return Err(err(e));
    }
    if let Some(old) = WARM.with(|w| w.borrow_mut().replace(ctx)) {
        old.release();
    }
    Ok(())
}

/// The warm device, once (a lost one is dropped).
fn take_warm() -> Option<GpuContext> {
    WARM.with(|w| w.borrow_mut().take())
        .filter(|c| !c.is_lost())
}

async fn start(
    mut bundle: Bundle,
    settings: JsValue,
    lazy: Option<(LazyFiles, js_sys::Function)>,
) -> Result<Reconstruction, JsValue> {
    let s: Settings = if settings.is_undefined() || settings.is_null() {
        Settings::default()
    } else {
        serde_wasm_bindgen::from_value(settings).map_err(|e| err(format!("settings: {e}")))?
    };
    let ply_up = s.ply_up().map_err(err)?;
    // The page defaults coarser than the paper's 5 cm so that the demo runs in a
    // minute or two on a CPU; the settings panel says so.
    let c = s.config(&bundle.manifest, settings::PAGE).map_err(err)?;
    let asked = s.tiling().map_err(err)?;
    let mut tiling = crate::tiles::choose(&bundle.manifest, &c, asked);
    if let (Some((files, _)), None) = (&lazy, tiling) {
        // Untiled, a run reads every file at once: a large drive read lazily is
        // tiled whatever its surfel count, so that memory holds one tile's files.
        let bytes: u64 = files.stores.iter().map(|s| s.total_bytes()).sum();
        if bytes > LAZY_UNTILED_BYTES {
            tiling = Some(TileConfig::default());
        }
    }
    let ctx = match take_warm() {
        Some(c) => c,
        None => GpuContext::new().await.map_err(err)?,
    };
    let run = match &lazy {
        Some((files, reader)) => {
            let mut f = super::lazy::fetcher(reader.clone());
            crate::tiles::start_lazy(&mut bundle, files, c, tiling, ctx, &mut f).await
        }
        None => TiledRun::new(&mut bundle, c, tiling, ctx).await,
    }
    .map_err(err)?;
    let mut run = run;
    run.fault_tile = s.fault_tile;
    let geometry = run.geometry;
    Ok(Reconstruction {
        bundle,
        run,
        geometry,
        outcome: None,
        files: Vec::new(),
        map_files: false,
        report: None,
        ply_up,
        lazy,
    })
}

/// Freed by the page (`free()`) before its next run: the run's device goes with it,
/// and every GPU buffer on it, without waiting for JavaScript's garbage collector.
impl Drop for Reconstruction {
    fn drop(&mut self) {
        self.run.release_gpu();
    }
}

#[wasm_bindgen]
impl Reconstruction {
    pub fn total_steps(&self) -> usize {
        self.run.total_steps()
    }

    pub fn steps_done(&self) -> usize {
        self.run.steps_done()
    }

    /// Surfels of the tiles started so far (all of them when untiled).
    pub fn surfels(&self) -> usize {
        self.run.surfels()
    }

    /// Tiles in the plan (1 when untiled).
    pub fn tiles(&self) -> usize {
        self.run.tile_count()
    }

    /// Index of the tile being trained (0 when untiled).
    pub fn tile(&self) -> usize {
        self.run.current_tile().map_or(0, |t| t.0)
    }

    /// One step; resolves to the total loss, or `undefined` when all steps are done.
    pub async fn step(&mut self) -> Result<Option<f64>, JsValue> {
        let l = match &self.lazy {
            Some((files, reader)) => {
                let mut f = super::lazy::fetcher(reader.clone());
                crate::tiles::step_lazy(&mut self.run, &self.bundle, files, &mut f).await
            }
            None => self.run.step(&self.bundle).await,
        }
        .map_err(err)?;
        Ok(l.map(|l| l.total()))
    }

    /// After a step failed at a tile for a reason of the machine (a lost device, not
    /// bad input): clears it so that the next step trains that tile again, keeping
    /// the finished ones, on a new GPU device if the old one was lost. Resolves to
    /// false when there is nothing to retry.
    pub async fn retry(&mut self) -> Result<bool, JsValue> {
        self.run.retry().await.map_err(err)
    }

    /// True once the run's GPU device is lost (a `retry` gets a new one).
    pub fn device_lost(&self) -> bool {
        self.run.device_lost()
    }

    /// Renders the layers, scores them and prepares the export files; resolves to the
    /// report (as JSON text).
    pub async fn finish(&mut self) -> Result<String, JsValue> {
        let o = match &self.lazy {
            Some((files, reader)) => {
                let mut f = super::lazy::fetcher(reader.clone());
                crate::tiles::finish_lazy(&mut self.run, &self.bundle, files, &mut f).await
            }
            None => self.run.finish(&self.bundle, &mut |_, _| {}).await,
        };
        // Kept for export even if the BEV failed.
        let (p, origin) = self.run.model();
        self.files =
            crate::export::model_files(p.held(), origin, &self.bundle.manifest, self.ply_up);
        self.map_files = false;
        let o = o.map_err(err)?;
        let r = self
            .run
            .report(&self.bundle, &o, &self.bundle.manifest.name);
        let text = serde_json::to_string_pretty(&r).map_err(err)?;
        self.outcome = Some(o);
        self.report = Some(text.clone());
        Ok(text)
    }

    /// The finished map's files (layers, report.json, map.rogsmap) beside the
    /// model's, encoded once, when first asked for: the page shows the map first.
    fn ensure_files(&mut self) -> Result<(), JsValue> {
        let (Some(o), Some(text), false) = (&self.outcome, &self.report, self.map_files) else {
            return Ok(());
        };
        let mut files = crate::export::files(o, &self.bundle.manifest).map_err(err)?;
        files.push(("report.json".into(), text.clone().into_bytes()));
        let map = crate::export::map_file::write(o, &self.bundle, text.as_bytes()).map_err(err)?;
        files.push(("map.rogsmap".into(), map));
        self.files.extend(files);
        self.map_files = true;
        Ok(())
    }

    /// Map width and height in pixels (the same for previews and the final layers).
    pub fn width(&self) -> u32 {
        self.geometry.width
    }

    pub fn height(&self) -> u32 {
        self.geometry.height
    }

    /// Metres per map pixel.
    pub fn resolution(&self) -> f64 {
        self.geometry.resolution
    }

    /// RGBA of the current model's BEV colour (throttle: it renders the whole map).
    pub async fn preview(&self) -> Result<Vec<u8>, JsValue> {
        self.run.preview().await.map_err(err)
    }

    /// Vehicle positions as map pixel coordinates, x and y interleaved.
    pub fn trajectory(&self) -> Vec<f32> {
        Session::trajectory(&self.bundle, &self.geometry)
    }

    /// Bytes of bundle files held in memory now (a lazily read bundle: the current
    /// tile's; read whole: 0, the zip's own bytes are not counted).
    pub fn held_bytes(&self) -> f64 {
        self.lazy.as_ref().map_or(0, |l| l.0.held_bytes()) as f64
    }

    /// Number of frames, for the camera-view panel.
    pub fn frames(&self) -> usize {
        self.bundle.manifest.frames.len()
    }

    /// `{width, height, rendered, input}` (RGBA) for view `view` of frame `frame`.
    pub async fn camera_view(&self, frame: usize, view: usize) -> Result<JsValue, JsValue> {
        // The last tile's session: untiled, the whole model.
        let s = self
            .run
            .session
            .as_ref()
            .ok_or_else(|| err("no trained tile to render from"))?;
        if let (Some((files, reader)), Some(fr)) =
            (&self.lazy, self.bundle.manifest.frames.get(frame))
        {
            // The view's input image, besides what the run holds.
            let mut wanted = self.run.wanted(&self.bundle);
            if let Some(v) = fr.views.get(view) {
                wanted.push(v.image.clone());
            }
            let mut f = super::lazy::fetcher(reader.clone());
            crate::tiles::hold(&self.bundle, files, &wanted, &mut f)
                .await
                .map_err(err)?;
        }
        let r = s
            .camera_view(&self.bundle, frame, view)
            .await
            .map_err(err)?
            .ok_or_else(|| err(format!("frame {frame} has no view {view}")))?;
        let o = js_sys::Object::new();
        let set = |k: &str, v: JsValue| js_sys::Reflect::set(&o, &k.into(), &v);
        set("width", r.0.into())?;
        set("height", r.1.into())?;
        set("rendered", js_sys::Uint8Array::from(&r.2[..]).into())?;
        set("input", js_sys::Uint8Array::from(&r.3[..]).into())?;
        Ok(o.into())
    }

    /// Elevation (world metres) at map pixel (x, y) of the finished map, if valid.
    pub fn elevation_at(&self, x: u32, y: u32) -> Option<f32> {
        let o = self.outcome.as_ref()?;
        let r = &o.raster;
        (x < r.width && y < r.height && r.is_valid(x, y)).then(|| r.elevation_at(x, y))
    }

    /// RGBA pixels of a layer (rgb, semantic, elevation, confidence, density, error).
    pub fn layer(&self, name: &str) -> Result<Vec<u8>, JsValue> {
        let o = self.outcome.as_ref().ok_or_else(|| err("finish first"))?;
        crate::export::layer_rgba(o, &self.bundle.manifest, name)
            .ok_or_else(|| err(format!("no layer {name:?} for this map")))
    }

    /// bev.json of the finished map (geometry, elevation range), without encoding
    /// its files.
    pub fn bev_json(&self) -> Result<String, JsValue> {
        let o = self.outcome.as_ref().ok_or_else(|| err("finish first"))?;
        let range = crate::export::range(&crate::export::elevation(o));
        let v = crate::export::bev_json(&o.geometry, &self.bundle.manifest, range);
        serde_json::to_string(&v).map_err(err)
    }

    /// Names of the export files (the map's are encoded on the first call).
    pub fn file_names(&mut self) -> Result<Vec<String>, JsValue> {
        self.ensure_files()?;
        Ok(self.files.iter().map(|f| f.0.clone()).collect())
    }

    /// The bytes of one export file.
    pub fn file(&mut self, name: &str) -> Result<Vec<u8>, JsValue> {
        self.ensure_files()?;
        self.files
            .iter()
            .find(|f| f.0 == name)
            .map(|f| f.1.clone())
            .ok_or_else(|| err(format!("no file {name:?}")))
    }

    /// Every export file in one zip (the CLI's output folder, zipped).
    pub fn exports_zip(&mut self) -> Result<Vec<u8>, JsValue> {
        self.ensure_files()?;
        let mut z = crate::bundle::ZipBundleWriter::new(std::io::Cursor::new(Vec::new()));
        for (name, bytes) in &self.files {
            z.add(name, bytes).map_err(err)?;
        }
        Ok(z.finish_raw().map_err(err)?.into_inner())
    }
}
