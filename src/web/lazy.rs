//! Bundles read lazily by the page (`www/bundle.js`): the zip's directory and
//! manifest first, then the files a tile needs, fetched from the dropped file (or
//! `?url=` by range requests) through a JavaScript reader when the run asks.

use crate::bundle::{Bundle, BundleErrors, LazyStore, Limits, Problem, MANIFEST};
use crate::tiles::Fetched;
use std::sync::Arc;
use wasm_bindgen::prelude::*;
use wasm_bindgen_futures::JsFuture;

/// A bundle over a store that holds only its manifest so far.
pub fn open(
    manifest: Vec<u8>,
    names: Vec<String>,
    sizes: Vec<f64>,
) -> Result<(Bundle, Arc<LazyStore>), BundleErrors> {
    let limits = Limits::default();
    if names.len() != sizes.len() {
        return Err(BundleErrors(vec![Problem::NotZip(format!(
            "{} entry names but {} sizes",
            names.len(),
            sizes.len()
        ))]));
    }
    let table = names
        .into_iter()
        .zip(sizes)
        .map(|(n, s)| {
            (
                n,
                if s.is_finite() && s >= 0.0 {
                    s as u64
                } else {
                    u64::MAX
                },
            )
        })
        .collect();
    let store = Arc::new(LazyStore::new(table, &limits).map_err(BundleErrors)?);
    store
        .provide(MANIFEST, manifest)
        .map_err(|p| BundleErrors(vec![p]))?;
    let b = Bundle::from_store(store.clone(), limits)?;
    Ok((b, store))
}

fn sentence(v: JsValue) -> String {
    v.as_string()
        .or_else(|| {
            js_sys::Reflect::get(&v, &"message".into())
                .ok()
                .and_then(|m| m.as_string())
        })
        .unwrap_or_else(|| format!("{v:?}"))
}

/// A `Fetch` over the page's reader: `reader([[drive, path], …])` resolves to the
/// files' bytes (Uint8Array each), in order.
pub fn fetcher(reader: js_sys::Function) -> impl FnMut(Vec<(usize, String)>) -> Fetched<'static> {
    move |want: Vec<(usize, String)>| {
        let reader = reader.clone();
        Box::pin(async move {
            let pairs = js_sys::Array::new();
            for (k, p) in &want {
                pairs.push(&js_sys::Array::of2(&(*k as u32).into(), &p.as_str().into()));
            }
            let promise = reader.call1(&JsValue::NULL, &pairs).map_err(sentence)?;
            let got = JsFuture::from(js_sys::Promise::resolve(&promise))
                .await
                .map_err(sentence)?;
            if !js_sys::Array::is_array(&got) {
                return Err("the page's reader did not resolve to an array of files".into());
            }
            Ok(js_sys::Array::from(&got)
                .iter()
                .map(|v| js_sys::Uint8Array::new(&v).to_vec())
                .collect())
        })
    }
}
