//! The JavaScript API (wasm32 only). Every entry point returns errors as values or
//! rejected promises with a sentence for the page to show; none may panic.

use crate::bundle::{example, write_zip, Bundle, Limits};
use crate::gpu::scatter_add::{scatter_add_cpu, scatter_add_gpu};
use crate::gpu::GpuContext;
use serde::Serialize;
use wasm_bindgen::prelude::*;

mod lazy;
pub mod map;

#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
}

/// Bytes of the module's linear memory (the wasm heap): it only grows.
#[wasm_bindgen]
pub fn wasm_memory_bytes() -> f64 {
    wasm_bindgen::memory()
        .dyn_into::<js_sys::WebAssembly::Memory>()
        .map_or(0.0, |m| {
            js_sys::ArrayBuffer::from(m.buffer()).byte_length() as f64
        })
}

#[wasm_bindgen]
pub fn version() -> String {
    env!("CARGO_PKG_VERSION").into()
}

#[derive(Serialize)]
struct ProblemJs {
    location: String,
    message: String,
}

#[derive(Serialize)]
#[serde(tag = "status", rename_all = "lowercase")]
enum InspectJs {
    Valid { summary: crate::bundle::Summary },
    Invalid { problems: Vec<ProblemJs> },
}

fn to_js<T: Serialize>(v: &T) -> Result<JsValue, JsValue> {
    serde_wasm_bindgen::to_value(v).map_err(|e| JsValue::from_str(&e.to_string()))
}

/// Dropped bundles up to this size have every image decoded when they are checked.
const DECODE_ON_DROP_BYTES: usize = 64 << 20;

/// Validates the bytes of a bundle `.zip`: `{status: "valid", summary}` or
/// `{status: "invalid", problems: [{location, message}]}`.
#[wasm_bindgen]
pub fn inspect_bundle(bytes: Vec<u8>) -> Result<JsValue, JsValue> {
    // Every image decoded, as `rogs inspect` does, so a damaged one is named on drop;
    // past 64 MiB that would hold the page for seconds without progress, and images
    // are decoded (and a damaged one named) as the run reads them.
    let limits = Limits {
        decode_images: bytes.len() <= DECODE_ON_DROP_BYTES,
        ..Limits::default()
    };
    inspected(Bundle::from_zip_bytes(bytes, limits))
}

/// As `inspect_bundle`, for a bundle read lazily (`www/bundle.js`): its manifest and
/// its zip's table of entries (names, uncompressed sizes). The checks are the
/// structural ones; each image and label is checked when a tile reads it.
#[wasm_bindgen]
pub fn inspect_lazy_bundle(
    manifest: Vec<u8>,
    names: Vec<String>,
    sizes: Vec<f64>,
) -> Result<JsValue, JsValue> {
    inspected(lazy::open(manifest, names, sizes).map(|(b, _)| b))
}

fn inspected(r: Result<Bundle, crate::bundle::BundleErrors>) -> Result<JsValue, JsValue> {
    let result = match r {
        Ok(b) => InspectJs::Valid {
            summary: b.summary(),
        },
        Err(e) => InspectJs::Invalid {
            problems: e
                .0
                .iter()
                .map(|p| ProblemJs {
                    location: p.location().to_string(),
                    message: p.to_string(),
                })
                .collect(),
        },
    };
    to_js(&result)
}

/// The tiny example bundle as `.zip` bytes.
#[wasm_bindgen]
pub fn example_bundle() -> Result<Vec<u8>, JsValue> {
    let (m, files) = example::tiny();
    write_zip(&m, &files).map_err(|e| JsValue::from_str(&e))
}

/// The embedded demo scene (`synth::demo_scene`): `{ bundle, truth_map }`, zip bytes.
#[wasm_bindgen]
pub fn demo_scene() -> Result<JsValue, JsValue> {
    let (bundle, map) = crate::synth::demo_scene().map_err(|e| JsValue::from_str(&e))?;
    let o = js_sys::Object::new();
    js_sys::Reflect::set(&o, &"bundle".into(), &js_sys::Uint8Array::from(&bundle[..]))?;
    js_sys::Reflect::set(&o, &"truth_map".into(), &js_sys::Uint8Array::from(&map[..]))?;
    Ok(o.into())
}

/// Finds the WebGPU adapter, runs the scatter-add self-test against the CPU and
/// returns the adapter report; rejects with advice when WebGPU is unavailable.
#[wasm_bindgen]
pub async fn gpu_info() -> Result<JsValue, JsValue> {
    let ctx = GpuContext::new()
        .await
        .map_err(|e| JsValue::from_str(&e.to_string()))?;
    let index: Vec<u32> = (0..4096u32).map(|i| i * 31 % 64).collect();
    let values: Vec<f32> = (0..4096).map(|i| (i % 5) as f32 * 0.5).collect();
    let gpu = scatter_add_gpu(&ctx, ctx.report.accumulation, 64, &index, &values).await;
    // The self-test's device is not kept, whatever the test gave.
    ctx.release();
    let gpu = gpu.map_err(|e| JsValue::from_str(&e.to_string()))?;
    let cpu = scatter_add_cpu(64, &index, &values);
    if gpu.iter().zip(&cpu).any(|(a, b)| (a - b).abs() > 1e-3) {
        return Err(JsValue::from_str(
            "the GPU self-test gave wrong sums: this browser's WebGPU implementation is not usable",
        ));
    }
    to_js(&ctx.report)
}

/// The rasteriser benchmark (`rogs bench raster`) in the browser: one view of the
/// bundle `bytes` at grid `resolution` (metres), `runs` times forward and forward +
/// backward; the figures as JSON text (scripts/bench-raster-page.mjs).
#[wasm_bindgen]
pub async fn bench_raster(
    bytes: Vec<u8>,
    frame: usize,
    view: usize,
    runs: usize,
    resolution: f64,
) -> Result<String, JsValue> {
    use crate::render::bench::{raster_view, RasterBench};
    let b = Bundle::from_zip_bytes(bytes, Limits::default())
        .map_err(|e| JsValue::from_str(&e.to_string()))?;
    let ctx = GpuContext::new()
        .await
        .map_err(|e| JsValue::from_str(&e.to_string()))?;
    let o = RasterBench {
        frame,
        view,
        runs,
        resolution,
        adaptive: true,
    };
    let now = || js_sys::Date::now() / 1e3;
    let out = raster_view(&ctx, &b, &o, &now)
        .await
        .map_err(|e| JsValue::from_str(&e))?;
    Ok(out.to_string())
}

/// The training-step benchmark (`rogs bench step`) in the browser: `steps` timed
/// steps of the bundle `bytes` at grid `resolution` (metres), corridor `half_width`
/// (metres); the figures as JSON text (scripts/bench-ratio.mjs).
#[wasm_bindgen]
pub async fn bench_step(
    bytes: Vec<u8>,
    steps: usize,
    resolution: f64,
    half_width: f64,
) -> Result<String, JsValue> {
    use crate::optim::bench::{step, StepBench};
    let mut b = Bundle::from_zip_bytes(bytes, Limits::default())
        .map_err(|e| JsValue::from_str(&e.to_string()))?;
    let ctx = GpuContext::new()
        .await
        .map_err(|e| JsValue::from_str(&e.to_string()))?;
    let o = StepBench {
        steps,
        resolution,
        half_width,
        moment_window: None,
        adam: crate::optim::TrainConfig::default().adam,
        frame_exposure: crate::optim::TrainConfig::default().frame_exposure,
    };
    let now = || js_sys::Date::now() / 1e3;
    let out = step(&mut b, "bundle", &o, ctx, &now)
        .await
        .map_err(|e| JsValue::from_str(&e))?;
    Ok(out.to_string())
}
