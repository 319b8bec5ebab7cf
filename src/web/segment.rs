//! The page's segmentation module (feature `segmenter`; scripts/build-segment.sh
//! builds it into www/pkg-segment): labels every view of a dropped bundle with a
//! road-segmentation network, as `rogs segment` does, through the same
//! `segment::label_bundle`. The page runs it in a Web Worker (www/segment-worker.js)
//! and fetches it only when a model is dropped, so the engine's module stays small
//! and the page responsive. Errors are values with a sentence; nothing may panic.

use crate::bundle::{Bundle, Limits};
use crate::segment::{label_bundle, ClassMap, Segmenter};
use wasm_bindgen::prelude::*;

#[wasm_bindgen(start)]
pub fn start() {
    console_error_panic_hook::set_once();
}

/// The class map `classes` names: `twinlitenet` (the built-in map of the test model)
/// or a class map's JSON text (docs/SEGMENT.md), named `name` in errors.
fn class_map(classes: &str, name: &str) -> Result<ClassMap, String> {
    if classes == "twinlitenet" {
        Ok(ClassMap::twinlitenet())
    } else {
        ClassMap::from_json(name, classes.as_bytes())
    }
}

/// Labels every view of the bundle `bundle` (a zip's bytes, named `bundle_name`) with
/// the ONNX model `model` (named `model_name`) and the class map `classes`
/// (`twinlitenet` or a class map's JSON text, named `classes_name`): resolves to
/// `{bytes, views, notes}`, the labelled bundle's zip. `progress(done, total)` is
/// called after each batch of views.
#[wasm_bindgen]
pub fn label_bundle_zip(
    bundle: Vec<u8>,
    bundle_name: &str,
    model: Vec<u8>,
    model_name: &str,
    classes: &str,
    classes_name: &str,
    progress: &js_sys::Function,
) -> Result<JsValue, JsValue> {
    let map = class_map(classes, classes_name).map_err(|e| JsValue::from_str(&e))?;
    let seg =
        Segmenter::new(model_name, &model, map).map_err(|e| JsValue::from_str(&e.to_string()))?;
    drop(model);
    let b = Bundle::from_zip_bytes(bundle, Limits::default())
        .map_err(|e| JsValue::from_str(&format!("{bundle_name}: {e}")))?;
    let mut report = |done: usize, total: usize| {
        // A callback that throws only loses the progress, not the labels.
        let _ = progress.call2(
            &JsValue::NULL,
            &(done as f64).into(),
            &(total as f64).into(),
        );
    };
    let out = label_bundle(&b, &seg, std::io::Cursor::new(Vec::new()), &mut report)
        .map_err(|e| JsValue::from_str(&format!("{bundle_name}: {e}")))?;
    let views: usize = out.manifest.frames.iter().map(|f| f.views.len()).sum();
    let o = js_sys::Object::new();
    let set = |k: &str, v: JsValue| js_sys::Reflect::set(&o, &k.into(), &v).map(|_| ());
    set(
        "bytes",
        js_sys::Uint8Array::from(out.sink.into_inner().as_slice()).into(),
    )?;
    set("views", (views as f64).into())?;
    let notes = js_sys::Array::new();
    for n in &out.notes {
        notes.push(&n.into());
    }
    set("notes", notes.into())?;
    Ok(o.into())
}
