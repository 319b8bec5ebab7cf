//! Spatial tiles and several drives in one map, on lavapipe: a tiled reconstruction of
//! a small scene against the untiled one computed in the same run, the seams across
//! tile borders against the same statistic inside tiles, one set of surfels where
//! tiles overlap, and two drives merged into one map (or refused when they do not
//! overlap).
#![cfg(not(target_arch = "wasm32"))]

mod common;

use rogs::bundle::{write_zip, Bundle, Limits, Manifest};
use rogs::gpu::GpuContext;
use rogs::reconstruct::{Outcome, ReconstructConfig};
use rogs::synth::{generate, Preset, SynthConfig};
use rogs::tiles::{plan, seams, TileConfig, TiledRun};

fn ctx() -> GpuContext {
    GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"))
}

fn demo() -> (Manifest, Vec<rogs::bundle::BundleFile>) {
    let mut c = SynthConfig::preset(Preset::Demo, 1);
    c.lidar = true;
    c.rays_per_axis = 1;
    let out = generate(&c, &|_, _, _| {}).expect("synth");
    (out.manifest, out.files)
}

fn bundle(m: &Manifest, files: &[rogs::bundle::BundleFile]) -> Bundle {
    let zip = write_zip(m, files).expect("zip");
    Bundle::from_zip_bytes(zip, Limits::default()).expect("valid bundle")
}

fn cfg() -> ReconstructConfig {
    let mut c = ReconstructConfig::default();
    c.prepare.grid.half_width = 4.0;
    c.prepare.grid.resolution = 0.1;
    c
}

fn run(b: &mut Bundle, tiling: Option<TileConfig>) -> (TiledRun, Outcome) {
    let mut r = pollster::block_on(TiledRun::new(b, cfg(), tiling, ctx())).expect("run");
    while pollster::block_on(r.step(b)).expect("step").is_some() {}
    let o = pollster::block_on(r.finish(b, &mut |_, _| {})).expect("finish");
    (r, o)
}

/// Agreement of two maps over the same geometry: coverage IoU, mean |Δ elevation|
/// (m), colour PSNR (dB) and class agreement over the pixels both cover.
fn agreement(a: &Outcome, b: &Outcome) -> (f64, f64, f64, f64) {
    let (ra, rb) = (&a.raster, &b.raster);
    assert_eq!((ra.width, ra.height), (rb.width, rb.height));
    let (mut both, mut either, mut dz, mut se, mut same) = (0usize, 0usize, 0.0, 0.0, 0usize);
    for row in 0..ra.height {
        for col in 0..ra.width {
            let (va, vb) = (ra.is_valid(col, row), rb.is_valid(col, row));
            either += (va || vb) as usize;
            if !(va && vb) {
                continue;
            }
            both += 1;
            dz += (ra.elevation_at(col, row) - rb.elevation_at(col, row)).abs() as f64;
            let (pa, pb) = (ra.rgb.get_pixel(col, row).0, rb.rgb.get_pixel(col, row).0);
            for c in 0..3 {
                se += ((pa[c] as f64 - pb[c] as f64) / 255.0).powi(2);
            }
            same += (ra.class_ids.get_pixel(col, row) == rb.class_ids.get_pixel(col, row)) as usize;
        }
    }
    let n = both.max(1) as f64;
    (
        both as f64 / either.max(1) as f64,
        dz / n,
        -10.0 * (se / (3.0 * n)).max(1e-12).log10(),
        same as f64 / n,
    )
}

#[test]
fn a_tiled_map_matches_the_untiled_one_without_seams() {
    let (m, files) = demo();
    let mut b = bundle(&m, &files);
    let (_, untiled) = run(&mut b, None);
    let mut b = bundle(&m, &files);
    let t = TileConfig {
        size_m: 12.0,
        overlap_m: 4.0,
        origin_m: None,
    };
    let (r, tiled) = run(&mut b, Some(t));
    let trained = r.reports.iter().filter(|t| t.steps > 0).count();
    assert!(
        trained >= 4,
        "expected several trained tiles, got {:?}",
        r.reports
    );
    // The GPU held one tile at a time: each tile is a fraction of the map.
    let total = untiled.params.len();
    for t in &r.reports {
        assert!(
            t.surfels < total * 3 / 4,
            "tile {} holds {} of {total} surfels",
            t.name,
            t.surfels
        );
    }
    // One set of surfels: no two in the model at the same place (overlaps are cut
    // at the cores), and the model covers what the untiled one covers.
    let mut xy: Vec<[i64; 2]> = tiled
        .params
        .pos
        .iter()
        .map(|p| {
            let q = |k: usize| ((p[k] as f64 + r.model_origin[k]) * 40.0).round() as i64;
            [q(0), q(1)]
        })
        .collect();
    xy.sort_unstable();
    let n = xy.len();
    xy.dedup();
    assert_eq!(xy.len(), n, "duplicate surfels in the tiled model");
    let ratio = n as f64 / total as f64;
    assert!(
        (0.98..1.02).contains(&ratio),
        "tiled model {n} surfels, untiled {total}"
    );

    let (cov, dz, psnr, cls) = agreement(&untiled, &tiled);
    eprintln!("tiled vs untiled: coverage IoU {cov:.4}, |dz| {dz:.4} m, PSNR {psnr:.2} dB, classes {cls:.4}");
    let (mu, mt) = (
        untiled.metrics.clone().unwrap(),
        tiled.metrics.clone().unwrap(),
    );
    eprintln!("untiled {mu:?}\ntiled   {mt:?}");
    // Measured: coverage 0.9997, |dz| 0.25 cm, 44.1 dB, classes 0.997 (two
    // optimisations of the same views, tiles with their own exposure and schedule).
    assert!(cov > 0.98, "coverage IoU {cov}");
    assert!(dz < 0.015, "mean elevation difference {dz} m");
    assert!(
        psnr > 26.0,
        "colour PSNR of one map against the other {psnr} dB"
    );
    assert!(cls > 0.9, "class agreement {cls}");
    // Against the truth, the tiled map is as good as the untiled one.
    assert!(mt.psnr_db.unwrap() > mu.psnr_db.unwrap() - 0.5);
    assert!(mt.miou.unwrap() > mu.miou.unwrap() - 0.03);
    assert!(mt.elevation_rmse_m.unwrap() < mu.elevation_rmse_m.unwrap() + 0.005);

    // Seams: the steps between neighbouring pixels across tile borders, against the
    // same lines of the untiled map (the borders may fall on paint or a kerb) and
    // against lines inside tiles. Measured: elevation 2.32 mm tiled, 2.24 mm untiled;
    // colour 0.0243 tiled, 0.0244 untiled.
    let settled = r.tiling.expect("tiled");
    let s = seams(&tiled.raster, &settled);
    let su = seams(&untiled.raster, &settled);
    eprintln!("seams tiled {s:?}\nseams untiled {su:?}");
    assert!(s.border_pairs > 100 && s.inside_pairs > 100, "{s:?}");
    assert!(
        s.border_elevation_step_m < 1.25 * su.border_elevation_step_m + 0.0005,
        "elevation seam {s:?} (untiled {su:?})"
    );
    assert!(
        s.border_rgb_step < 1.25 * su.border_rgb_step + 0.002,
        "colour seam {s:?} (untiled {su:?})"
    );
    // Borders against lines inside tiles, relative to the same ratio on the untiled
    // map (the scene's own relief decides where lines fall on kerbs): measured 2.03
    // tiled, 2.04 untiled.
    let ratio = |s: &rogs::tiles::Seams| s.border_elevation_step_m / s.inside_elevation_step_m;
    assert!(
        ratio(&s) < 1.25 * ratio(&su),
        "elevation steps at borders {s:?} (untiled {su:?})"
    );
    let report = r.report(&b, &tiled, "demo");
    assert_eq!(
        report["tiles"].as_array().map(|a| a.len()),
        Some(r.reports.len())
    );
    assert!(report["seams"]["border_pairs"].as_u64().unwrap_or(0) > 0);
    // Every tile's frame gains in one summary: a view that sees two tiles counts
    // in each.
    let per_tile: u64 = r
        .reports
        .iter()
        .filter_map(|t| t.frame_gains["views"].as_u64())
        .sum();
    assert!(per_tile > 0 && report["frame_gains"]["views"].as_u64() == Some(per_tile));
    assert!(report["peak_gpu_bytes"].as_u64().unwrap_or(0) > 0);
    assert!(report["peak_host_bytes"].as_u64().unwrap_or(0) > 0);
    assert!(report["peak_host_training_bytes"].as_u64().unwrap_or(0) > 0);
    // The blend sealed each block as the last tile rendering into it finished (the
    // map here spans few blocks, so the peak is not lower; stitch.rs tests that on a
    // longer one), and sealed blocks hold a fraction of their sums.
    let blend = &report["blend"];
    assert_eq!(blend["blocks_open"].as_u64(), Some(0), "{blend}");
    assert!(blend["blocks_sealed"].as_u64().unwrap_or(0) > 0, "{blend}");
    let windows: Vec<_> = r
        .tiles
        .iter()
        .filter_map(|t| rogs::tiles::Stitcher::new(r.geometry, 1, 0.0).window(&t.rect))
        .collect();
    let all_open =
        rogs::tiles::Stitcher::block_bytes(&r.geometry, tiled.params.channels, windows.iter());
    let held = blend["held_bytes"].as_u64().unwrap_or(u64::MAX);
    assert!(
        held < all_open / 2,
        "sealed blend {held} B, open {all_open} B"
    );
    let peak = blend["peak_held_bytes"].as_u64().unwrap_or(u64::MAX);
    assert!(
        peak <= all_open,
        "blend peak {peak} B, all blocks open {all_open} B"
    );
}

#[test]
fn every_planned_tile_is_seen_and_views_that_see_two_tiles_train_both() {
    let (m, files) = demo();
    let b = bundle(&m, &files);
    let t = TileConfig {
        size_m: 12.0,
        overlap_m: 4.0,
        origin_m: None,
    };
    let (_, tiles) = plan(&b, &cfg(), &t);
    assert!(tiles.len() >= 4);
    let views: usize = m.frames.iter().map(|f| f.views.len()).sum();
    let planned: usize = tiles.iter().map(|t| t.views.len()).sum();
    // Nearly every view sees a tile (the last frames' front cameras look past the
    // end of the corridor), and many see more than one.
    let seen = m
        .frames
        .iter()
        .enumerate()
        .flat_map(|(f, fr)| (0..fr.views.len()).map(move |v| (f, v)))
        .filter(|&(f, v)| tiles.iter().any(|t| t.sees(f, v)))
        .count();
    assert!(seen * 10 >= views * 9, "{seen} of {views} views in a tile");
    assert!(planned > views, "{planned} planned views for {views} views");
    // Cores tile the plane: no two tiles share a core.
    for (i, a) in tiles.iter().enumerate() {
        for c in &tiles[i + 1..] {
            assert_ne!(a.id, c.id);
        }
        assert!(a.rect.min[0] < a.core.min[0] && a.rect.max[1] > a.core.max[1]);
    }
}

/// The manifest with only frames `r` (the files stay: unreferenced ones are allowed).
fn part(m: &Manifest, r: std::ops::Range<usize>, shift_x: f64) -> Manifest {
    let mut p = m.clone();
    p.frames = m.frames[r].to_vec();
    for f in &mut p.frames {
        f.vehicle_to_world[0][3] += shift_x;
    }
    p
}

#[test]
fn two_drives_of_one_street_make_one_map_and_drives_apart_are_refused() {
    let (m, files) = demo();
    let n = m.frames.len();
    let drives = || {
        vec![
            bundle(&part(&m, 0..n * 2 / 3, 0.0), &files),
            bundle(&part(&m, n / 3..n, 0.0), &files),
        ]
    };
    let names = ["a.zip".to_string(), "b.zip".to_string()];
    let mut merged = Bundle::merge(drives(), &names).expect("merge");
    assert_eq!(merged.drives.len(), 2);
    assert_eq!(merged.manifest.cameras.len(), 2 * m.cameras.len());
    assert_eq!(merged.manifest.frames.len(), n * 2 / 3 + (n - n / 3));
    // Every file of the second drive is read through its own source.
    let v = &merged.manifest.frames[merged.drives[1].frames.start].views[0];
    assert!(v.image.starts_with("drive1/") && v.camera.ends_with("#2"));
    merged
        .read_rgb(&v.image.clone())
        .expect("second drive's image");
    let (r, o) = run(&mut merged, None);
    let mut whole = bundle(&m, &files);
    let (_, ow) = run(&mut whole, None);
    let (cov, dz, psnr, _) = agreement(&ow, &o);
    let (mm, mw) = (o.metrics.clone().unwrap(), ow.metrics.clone().unwrap());
    eprintln!("merged {mm:?}\nwhole {mw:?}\ncoverage {cov:.4} |dz| {dz:.4} PSNR {psnr:.2}");
    // The merged map covers the union of the drives (the whole street) ...
    assert!(cov > 0.97, "coverage IoU against the whole drive {cov}");
    // ... with no corridor joining the end of drive a to the start of drive b, and
    // as good as the single drive over the same frames (the shared third is seen twice).
    assert!(mm.psnr_db.unwrap() > mw.psnr_db.unwrap() - 0.5);
    assert!(mm.miou.unwrap() > mw.miou.unwrap() - 0.03);
    assert!(mm.elevation_rmse_m.unwrap() < mw.elevation_rmse_m.unwrap() + 0.005);
    let report = r.report(&merged, &o, "a + b");
    assert_eq!(report["drives"].as_array().map(|d| d.len()), Some(2));

    // A drive 1 km away shares no street: refused, naming it.
    let apart = vec![
        bundle(&part(&m, 0..n, 0.0), &files),
        bundle(&part(&m, 0..n, 1000.0), &files),
    ];
    let e = match Bundle::merge(apart, &names) {
        Ok(_) => panic!("drives 1 km apart were merged"),
        Err(e) => e.to_string(),
    };
    assert!(e.contains("b.zip") && e.contains("does not overlap"), "{e}");
    // Other class tables are refused by name.
    let mut other = part(&m, 0..n, 0.0);
    other.semantic_classes[0].name = "tarmac".into();
    let e = match Bundle::merge(vec![bundle(&m, &files), bundle(&other, &files)], &names) {
        Ok(_) => panic!("merged other class tables"),
        Err(e) => e.to_string(),
    };
    assert!(e.contains("b.zip: semantic_classes"), "{e}");
    // Two drives of one dataset frame, each shifted to its own first pose (as the
    // nuScenes importer does): b's poses are brought into a's, so the 1 km shift
    // the offsets explain is undone and they merge.
    let framed = |m: &Manifest, off: f64| {
        let mut p = m.clone();
        p.world_frame = Some(rogs::bundle::WorldFrame {
            name: "nuScenes global frame of boston-seaport".into(),
            offset_m: [off, 0.0, 0.0],
        });
        p
    };
    let a = framed(&part(&m, 0..n, 0.0), 500.0);
    let b = framed(&part(&m, 0..n, -1000.0), 1500.0);
    let merged = Bundle::merge(vec![bundle(&a, &files), bundle(&b, &files)], &names)
        .expect("one frame, two offsets");
    let fr = &merged.manifest.frames;
    for k in 0..n {
        assert!((fr[n + k].vehicle_to_world[0][3] - fr[k].vehicle_to_world[0][3]).abs() < 1e-9);
    }
    assert_eq!(merged.manifest.world_frame, a.world_frame);
    // Other frames are refused by name.
    let mut c = framed(&part(&m, 0..n, 0.0), 0.0);
    if let Some(f) = &mut c.world_frame {
        f.name = "nuScenes global frame of singapore-onenorth".into();
    }
    let e = match Bundle::merge(vec![bundle(&a, &files), bundle(&c, &files)], &names) {
        Ok(_) => panic!("merged two world frames"),
        Err(e) => e.to_string(),
    };
    assert!(
        e.contains("b.zip: world_frame") && e.contains("singapore"),
        "{e}"
    );
}

/// A merged map's geometry: the first drive's truth grid grown to every drive's
/// corridor, on the same pixel grid, and left alone when it already covers it.
#[test]
fn the_truth_grid_grows_to_cover_every_drive() {
    use rogs::bev::BevGeometry;
    let g = BevGeometry {
        origin: [0.0, 10.0],
        resolution: 0.5,
        width: 20,
        height: 20,
    };
    let inner = BevGeometry::around([[2.0, 2.0], [8.0, 8.0]].into_iter(), 0.5, 0.5);
    assert_eq!(g.covering(&inner), g);
    let other = BevGeometry::around([[-1.2, 3.0], [12.3, 11.0]].into_iter(), 0.5, 0.0);
    let c = g.covering(&other);
    assert_eq!(c.resolution, 0.5);
    // The same grid: the origin moved by whole pixels.
    for (a, b) in c.origin.iter().zip(g.origin) {
        let px = (a - b) / 0.5;
        assert!((px - px.round()).abs() < 1e-9, "{:?}", c.origin);
    }
    let edges = |g: &BevGeometry| {
        let r = g.resolution;
        [
            g.origin[0],
            g.origin[0] + g.width as f64 * r,
            g.origin[1] - g.height as f64 * r,
            g.origin[1],
        ]
    };
    let (e, o) = (edges(&c), edges(&other));
    assert!(
        e[0] <= o[0] && e[1] >= o[1] && e[2] <= o[2] && e[3] >= o[3],
        "{e:?} covers {o:?}"
    );
    assert!(
        e[0] > o[0] - 0.5 && e[1] < o[1] + 0.5,
        "grown by less than a pixel too many"
    );
}

#[test]
fn a_camera_too_large_for_the_gpu_is_refused_with_the_size_that_fits() {
    // Once a raw wgpu buffer error mid-step: a camera whose per-pixel buffers exceed
    // the adapter's binding limit is refused by name, before any work, with a size
    // that fits. Made just over this adapter's limit, so the test follows the device.
    let c = ctx();
    let (mut m, mut files) = rogs::bundle::example::tiny();
    let per_px = rogs::render::gpu::view_bytes_per_pixel(m.semantic_classes.len());
    let limit = c.limits.max_storage_buffer_binding_size;
    let w = 4096u32;
    let h = (limit / per_px / w as u64 + 8) as u32;
    assert!(
        h <= 8192,
        "this adapter's limit needs a camera past the image limit"
    );
    let scale = w as f64 / m.cameras[0].width as f64;
    let cam = &mut m.cameras[0];
    (cam.fx, cam.fy, cam.cx, cam.cy) = (
        cam.fx * scale,
        cam.fy * scale,
        w as f64 / 2.0,
        h as f64 / 2.0,
    );
    (cam.width, cam.height) = (w, h);
    for (p, bytes) in &mut files {
        if p.starts_with("images/") {
            *bytes = rogs::bundle::example::png_rgb(&image::RgbImage::new(w, h));
        } else if p.starts_with("labels/") {
            *bytes = rogs::bundle::example::png_gray(&image::GrayImage::new(w, h));
        }
    }
    let mut b = bundle(&m, &files);
    let e = match pollster::block_on(TiledRun::new(&mut b, cfg(), None, c)) {
        Err(e) => e,
        Ok(_) => panic!("a {w}×{h} camera must be refused on a {limit}-byte binding"),
    };
    assert!(e.is_input(), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("camera front's images are {w}×{h} px")) && msg.contains("downscale"),
        "{msg}"
    );
}

#[test]
fn a_map_too_large_for_memory_is_refused_with_advice_before_it_is_allocated() {
    // A drive 100 km long at 5 cm: 2 million pixels by the corridor's width, tens
    // of GB of layers. Refused by name before anything map-sized is allocated.
    let (mut m, files) = rogs::bundle::example::tiny();
    let last = m.frames.len() - 1;
    m.frames[last].vehicle_to_world[0][3] = 1e5;
    m.ground_truth = None;
    let mut b = bundle(&m, &files);
    let mut c = ReconstructConfig::default();
    c.prepare.grid.resolution = 0.05;
    // As the CLI and the page choose: tiled, since the corridor is large.
    let tiling = rogs::tiles::choose(&b.manifest, &c, None);
    assert!(tiling.is_some());
    let e = match pollster::block_on(TiledRun::new(&mut b, c, tiling, ctx())) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a 100 km map at 5 cm must be refused"),
    };
    assert!(
        e.contains("MiB of layers") && e.contains("coarser resolution"),
        "{e}"
    );
}

/// Every raster file written block by block (`streamed`) shows what the whole map's
/// file of the same name shows: PNGs decoded pixel for pixel, the elevation arrays
/// byte for byte, the tiled GeoTIFFs as GDAL reads them.
fn same_raster_files(streamed: &[(String, std::io::Cursor<Vec<u8>>)], whole: &[(String, Vec<u8>)]) {
    let dir = std::env::temp_dir().join(format!("rogs-layers-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let names: Vec<&str> = streamed.iter().map(|f| f.0.as_str()).collect();
    for n in [
        "rgb.png",
        "semantic.png",
        "elevation.png",
        "error.png",
        "elevation.f32",
        "elevation.tif",
        "rgb.tif",
        "semantic.tif",
    ] {
        assert!(names.contains(&n), "{n} is not among {names:?}");
    }
    for (name, c) in streamed {
        let a = c.get_ref();
        let b = &whole
            .iter()
            .find(|f| &f.0 == name)
            .unwrap_or_else(|| panic!("{name} is not among the whole map's files"))
            .1;
        if name.ends_with(".png") {
            let (x, y) = (
                image::load_from_memory(a).expect("png"),
                image::load_from_memory(b).expect("png"),
            );
            assert_eq!((x.width(), x.height()), (y.width(), y.height()), "{name}");
            assert!(x.as_bytes() == y.as_bytes(), "{name}: pixels differ");
        } else if name.ends_with(".tif") {
            std::fs::write(dir.join(format!("s-{name}")), a).expect("write");
            std::fs::write(dir.join(format!("w-{name}")), b).expect("write");
            let (x, y) = (
                common::gdal_pixels(&dir, &format!("s-{name}")),
                common::gdal_pixels(&dir, &format!("w-{name}")),
            );
            assert!(!x.is_empty() && x == y, "{name}: GDAL reads other pixels");
        } else {
            assert!(a == b, "{name}: bytes differ");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_map_too_large_for_whole_layers_streams_block_by_block_into_the_same_map_file() {
    // The IPM baseline (no training) of `demo` at the truth's 2 cm in 12 m tiles:
    // a map of 8 × 3 blocks (1867 × 718 px, 107.2 MB of whole layers, 101.9 MB of
    // blocks: the corridor fills this straight drive's box), with a budget between.
    let mut c = SynthConfig::preset(Preset::Demo, 1);
    c.rays_per_axis = 1;
    c.truth_resolution = 0.02;
    let out = generate(&c, &|_, _, _| {}).expect("synth");
    let mut b = bundle(&out.manifest, &out.files);
    let mut cfg = cfg();
    cfg.baseline_ipm = true;
    cfg.map.budget_bytes = Some(104_000_000);
    let t = TileConfig {
        size_m: 12.0,
        overlap_m: 2.0,
        origin_m: None,
    };
    // Without streaming (the page), the same map is refused before any work.
    let e = match pollster::block_on(TiledRun::new(&mut b, cfg.clone(), Some(t), ctx())) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a map over the budget must be refused where it cannot stream"),
    };
    assert!(e.contains("MiB of layers") && e.contains("--tile-m"), "{e}");
    cfg.map.stream = true;
    let mut b = bundle(&out.manifest, &out.files);
    let mut r = pollster::block_on(TiledRun::new(&mut b, cfg, Some(t), ctx())).expect("run");
    assert!(r.streamed, "a tiled map over the budget streams");
    while pollster::block_on(r.step(&b)).expect("step").is_some() {}
    let s = pollster::block_on(r.finish_streamed(
        &b,
        "demo",
        std::io::Cursor::new(Vec::new()),
        &mut |_, _| {},
    ))
    .expect("streamed");
    let held = s.report["map_layers"]["held_bytes"].as_u64().unwrap_or(0);
    let whole = s.report["map_layers"]["whole_layers_bytes"]
        .as_u64()
        .unwrap_or(0);
    assert!(
        held > 0 && held <= 104_000_000 && whole > 104_000_000,
        "{}",
        s.report["map_layers"]
    );
    // Its raster files, block by block.
    let names = rogs::export::layers::names(&r.geometry, &b.manifest, true);
    let mut sinks: Vec<_> = names
        .iter()
        .map(|n| (n.to_string(), std::io::Cursor::new(Vec::new())))
        .collect();
    let mut blocks = 0;
    r.write_layers(&b, s.range, &mut sinks, &mut |_, t| blocks = t)
        .expect("layers");
    assert!(blocks >= 24, "{blocks} blocks");
    // The same run finished whole (the budget only decides which way the CLI goes).
    let o = pollster::block_on(r.finish(&b, &mut |_, _| {})).expect("finish");
    let whole = rogs::export::files(&o, &b.manifest).expect("files");
    same_raster_files(&sinks, &whole);
    let dense = rogs::export::map_file::write(&o, &b, b"{}").expect("map");
    let (a, d) = (
        common::zip_entries(s.map.get_ref()),
        common::zip_entries(&dense),
    );
    let tiles = |e: &[(String, Vec<u8>)]| -> Vec<(String, Vec<u8>)> {
        let mut t: Vec<_> = e
            .iter()
            .filter(|(n, _)| n.starts_with("layers/") || n.starts_with("values/"))
            .cloned()
            .collect();
        t.sort();
        t
    };
    let (ta, td) = (tiles(&a), tiles(&d));
    assert!(ta.len() > 40, "{} tiles", ta.len());
    assert_eq!(
        ta.iter().map(|t| &t.0).collect::<Vec<_>>(),
        td.iter().map(|t| &t.0).collect::<Vec<_>>(),
        "the same tiles"
    );
    for ((name, x), (_, y)) in ta.iter().zip(&td) {
        assert!(
            x == y,
            "{name} differs between the streamed and the whole map"
        );
    }
    let index = |e: &[(String, Vec<u8>)]| -> serde_json::Value {
        let j = &e.iter().find(|f| f.0 == "map.json").expect("map.json").1;
        serde_json::from_slice(j).expect("json")
    };
    let (ia, id) = (index(&a), index(&d));
    for k in [
        "present",
        "stats",
        "elevation_range",
        "layers",
        "values",
        "width",
    ] {
        assert_eq!(ia[k], id[k], "map.json {k}");
    }
    // Metrics summed over the blocks are the whole map's.
    let (ms, mw) = (
        s.outcome.metrics.clone().expect("streamed metrics"),
        o.metrics.clone().expect("metrics"),
    );
    assert!(
        (ms.psnr_db.unwrap() - mw.psnr_db.unwrap()).abs() < 1e-9,
        "{ms:?} {mw:?}"
    );
    assert!(
        (ms.miou.unwrap() - mw.miou.unwrap()).abs() < 1e-12,
        "{ms:?} {mw:?}"
    );
    assert_eq!(ms.elevation_rmse_m, mw.elevation_rmse_m);
    let (bs, bw) = (
        s.report["seams"]["border_pairs"].as_u64().unwrap_or(0),
        seams(&o.raster, &r.tiling.expect("tiled")).border_pairs as u64,
    );
    assert!(bs > 0 && bs <= bw, "seam pairs streamed {bs}, whole {bw}");
}

#[test]
fn a_failed_tile_keeps_the_finished_ones_and_the_run_resumes_from_checkpoints() {
    let (m, files) = demo();
    let t = TileConfig {
        size_m: 12.0,
        overlap_m: 4.0,
        origin_m: None,
    };
    // Run A: tile 2 fails (a lost device, injected); tiles 0 and 1 are kept and
    // checkpointed. Then A retries the failed tile and finishes: the reference map.
    let mut b = bundle(&m, &files);
    let mut a = pollster::block_on(TiledRun::new(&mut b, cfg(), Some(t), ctx())).expect("run");
    a.checkpoints = true;
    a.fault_tile = Some(2);
    let mut saved = Vec::new();
    let err = loop {
        match pollster::block_on(a.step(&b)) {
            Ok(Some(_)) => saved.extend(std::iter::from_fn(|| a.take_checkpoint())),
            Ok(None) => panic!("the injected fault never came"),
            // The step that fails may have finished the tile before (as the CLI
            // does, take its checkpoint on errors too).
            Err(e) => {
                saved.extend(std::iter::from_fn(|| a.take_checkpoint()));
                break e;
            }
        }
    };
    let name = a.tiles[2].name();
    assert!(err.to_string().contains(&format!("tile {name}")), "{err}");
    assert!(
        !err.is_input(),
        "a lost device is the machine's failure: {err}"
    );
    assert_eq!(a.tiles_done(), 2, "{:?}", a.reports);
    assert_eq!(saved.len(), 2, "one checkpoint per finished tile");
    assert!(saved[0].0.ends_with(".tile"));
    // Nothing more runs until the failure is cleared.
    assert!(pollster::block_on(a.step(&b)).expect("stopped").is_none());
    assert!(a.device_lost(), "the fault destroyed the device");
    assert!(pollster::block_on(a.retry()).expect("a new device"));
    assert!(!a.device_lost());
    while pollster::block_on(a.step(&b)).expect("step").is_some() {}
    let whole = pollster::block_on(a.finish(&b, &mut |_, _| {})).expect("finish");
    assert_eq!(a.tiles_done(), a.tiles.len());

    // Run B: a new process restores the two checkpoints and trains the rest only.
    // As the CLI does, it writes its checkpoints into a directory and leaves each
    // tile's surfels there (spilled) instead of holding them.
    let dir = std::env::temp_dir().join(format!("rogs-spill-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut b2 = bundle(&m, &files);
    let mut r = pollster::block_on(TiledRun::new(&mut b2, cfg(), Some(t), ctx())).expect("run");
    r.checkpoints = true;
    r.spill_models(dir.clone());
    let planned = r.total_steps();
    let mut order = Vec::new();
    for (name, bytes) in &saved {
        std::fs::write(dir.join(name), bytes).expect("write checkpoint");
        r.restore_file(bytes, Some(&dir.join(name)))
            .expect("restore");
        order.push(name.clone());
    }
    assert!(
        r.total_steps() < planned,
        "restored tiles are not planned again"
    );
    // The same checkpoint twice is refused.
    let twice = r.restore(&saved[0].1).expect_err("restored twice");
    assert!(twice.to_string().contains("twice"), "{twice}");
    let mut steps = 0;
    let keep = |r: &mut TiledRun, order: &mut Vec<String>| {
        while let Some((name, bytes)) = r.take_checkpoint() {
            std::fs::write(dir.join(&name), bytes).expect("write checkpoint");
            order.push(name);
        }
    };
    while pollster::block_on(r.step(&b2)).expect("step").is_some() {
        keep(&mut r, &mut order);
        steps += 1;
    }
    keep(&mut r, &mut order);
    assert_eq!(steps, r.steps_done());
    let resumed = pollster::block_on(r.finish(&b2, &mut |_, _| {})).expect("finish");
    let restored: Vec<_> = r
        .reports
        .iter()
        .filter(|t| t.restored)
        .map(|t| &t.name)
        .collect();
    assert_eq!(restored.len(), 2, "{:?}", r.reports);
    let trained_a: usize = a.reports.iter().map(|t| t.steps).sum();
    let trained_b: usize = r
        .reports
        .iter()
        .filter(|t| !t.restored)
        .map(|t| t.steps)
        .sum();
    assert!(
        trained_b < trained_a,
        "B trained {trained_b} steps, A {trained_a}"
    );
    let (spilled, origin) = r.model();
    assert_eq!(spilled.len(), whole.params.len());
    assert_eq!(
        spilled.held().len(),
        0,
        "B holds no finished tile's surfels"
    );
    assert_eq!(spilled.spilled_tiles(), order.len());

    // B's model files, each tile read back from its checkpoint, are the files of a
    // run that holds the same tiles' surfels (C restores B's checkpoints in B's order).
    let mut streamed = rogs::export::ModelWriter::start(
        |_| Ok(Vec::new()),
        spilled.len(),
        origin,
        &b2.manifest,
        Default::default(),
    )
    .expect("start");
    spilled.write(&mut streamed).expect("read back");
    let streamed = streamed.finish().expect("finish");
    let mut b4 = bundle(&m, &files);
    let mut c = pollster::block_on(TiledRun::new(&mut b4, cfg(), Some(t), ctx())).expect("run");
    for name in &order {
        c.restore(&std::fs::read(dir.join(name)).expect("read"))
            .expect("restore");
    }
    let (held, origin_c) = c.model();
    assert_eq!(held.held().len(), whole.params.len());
    // And the seen centres the elevation metrics read.
    let centres = spilled.centres().expect("read back");
    assert!(!centres.is_empty());
    assert_eq!(centres, held.centres().expect("held"));
    let whole_files =
        rogs::export::model_files(held.held(), origin_c, &b4.manifest, Default::default());
    assert_eq!(streamed.len(), whole_files.len());
    for ((na, a), (nb, b)) in streamed.iter().zip(&whole_files) {
        assert_eq!(na, nb);
        assert!(
            a == b,
            "{na}: the spilled model's file differs from the held one's"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);

    // The resumed map is the uninterrupted one (tiles are independent jobs).
    let (cov, dz, psnr, cls) = agreement(&whole, &resumed);
    eprintln!("resumed vs retried: coverage {cov:.5}, |dz| {dz:.5} m, PSNR {psnr:.2} dB, classes {cls:.5}");
    assert!(cov > 0.999, "coverage IoU {cov}");
    assert!(dz < 0.001, "mean elevation difference {dz} m");
    assert!(psnr > 45.0, "colour PSNR {psnr} dB");
    assert!(cls > 0.995, "class agreement {cls}");
    let (mw, mr) = (whole.metrics.unwrap(), resumed.metrics.unwrap());
    assert!((mw.psnr_db.unwrap() - mr.psnr_db.unwrap()).abs() < 0.05);

    // A checkpoint of other settings, a damaged one, and one of an untiled run.
    let mut other = cfg();
    other.train.seed = 7;
    let mut b3 = bundle(&m, &files);
    let mut o = pollster::block_on(TiledRun::new(&mut b3, other, Some(t), ctx())).expect("run");
    let e = o.restore(&saved[0].1).expect_err("other settings");
    assert!(
        e.is_input() && e.to_string().contains("other bundles or settings"),
        "{e}"
    );
    let mut cut = saved[1].1.clone();
    cut.truncate(cut.len() / 2);
    let e = o.restore(&cut).expect_err("damaged");
    assert!(e.to_string().contains("not a tile checkpoint"), "{e}");
    let mut swapped = rogs::tiles::checkpoint::decode(&saved[1].1)
        .expect("decode")
        .0;
    swapped.index = 0;
    let forged = rogs::tiles::checkpoint::encode(&swapped, o.fingerprint).expect("encode");
    let e = o.restore(&forged).expect_err("wrong tile");
    assert!(e.to_string().contains("names tile"), "{e}");
    assert_eq!(o.tiles_done(), 0, "a refused checkpoint changes nothing");
}

/// A forward camera sees the road from metres ahead, so on a drive that comes back
/// along its own road the frames nearest a place (both passes', beside it) do not
/// see it: the map must still cover the road from end to end, not only the ends.
#[test]
fn a_drive_out_and_back_is_mapped_along_its_whole_length() {
    let mut c = SynthConfig::preset(Preset::Long, 1);
    c.set_length_m(80.0);
    (c.width, c.height, c.rays_per_axis) = (160, 48, 1);
    c.truth_resolution = 0.2;
    let out = generate(&c, &|_, _, _| {}).expect("synth");
    let mut b = bundle(&out.manifest, &out.files);
    let mut cfg = ReconstructConfig::default();
    cfg.prepare.grid.resolution = 0.2;
    cfg.baseline_ipm = true;
    let t = TileConfig {
        size_m: 24.0,
        overlap_m: 2.0,
        origin_m: None,
    };
    let mut r = pollster::block_on(TiledRun::new(&mut b, cfg, Some(t), ctx())).expect("run");
    while pollster::block_on(r.step(&b)).expect("step").is_some() {}
    let o = pollster::block_on(r.finish(&b, &mut |_, _| {})).expect("finish");
    let m = o.metrics.as_ref().expect("metrics against the truth");
    let coverage = m.coverage.expect("coverage");
    // Mapped along its length: every 5 m of the drive's x extent holds map pixels.
    let g = &o.raster;
    let stretch = (5.0 / g.resolution) as u32;
    let empty: Vec<u32> = (0..g.width / stretch)
        .filter(|&s| {
            !(s * stretch..(s + 1) * stretch)
                .any(|col| (0..g.height).any(|row| g.is_valid(col, row)))
        })
        .collect();
    println!("coverage {coverage:.3}, empty 5 m stretches {empty:?}");
    assert!(coverage >= 0.9, "the map covers {coverage:.3} of the truth");
    assert!(empty.is_empty(), "unmapped 5 m stretches: {empty:?}");
}
