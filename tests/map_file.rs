//! The map file (`map.rogsmap`, docs/MAP.md): written from a finished run, read back
//! tile by tile against the layers it came from, its pyramid against 2 × 2 means,
//! and damaged copies refused with the entry or field named.
#![cfg(not(target_arch = "wasm32"))]

mod common;

use rogs::bundle::{Bundle, Limits, ZipBundleWriter};
use rogs::export::map_file::{validate, write, MapIndex, INDEX, TILE};
use rogs::gpu::GpuContext;
use rogs::reconstruct::{Outcome, ReconstructConfig};
use rogs::synth::{generate, Preset, SynthConfig};
use rogs::tiles::TiledRun;

/// The IPM baseline map of the demo scene at 2 cm (a map of several tiles and levels).
fn outcome() -> (Bundle, Outcome) {
    let mut c = SynthConfig::preset(Preset::Demo, 1);
    c.rays_per_axis = 1;
    c.truth_resolution = 0.02;
    let out = generate(&c, &|_, _, _| {}).expect("synth");
    let zip = rogs::bundle::write_zip(&out.manifest, &out.files).expect("zip");
    let mut b = Bundle::from_zip_bytes(zip, Limits::default()).expect("bundle");
    let mut cfg = ReconstructConfig::default();
    cfg.prepare.grid.half_width = 4.0;
    cfg.prepare.grid.resolution = 0.1;
    cfg.baseline_ipm = true;
    let ctx =
        GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"));
    let mut r = pollster::block_on(TiledRun::new(&mut b, cfg, None, ctx)).expect("run");
    while pollster::block_on(r.step(&b)).expect("step").is_some() {}
    let o = pollster::block_on(r.finish(&b, &mut |_, _| {})).expect("finish");
    (b, o)
}

fn entries(zip: &[u8]) -> Vec<(String, Vec<u8>)> {
    common::zip_entries(zip)
}

fn rezip(files: &[(String, Vec<u8>)]) -> Vec<u8> {
    let mut z = ZipBundleWriter::new(std::io::Cursor::new(Vec::new()));
    for (n, b) in files {
        z.add(n, b).expect("add");
    }
    z.finish_raw().expect("finish").into_inner()
}

#[test]
fn a_map_file_holds_every_layer_as_a_tile_pyramid_and_damage_is_named() {
    let (b, o) = outcome();
    let g = o.geometry;
    assert!(g.width > TILE, "the map should span several tiles: {g:?}");
    let map = write(&o, &b, b"{}").expect("write");
    let s = validate(map.clone(), &Limits::default()).expect("valid map");
    let i = &s.index;
    assert_eq!((i.width, i.height, i.origin), (g.width, g.height, g.origin));
    assert!(i.levels >= 2 && i.tiles(i.levels - 1) == (1, 1));
    assert!(
        i.layers.iter().any(|l| l == "error"),
        "truth gives an error layer"
    );
    assert_eq!(i.trajectory.len(), b.manifest.frames.len());
    // Thumbnails of the input images: every frame of this short drive, 320 px wide.
    assert_eq!(i.thumbnails.len(), b.manifest.frames.len());
    let files = entries(&map);
    let get = |p: &str| {
        &files
            .iter()
            .find(|f| f.0 == p)
            .unwrap_or_else(|| panic!("{p}"))
            .1
    };
    let thumb = image::load_from_memory(get(&MapIndex::thumbnail_path(3))).expect("jpeg");
    assert_eq!(thumb.width(), rogs::export::map_file::THUMB_WIDTH);
    // Level 0 reassembled from its tiles is the layer itself.
    let full = rogs::export::layer_rgba(&o, &b.manifest, "rgb").expect("rgb");
    let (tx, ty) = i.tiles(0);
    let mut absent = 0;
    for r in 0..ty {
        for c in 0..tx {
            if !i.is_present(0, c, r) {
                // A tile left out is one where nothing is mapped.
                let (tw, th) = i.tile_size(0, c, r);
                for y in r * TILE..r * TILE + th {
                    for x in c * TILE..c * TILE + tw {
                        assert_eq!(full[((y * g.width + x) * 4 + 3) as usize], 0);
                    }
                }
                assert!(!files
                    .iter()
                    .any(|f| f.0 == MapIndex::layer_path("rgb", 0, c, r)));
                absent += 1;
                continue;
            }
            let img = image::load_from_memory(get(&MapIndex::layer_path("rgb", 0, c, r)))
                .expect("png")
                .to_rgba8();
            for (x, y, p) in img.enumerate_pixels() {
                let (gx, gy) = (c * TILE + x, r * TILE + y);
                let k = ((gy * g.width + gx) * 4) as usize;
                assert_eq!(&p.0[..], &full[k..k + 4], "rgb at ({gx}, {gy})");
            }
        }
    }
    // Elevation values: level 0 as exported; level 1 the mean of each 2 × 2 block.
    let z = rogs::export::elevation(&o);
    let f32s = |p: String| -> Vec<f32> {
        get(&p)
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    };
    eprintln!("{absent} of {} level-0 tiles left out as empty", tx * ty);
    // The level-0 tile with even indices that holds the most of the map.
    let (c0, r0) = (0..ty)
        .step_by(2)
        .flat_map(|r| (0..tx).step_by(2).map(move |c| (c, r)))
        .filter(|&(c, r)| i.is_present(0, c, r))
        .max_by_key(|&(c, r)| {
            f32s(MapIndex::values_path("elevation", 0, c, r))
                .iter()
                .filter(|v| v.is_finite())
                .count()
        })
        .expect("a tile");
    let t0 = f32s(MapIndex::values_path("elevation", 0, c0, r0));
    let t1 = f32s(MapIndex::values_path("elevation", 1, c0 / 2, r0 / 2));
    let (w0, h0) = i.tile_size(0, c0, r0);
    let (w1, _) = i.tile_size(1, c0 / 2, r0 / 2);
    let mut checked = 0;
    for y in 0..h0 / 2 {
        for x in 0..w0 / 2 {
            let q: Vec<f32> = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|(dx, dy)| t0[((2 * y + dy) * w0 + 2 * x + dx) as usize])
                .filter(|v| v.is_finite())
                .collect();
            let v = t1[(y * w1 + x) as usize];
            if q.is_empty() {
                assert!(v.is_nan());
            } else {
                let mean = q.iter().sum::<f32>() / q.len() as f32;
                assert!((v - mean).abs() < 1e-4, "level 1 ({x}, {y}): {v} vs {mean}");
                checked += 1;
            }
        }
    }
    assert!(checked > 100);
    for (y, row) in t0.chunks(w0 as usize).enumerate() {
        for (x, v) in row.iter().enumerate() {
            let (gx, gy) = (c0 * TILE + x as u32, r0 * TILE + y as u32);
            let e = z[(gy * g.width + gx) as usize];
            assert!(v == &e || (v.is_nan() && e.is_nan()));
        }
    }

    // Damage, each named.
    let problems = |files: Vec<(String, Vec<u8>)>| -> String {
        match validate(rezip(&files), &Limits::default()) {
            Ok(_) => panic!("a damaged map passed"),
            Err(e) => e.to_string(),
        }
    };
    let missing = MapIndex::layer_path("semantic", 1, c0 / 2, r0 / 2);
    let e = problems(files.iter().filter(|f| f.0 != missing).cloned().collect());
    assert!(
        e.contains(&missing) && e.contains("not in the bundle"),
        "{e}"
    );
    let bad = MapIndex::layer_path("rgb", 0, c0, r0);
    let e = problems(
        files
            .iter()
            .map(|f| {
                if f.0 == bad {
                    (f.0.clone(), f.1[..40].to_vec())
                } else {
                    f.clone()
                }
            })
            .collect(),
    );
    assert!(e.contains(&bad) && e.contains("decode"), "{e}");
    let short = MapIndex::values_path("elevation", 0, c0, r0);
    let e = problems(
        files
            .iter()
            .map(|f| {
                if f.0 == short {
                    (f.0.clone(), vec![0; 12])
                } else {
                    f.clone()
                }
            })
            .collect(),
    );
    assert!(e.contains(&short) && e.contains("12 bytes"), "{e}");
    let mut idx: serde_json::Value = serde_json::from_slice(get(INDEX)).expect("json");
    idx["format"] = "rogs-bundle".into();
    let e = problems(
        files
            .iter()
            .map(|f| {
                if f.0 == INDEX {
                    (f.0.clone(), serde_json::to_vec(&idx).unwrap())
                } else {
                    f.clone()
                }
            })
            .collect(),
    );
    assert!(e.contains("map.json: format"), "{e}");
    idx["format"] = "rogs-map".into();
    idx["resolution"] = "fine".into();
    let e = problems(
        files
            .iter()
            .map(|f| {
                if f.0 == INDEX {
                    (f.0.clone(), serde_json::to_vec(&idx).unwrap())
                } else {
                    f.clone()
                }
            })
            .collect(),
    );
    assert!(e.contains("map.json: resolution"), "{e}");
    let e = validate(b"not a zip".to_vec(), &Limits::default())
        .expect_err("refused")
        .to_string();
    assert!(e.contains("not a readable zip"), "{e}");

    // `rogs inspect` takes a map file: exit 0, and 2 with the problem for a damaged one.
    let dir = std::env::temp_dir().join(format!("rogs-map-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let ok = dir.join("ok.rogsmap");
    std::fs::write(&ok, &map).expect("write");
    let bad_map = dir.join("bad.rogsmap");
    std::fs::write(
        &bad_map,
        rezip(
            &files
                .iter()
                .filter(|f| f.0 != missing)
                .cloned()
                .collect::<Vec<_>>(),
        ),
    )
    .expect("write");
    let run = |p: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_rogs"))
            .arg("inspect")
            .arg(p)
            .output()
            .expect("rogs")
    };
    let out = run(&ok);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("levels"));
    let out = run(&bad_map);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains(&missing));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The truth written tile by tile (`rogs synth --truth-map`) against the dense truth
/// rasters of the same scene: every level-0 value and colour, the tiles left out
/// exactly where nothing is valid, and the class areas in `stats`.
#[test]
fn the_streamed_truth_map_matches_the_dense_truth_rasters() {
    use rogs::synth::{truth, world_and_poses};
    let cfg = SynthConfig::preset(Preset::Demo, 1);
    let (world, poses) = world_and_poses(&cfg, &|_, _, _| {});
    let dense = truth::rasters(&world, &poses, 6.0, 0.05);
    let map = truth::map_file(&world, &poses, "t", 6.0, 0.05, &mut |_, _| {}).expect("map");
    let s = validate(map.clone(), &Limits::default()).expect("valid");
    let i = &s.index;
    assert_eq!(
        (i.width, i.height, i.origin),
        (dense.width, dense.height, dense.origin)
    );
    let files = entries(&map);
    let get = |p: &str| files.iter().find(|f| f.0 == p).map(|f| f.1.clone());
    let f32s = |b: Vec<u8>| -> Vec<f32> {
        b.chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    };
    let (tx, ty) = i.tiles(0);
    let (mut compared, mut absent) = (0, 0);
    for r in 0..ty {
        for c in 0..tx {
            let (tw, th) = i.tile_size(0, c, r);
            let any_valid = (r * TILE..r * TILE + th)
                .any(|y| (c * TILE..c * TILE + tw).any(|x| dense.valid.get_pixel(x, y).0[0] != 0));
            assert_eq!(i.is_present(0, c, r), any_valid, "tile ({c}, {r})");
            if !any_valid {
                absent += 1;
                continue;
            }
            let z = f32s(get(&MapIndex::values_path("elevation", 0, c, r)).expect("z"));
            let k = f32s(get(&MapIndex::values_path("class", 0, c, r)).expect("class"));
            let rgb =
                image::load_from_memory(&get(&MapIndex::layer_path("rgb", 0, c, r)).expect("rgb"))
                    .expect("png")
                    .to_rgba8();
            for y in 0..th {
                for x in 0..tw {
                    let (gx, gy) = (c * TILE + x, r * TILE + y);
                    let o = (y * tw + x) as usize;
                    if dense.valid.get_pixel(gx, gy).0[0] == 0 {
                        assert!(z[o].is_nan() && k[o].is_nan() && rgb.get_pixel(x, y).0[3] == 0);
                        continue;
                    }
                    assert_eq!(z[o], dense.elevation[(gy * dense.width + gx) as usize]);
                    assert_eq!(k[o], dense.class_ids.get_pixel(gx, gy).0[0] as f32);
                    assert_eq!(
                        &rgb.get_pixel(x, y).0[..3],
                        &dense.rgb.get_pixel(gx, gy).0[..]
                    );
                    compared += 1;
                }
            }
        }
    }
    assert!(compared > 50_000, "{compared} pixels compared");
    eprintln!(
        "{compared} pixels equal; {absent} of {} tiles left out",
        tx * ty
    );
    let stats = i.stats.as_ref().expect("stats");
    let road = stats
        .classes
        .iter()
        .find(|c| c.name == "road")
        .expect("road");
    let road_px = dense
        .class_ids
        .pixels()
        .zip(dense.valid.pixels())
        .filter(|(k, v)| v.0[0] != 0 && k.0[0] == road.id)
        .count();
    assert!((road.area_m2 - road_px as f64 * 0.0025).abs() < 1e-6);
    let valid_px = dense.valid.pixels().filter(|v| v.0[0] != 0).count();
    assert!((stats.mapped_m2 - valid_px as f64 * 0.0025).abs() < 1e-6);
}
