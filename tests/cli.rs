//! The `rogs` binary: inspect prints a summary, or every problem with exit code 3
//! (bad input; 2 is a usage error, 4 a machine that could not do it).
#![cfg(not(target_arch = "wasm32"))]

mod common;

use std::path::PathBuf;
use std::process::Command;

fn rogs(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_rogs"))
        .args(args)
        .output()
        .expect("run rogs")
}

fn temp(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("rogs-cli-{}-{name}", std::process::id()))
}

#[test]
fn inspect_valid_bundle_prints_summary() {
    let out = temp("valid.zip");
    assert!(rogs(&["example", "--out", out.to_str().unwrap()])
        .status
        .success());
    let o = rogs(&["inspect", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("trajectory  2.0 m"), "{text}");
    assert!(text.contains("300 points in 3 sweeps"), "{text}");
    let o = rogs(&["inspect", "--json", out.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(v["frames"], 3);
    std::fs::remove_file(out).ok();
}

#[test]
fn inspect_broken_bundle_lists_problems_with_exit_code_3() {
    let dir = temp("broken");
    assert!(rogs(&["example", "--out", dir.to_str().unwrap()])
        .status
        .success());
    std::fs::remove_file(dir.join("images/front/000002.png")).unwrap();
    std::fs::write(dir.join("lidar/000000.bin"), [0u8; 5]).unwrap();
    let o = rogs(&["inspect", dir.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(3));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("frames[2].views[0].image"), "{err}");
    assert!(err.contains("lidar/000000.bin: 5 bytes"), "{err}");
    let o = rogs(&["inspect", "--json", dir.to_str().unwrap()]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(v["problems"].as_array().map(|a| a.len()), Some(2));
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn help_explains_each_command() {
    let o = rogs(&["--help"]);
    let text = String::from_utf8_lossy(&o.stdout);
    for cmd in ["inspect", "gpu", "example"] {
        assert!(text.contains(cmd), "{text}");
    }
}

#[test]
fn a_bad_lidar_gate_is_refused_with_what_was_expected() {
    for (flag, bad) in ["nan", "-0.3", "0", "wide"]
        .into_iter()
        .flat_map(|b| [("--lidar-gate", b), ("--lidar-band", b)])
    {
        let o = rogs(&[
            "reconstruct",
            "x.zip",
            "--out",
            "x",
            &format!("{flag}={bad}"),
        ]);
        assert_eq!(o.status.code(), Some(2), "{flag} {bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("expected a positive number of metres"),
            "{err}"
        );
    }
}

#[test]
fn a_drive_too_long_for_whole_layers_streams_and_over_its_budget_is_bad_input() {
    // 100 km at 5 cm: 2 million pixels by the corridor's width, 49 GB of whole
    // layers; the views see only its first metres, so the map's blocks are few.
    let (mut m, files) = rogs::bundle::example::tiny();
    let last = m.frames.len() - 1;
    m.frames[last].vehicle_to_world[0][3] = 1e5;
    m.ground_truth = None;
    let zip = temp("far.zip");
    std::fs::write(&zip, rogs::bundle::write_zip(&m, &files).expect("zip")).expect("write");
    let out = temp("far-out");
    let args = |extra: &[&'static str]| -> Vec<String> {
        let mut a = vec![
            "reconstruct".to_string(),
            zip.to_str().unwrap().into(),
            "--out".into(),
            out.to_str().unwrap().into(),
            "--resolution".into(),
            "0.05".into(),
        ];
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let run = |a: &[String]| rogs(&a.iter().map(|s| s.as_str()).collect::<Vec<_>>());
    // Streamed: map.rogsmap holds every layer, no whole-image layer is written.
    let o = run(&args(&[]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("written block by block: map.rogsmap"), "{err}");
    let map = std::fs::read(out.join("map.rogsmap")).expect("map.rogsmap");
    let embedded = embedded_report(&map);
    let summary = rogs::export::map_file::validate(map, &rogs::bundle::Limits::default())
        .unwrap_or_else(|e| panic!("the streamed map is invalid: {e}"));
    eprintln!("{summary:?}");
    // Over 2^28 px: no dense layers, the tiled GeoTIFFs as GDAL reads them.
    assert!(!out.join("rgb.png").exists());
    let info: serde_json::Value =
        serde_json::from_slice(&common::tool(&out, "gdalinfo", &["-json", "elevation.tif"]))
            .expect("gdalinfo json");
    let bev: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bev.json")).expect("bev.json"))
            .expect("json");
    assert_eq!(
        info["size"],
        serde_json::json!([bev["width"], bev["height"]]),
        "{info}"
    );
    assert!(out.join("rgb.tif").exists() && out.join("elevation_legend.png").exists());
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["map_layers"]["streamed"], true, "{report}");
    // report.json's peak is read after the map and its layers were written, the
    // embedded copy's before.
    let peak = |r: &serde_json::Value| r["peak_host_bytes"].as_u64().expect("peak_host_bytes");
    assert!(peak(&report) >= peak(&embedded), "{report} {embedded}");
    // Over a budget its blocks exceed too: bad input, with what they need.
    let o = run(&args(&["--map-memory-mib", "64"]));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(
        err.contains("MiB of layers")
            && err.contains("coarser resolution")
            && err.contains("the map's blocks along the drive need"),
        "{err}"
    );
    std::fs::remove_file(zip).ok();
    std::fs::remove_dir_all(out).ok();
}

#[test]
fn a_run_that_failed_at_a_tile_resumes_with_the_finished_tiles() {
    let (m, files) = rogs::bundle::example::tiny();
    let zip = temp("resume.zip");
    std::fs::write(&zip, rogs::bundle::write_zip(&m, &files).expect("zip")).expect("write");
    let out = temp("resume-out");
    let run = |extra: &[&str]| {
        let mut args = vec![
            "reconstruct",
            zip.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--resolution",
            "0.1",
            "--half-width",
            "3",
            "--tile-m",
            "2",
            "--tile-overlap-m",
            "0.5",
        ];
        args.extend_from_slice(extra);
        rogs(&args)
    };
    let tiles = out.join("tiles");
    let checkpoints = || {
        std::fs::read_dir(&tiles)
            .map(|d| d.filter_map(|e| e.ok()).count())
            .unwrap_or(0)
    };
    // The second tile fails: exit 4, the first tile's checkpoint is on disk and the
    // message says how to go on.
    let o = run(&["--fault-tile", "1"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(4), "{err}");
    assert!(
        err.contains("--resume") && err.contains("device was lost"),
        "{err}"
    );
    let kept = checkpoints();
    assert!(kept >= 1, "no checkpoint in {}: {err}", tiles.display());
    // Other settings: the checkpoint is refused by name, as bad input.
    let o = run(&["--resume", "--seed", "3"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(
        err.contains(".tile") && err.contains("delete the file"),
        "{err}"
    );
    // The same command with --resume restores it, trains the rest, and cleans up.
    let o = run(&["--resume"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(
        err.contains(&format!("resumed: {kept} finished tiles")),
        "{err}"
    );
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("report"))
            .expect("json");
    let restored = report["tiles"]
        .as_array()
        .expect("tiles")
        .iter()
        .filter(|t| t["restored"] == true)
        .count();
    assert_eq!(restored, kept, "{}", report["tiles"]);
    assert!(report["stopped"].is_null(), "{}", report["stopped"]);
    // The finished tiles' surfels were left in their checkpoints, not held, and
    // read back into surfels.ply.
    let s = &report["surfels"];
    assert!(s["model_spilled_tiles"].as_u64() >= Some(2), "{s}");
    let ply = std::fs::read(out.join("surfels.ply")).expect("surfels.ply");
    let head = String::from_utf8_lossy(&ply[..ply.len().min(600)]).to_string();
    let n = s["model_surfels"].as_u64().expect("model_surfels");
    assert!(head.contains(&format!("element vertex {n}\n")), "{head}");
    let body = ply.len() - head.find("end_header\n").expect("header") - "end_header\n".len();
    assert_eq!(body as u64, n * 17 * 4, "every surfel read back");
    assert!(
        !tiles.exists(),
        "checkpoints are removed once the map is written"
    );
    std::fs::remove_file(zip).ok();
    std::fs::remove_dir_all(out).ok();
}

#[test]
fn inspect_decodes_every_image_and_names_a_truncated_one() {
    let (m, mut files) = rogs::bundle::example::tiny();
    let path = "images/front/000002.png";
    let f = files.iter_mut().find(|(p, _)| p == path).expect("image");
    f.1.truncate(f.1.len() / 2);
    let zip = temp("truncated.zip");
    std::fs::write(&zip, rogs::bundle::write_zip(&m, &files).expect("zip")).expect("write");
    let o = rogs(&["inspect", zip.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains(path), "{err}");
    std::fs::remove_file(zip).ok();
}

#[test]
fn the_benchmarks_print_json_with_the_keys_scripts_compare() {
    let (m, files) = rogs::bundle::example::tiny();
    let zip = temp("bench.zip");
    std::fs::write(&zip, rogs::bundle::write_zip(&m, &files).expect("zip")).expect("write");
    let z = zip.to_str().unwrap();
    for args in [
        vec![
            "bench",
            "step",
            z,
            "--steps",
            "1",
            "--resolution",
            "0.1",
            "--half-width",
            "3",
        ],
        vec!["bench", "raster", z, "--runs", "1", "--resolution", "0.1"],
    ] {
        let o = rogs(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{args:?}: {err}");
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON on stdout");
        for k in [
            "seconds_per_step",
            "seconds_per_epoch",
            "kernels_ms",
            "surfels",
            "candidates_per_view",
            "pairs",
        ] {
            assert!(v.get(k).is_some(), "{args:?}: no {k} in {v}");
        }
        assert!(
            v["seconds_per_step"].as_f64().is_some_and(|s| s > 0.0),
            "{v}"
        );
        assert!(v["surfels"].as_u64().is_some_and(|n| n > 0), "{v}");
        assert!(v["pairs"].as_f64().is_some_and(|n| n > 0.0), "{v}");
    }
    std::fs::remove_file(zip).ok();
}

/// `rogs reconstruct` of the tiny example with `extra` settings into a fresh folder:
/// its output, stderr and the folder (removed by the caller).
fn reconstruct_example(name: &str, extra: &[&str]) -> (std::process::Output, String, PathBuf) {
    let bundle = temp(&format!("{name}.zip"));
    let out = temp(&format!("{name}-out"));
    assert!(rogs(&["example", "--out", bundle.to_str().unwrap()])
        .status
        .success());
    let mut args = vec![
        "reconstruct",
        bundle.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = rogs(&args);
    std::fs::remove_file(bundle).ok();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    (o, err, out)
}

/// A corridor far wider than the views see (36 m each side of a 2 m drive, a 25 cm
/// truth map over a finer surfel grid): the map's 256-px chunks of 64 m listed
/// 1.5 M surfels each (138 MiB, over lavapipe's 128 MiB binding) and the run failed
/// at the end (exit 4). Chunks now shrink until they fit, and list only the surfels
/// whose own footprint reaches them.
#[test]
fn a_corridor_wider_than_the_views_see_maps_in_chunks_that_fit() {
    let (o, err, out) = reconstruct_example("wide", &["--half-width", "36", "--epochs", "1"]);
    assert_eq!(o.status.code(), Some(0), "{err}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("report"))
            .expect("json");
    assert!(
        report["metrics"]["psnr_db"]
            .as_f64()
            .is_some_and(|p| p > 15.0),
        "{}",
        report["metrics"]
    );
    std::fs::remove_dir_all(out).ok();
}

/// A tile whose model cannot fit the adapter is refused before any tile trains (it
/// was found only when that tile came up), naming the tile and advising smaller tiles.
#[test]
fn a_tile_too_large_for_the_gpu_is_refused_before_any_work() {
    // 20 m each side at 5 mm: about 17 M surfels in each tile the 2 m drive touches,
    // 16 bytes each in one binding, over lavapipe's 128 MiB.
    let (o, err, out) = reconstruct_example(
        "bigtile",
        &[
            "--tile-m",
            "100",
            "--half-width",
            "20",
            "--resolution",
            "0.005",
        ],
    );
    assert_eq!(o.status.code(), Some(4), "{err}");
    assert!(
        err.contains("estimated before any work") && err.contains("--tile-m 50"),
        "{err}"
    );
    assert!(!err.contains("step "), "no step ran: {err}");
    std::fs::remove_dir_all(out).ok();
}

/// The report.json that a map.rogsmap embeds.
fn embedded_report(map: &[u8]) -> serde_json::Value {
    use rogs::bundle::{Source, ZipSource};
    let limits = rogs::bundle::Limits::default();
    let zip = ZipSource::new(map.to_vec(), &limits).expect("map.rogsmap is a zip");
    let bytes = zip
        .read("report.json", &limits)
        .expect("report.json in the map");
    serde_json::from_slice(&bytes).expect("json")
}
