//! Lazy reading, on lavapipe: a tiled run whose bundle holds only the files the run
//! says it will read (as the page reads a dropped drive, `tiles::files`) makes the
//! same map as the same run reading the whole zip, holding one tile's files at a
//! time; a file it was not given is a named, recoverable error; a bad image is
//! refused by name when it arrives.
#![cfg(not(target_arch = "wasm32"))]

mod common;

use rogs::bundle::{write_zip, Bundle, LazyFiles, LazyStore, Limits, Manifest};
use rogs::gpu::GpuContext;
use rogs::reconstruct::{Outcome, ReconstructConfig};
use rogs::synth::{generate, Preset, SynthConfig};
use rogs::tiles::{finish_lazy, start_lazy, step_lazy, Fetch, Fetched, TileConfig, TiledRun};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

fn ctx() -> GpuContext {
    GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"))
}

fn demo_zip(length_m: Option<f64>) -> (Manifest, Vec<u8>) {
    let mut c = SynthConfig::preset(Preset::Demo, 1);
    c.lidar = true;
    c.rays_per_axis = 1;
    if let Some(l) = length_m {
        c.set_length_m(l);
    }
    let out = generate(&c, &|_, _, _| {}).expect("synth");
    let zip = write_zip(&out.manifest, &out.files).expect("zip");
    (out.manifest, zip)
}

fn entries(zip: &[u8]) -> HashMap<String, Vec<u8>> {
    common::zip_entries(zip).into_iter().collect()
}

fn cfg() -> ReconstructConfig {
    let mut c = ReconstructConfig::default();
    c.prepare.grid.half_width = 4.0;
    c.prepare.grid.resolution = 0.1;
    c.train.max_steps = Some(8);
    c
}

const TILES: Option<TileConfig> = Some(TileConfig {
    size_m: 16.0,
    overlap_m: 2.0,
    origin_m: None,
});

fn eager(zip: Vec<u8>) -> Outcome {
    let mut b = Bundle::from_zip_bytes(zip, Limits::default()).expect("bundle");
    let mut r = pollster::block_on(TiledRun::new(&mut b, cfg(), TILES, ctx())).expect("run");
    while pollster::block_on(r.step(&b)).expect("step").is_some() {}
    pollster::block_on(r.finish(&b, &mut |_, _| {})).expect("finish")
}

struct Lazy {
    b: Bundle,
    files: LazyFiles,
    all: Arc<HashMap<String, Vec<u8>>>,
    asked: Arc<Mutex<Vec<String>>>,
}

fn lazy(zip: &[u8], damage: Option<&str>) -> Lazy {
    let mut all = entries(zip);
    if let Some(p) = damage {
        let v = all.get_mut(p).expect("entry to damage");
        let n = v.len();
        v[n / 3..].iter_mut().for_each(|x| *x = 0);
    }
    let table = all
        .iter()
        .map(|(k, v)| (k.clone(), v.len() as u64))
        .collect();
    let store = Arc::new(LazyStore::new(table, &Limits::default()).expect("store"));
    store
        .provide("manifest.json", all["manifest.json"].clone())
        .expect("manifest");
    let b = Bundle::from_store(store.clone(), Limits::default()).expect("structure");
    Lazy {
        b,
        files: LazyFiles {
            stores: vec![store],
        },
        all: Arc::new(all),
        asked: Arc::default(),
    }
}

fn fetcher(l: &Lazy) -> impl FnMut(Vec<(usize, String)>) -> Fetched<'static> {
    let (all, asked) = (l.all.clone(), l.asked.clone());
    move |want: Vec<(usize, String)>| {
        let (all, asked) = (all.clone(), asked.clone());
        Box::pin(async move {
            want.iter()
                .map(|(_, p)| {
                    asked.lock().expect("lock").push(p.clone());
                    all.get(p).cloned().ok_or(format!("{p}: no such entry"))
                })
                .collect()
        })
    }
}

#[test]
fn a_lazily_read_run_makes_the_same_map_holding_one_tile_at_a_time() {
    // Long enough that a tile's near frames are a part of the drive.
    let (m, zip) = demo_zip(Some(120.0));
    let reference = eager(zip.clone());
    let mut l = lazy(&zip, None);
    let mut f = fetcher(&l);
    let fetch: &mut Fetch = &mut f;
    let mut run = pollster::block_on(start_lazy(&mut l.b, &l.files, cfg(), TILES, ctx(), fetch))
        .expect("start");
    assert!(run.tiles.len() >= 3, "{} tiles", run.tiles.len());
    let total: u64 = l
        .all
        .iter()
        .filter(|(k, _)| *k != "manifest.json")
        .map(|(_, v)| v.len() as u64)
        .sum();
    let mut peak = 0u64;
    while pollster::block_on(step_lazy(&mut run, &l.b, &l.files, fetch))
        .expect("step")
        .is_some()
    {
        peak = peak.max(l.files.held_bytes());
    }
    let o = pollster::block_on(finish_lazy(&mut run, &l.b, &l.files, fetch)).expect("finish");
    eprintln!("held at most {peak} of {total} bytes");
    // One tile's files at a time (its frames within the culling distance, about
    // 70 m of drive, with the next tile's): under the bundle, and on a long drive a
    // bounded window of it.
    assert!(
        (peak as f64) < 0.8 * total as f64,
        "held {peak} of {total} bytes"
    );
    // Every image read while training is asked for once per tile that reads it, not
    // once per step.
    let asked = l.asked.lock().expect("lock").len();
    let views: usize = m.frames.iter().map(|f| f.views.len()).sum();
    assert!(asked < 2 * views * run.tiles.len(), "{asked} reads");
    // The same map: the same coverage, elevations and colours (GPU sums may differ
    // in their last bits between runs).
    let (ra, rb) = (&reference.raster, &o.raster);
    assert_eq!((ra.width, ra.height), (rb.width, rb.height));
    let (mut n, mut dz, mut dc, mut cover) = (0usize, 0f64, 0f64, 0usize);
    for row in 0..ra.height {
        for col in 0..ra.width {
            cover += (ra.is_valid(col, row) != rb.is_valid(col, row)) as usize;
            if !(ra.is_valid(col, row) && rb.is_valid(col, row)) {
                continue;
            }
            n += 1;
            dz = dz.max((ra.elevation_at(col, row) - rb.elevation_at(col, row)).abs() as f64);
            let (pa, pb) = (ra.rgb.get_pixel(col, row).0, rb.rgb.get_pixel(col, row).0);
            dc = dc.max(
                (0..3)
                    .map(|c| (pa[c] as f64 - pb[c] as f64).abs())
                    .fold(0.0, f64::max),
            );
        }
    }
    assert!(n > 1000, "{n} pixels");
    assert!(cover * 1000 <= n, "{cover} pixels covered by one map only");
    assert!(dz < 1e-3, "elevations differ by up to {dz} m");
    assert!(dc <= 2.0, "colours differ by up to {dc} levels");
    let psnr = |o: &Outcome| o.metrics.as_ref().and_then(|m| m.psnr_db).expect("PSNR");
    let (ma, mb) = (psnr(&reference), psnr(&o));
    assert!((ma - mb).abs() < 0.05, "{} vs {} dB", ma, mb);
}

#[test]
fn a_file_not_given_is_named_and_a_damaged_image_is_refused_when_it_arrives() {
    let (m, zip) = demo_zip(None);
    // Nothing provided: the step names the file it lacks and changes nothing.
    let mut l = lazy(&zip, None);
    let mut f = fetcher(&l);
    let fetch: &mut Fetch = &mut f;
    let mut run = pollster::block_on(start_lazy(&mut l.b, &l.files, cfg(), TILES, ctx(), fetch))
        .expect("start");
    l.files.retain(&[]);
    let e = match pollster::block_on(run.step(&l.b)) {
        Err(e) => e,
        Ok(_) => panic!("a step without its files must fail"),
    };
    let path = e.not_loaded().expect("a not-loaded error").to_string();
    assert!(
        e.to_string().contains(&path) && e.to_string().contains("not read yet"),
        "{e}"
    );
    assert!(run.failed.is_none(), "a missing file is not a failed tile");
    assert!(
        pollster::block_on(step_lazy(&mut run, &l.b, &l.files, fetch))
            .expect("the same step, once the files are there")
            .is_some()
    );

    // A damaged image of a view of the first tile: refused by name when fetched.
    let (f0, v0) = run.tiles[0].views[0];
    let bad = m.frames[f0].views[v0].image.clone();
    let mut l = lazy(&zip, Some(&bad));
    let mut f = fetcher(&l);
    let fetch: &mut Fetch = &mut f;
    let mut run = pollster::block_on(start_lazy(&mut l.b, &l.files, cfg(), TILES, ctx(), fetch))
        .expect("start");
    let e = match pollster::block_on(step_lazy(&mut run, &l.b, &l.files, fetch)) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a damaged image must be refused"),
    };
    assert!(e.contains(&bad), "{e}");
}
