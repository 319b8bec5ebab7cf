//! Tile jobs through the `rogs` binary: `rogs plan` writes a tiled reconstruction as
//! independent jobs, each runs in its own process (`rogs reconstruct --plan --tile`),
//! and `rogs merge` stitches them into the map the single-process tiled run writes
//! (the same within lavapipe's float-atomic jitter: docs/DISTRIBUTED.md). A finished job is not run again, a damaged checkpoint is trained
//! again, and a missing tile, a tile not in the plan or a bundle changed since the
//! plan are refused by name as bad input (exit code 3).
#![cfg(not(target_arch = "wasm32"))]

use std::path::{Path, PathBuf};
use std::process::Command;

fn rogs(args: &[&str]) -> (Option<i32>, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_rogs"))
        .args(args)
        .output()
        .expect("run rogs");
    (o.status.code(), String::from_utf8_lossy(&o.stderr).into())
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("rogs-jobs-{}-{name}", std::process::id()))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

const SETTINGS: [&str; 8] = [
    "--resolution",
    "0.1",
    "--half-width",
    "3",
    "--tile-m",
    "2",
    "--tile-overlap-m",
    "0.5",
];

/// The maps of two runs of the same tiles agree within this (metres): the GPU's
/// float atomics add in the order its threads come, so two single-process runs
/// already differ in the last bits (docs/DISTRIBUTED.md: 3e-5 m on `demo`).
const ELEVATION_TOL_M: f32 = 1e-3;

fn floats(p: &Path) -> Vec<f32> {
    std::fs::read(p)
        .expect("elevation.f32")
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// The merged map is the single-process one: the same cells, elevations within
/// the tolerance, colours and classes within one level, the same surfels.
fn assert_same_map(single: &Path, merged: &Path) {
    let (a, b) = (
        floats(&single.join("elevation.f32")),
        floats(&merged.join("elevation.f32")),
    );
    assert_eq!(a.len(), b.len());
    for (i, (u, v)) in a.iter().zip(&b).enumerate() {
        assert_eq!(u.is_nan(), v.is_nan(), "coverage differs at cell {i}");
        assert!(
            u.is_nan() || (u - v).abs() <= ELEVATION_TOL_M,
            "cell {i}: {u} vs {v}"
        );
    }
    for f in ["rgb.png", "semantic_ids.png"] {
        let x = image::open(single.join(f)).expect(f).to_rgba8();
        let y = image::open(merged.join(f)).expect(f).to_rgba8();
        assert_eq!(x.dimensions(), y.dimensions(), "{f}");
        let worst = x.iter().zip(y.iter()).map(|(p, q)| p.abs_diff(*q)).max();
        assert!(worst <= Some(1), "{f}: differs by {worst:?} levels");
    }
    let size = |d: &Path| std::fs::metadata(d.join("surfels.ply")).expect("ply").len();
    assert_eq!(size(single), size(merged), "the same surfels");
}

#[test]
fn tile_jobs_run_apart_merge_into_the_single_process_map_and_bad_jobs_are_named() {
    let (m, files) = rogs::bundle::example::tiny();
    let zip = temp("tiny.zip");
    std::fs::write(&zip, rogs::bundle::write_zip(&m, &files).expect("zip")).expect("write");
    let (plan, tiles, merged, single) =
        (temp("plan"), temp("tiles"), temp("merged"), temp("single"));

    let mut args = vec!["plan", s(&zip), "--out", s(&plan)];
    args.extend(SETTINGS);
    let (code, err) = rogs(&args);
    assert_eq!(code, Some(0), "{err}");
    let p: serde_json::Value =
        serde_json::from_slice(&std::fs::read(plan.join("plan.json")).expect("plan.json"))
            .expect("json");
    let names: Vec<String> = p["jobs"]
        .as_array()
        .expect("jobs")
        .iter()
        .map(|j| j["tile"].as_str().expect("tile").to_string())
        .collect();
    assert!(names.len() >= 3, "a plan of several tiles: {names:?}");
    for n in &names {
        let job: serde_json::Value = serde_json::from_slice(
            &std::fs::read(plan.join("jobs").join(format!("{n}.json"))).expect("job file"),
        )
        .expect("json");
        assert_eq!(job["tile"], n.as_str());
        assert_eq!(job["fingerprint"], p["fingerprint"]);
        assert!(job["command"].as_array().is_some_and(|c| c.len() == 8));
    }

    // A merge before the jobs ran names the missing tiles.
    let (code, err) = rogs(&["merge", s(&plan), s(&tiles), "--out", s(&merged)]);
    assert_eq!(code, Some(3), "{err}");
    assert!(
        err.contains(&names[0]) && err.contains("--tile NAME"),
        "{err}"
    );
    // A tile not in the plan is named with the plan's tiles.
    let (code, err) = rogs(&[
        "reconstruct",
        "--plan",
        s(&plan),
        "--tile",
        "x99_y99",
        "--out",
        s(&tiles.join("x99_y99")),
    ]);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("x99_y99") && err.contains(&names[0]), "{err}");

    // Every job in its own process, in reverse order (the order does not matter).
    let job = |n: &str| {
        rogs(&[
            "reconstruct",
            "--plan",
            s(&plan),
            "--tile",
            n,
            "--out",
            s(&tiles.join(n)),
        ])
    };
    for n in names.iter().rev() {
        let (code, err) = job(n);
        assert_eq!(code, Some(0), "tile {n}: {err}");
        assert!(tiles.join(n).join(format!("{n}.tile")).is_file(), "{err}");
    }
    // Run again: the job is done already.
    let (code, err) = job(&names[1]);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("already finished"), "{err}");

    let (code, err) = rogs(&["merge", s(&plan), s(&tiles), "--out", s(&merged)]);
    assert_eq!(code, Some(0), "{err}");
    let mut args = vec!["reconstruct", s(&zip), "--out", s(&single)];
    args.extend(SETTINGS);
    let (code, err) = rogs(&args);
    assert_eq!(code, Some(0), "{err}");
    assert_same_map(&single, &merged);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(merged.join("report.json")).expect("report"))
            .expect("json");
    assert_eq!(report["tile_count"], names.len());
    assert_eq!(report["tiles"][0]["restored"], true);
    assert!(report["settings"]["resolution_m"] == 0.1, "{report}");

    // A damaged checkpoint: the merge refuses it by name, its job trains it again.
    let victim = tiles.join(&names[2]).join(format!("{}.tile", names[2]));
    let mut bytes = std::fs::read(&victim).expect("checkpoint");
    let k = bytes.len() / 2;
    bytes[k] ^= 0x5a;
    std::fs::write(&victim, &bytes).expect("write");
    let (code, err) = rogs(&["merge", s(&plan), s(&tiles), "--out", s(&merged)]);
    assert_eq!(code, Some(3), "{err}");
    assert!(
        err.contains(&names[2]) && err.contains("run its job again"),
        "{err}"
    );
    let (code, err) = job(&names[2]);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("training tile") && err.contains("again"),
        "{err}"
    );
    let (code, err) = rogs(&["merge", s(&plan), s(&tiles), "--out", s(&merged)]);
    assert_eq!(code, Some(0), "{err}");
    assert_same_map(&single, &merged);

    // A bundle changed since the plan: every process of the plan refuses it.
    let mut m2 = m.clone();
    m2.frames[0].vehicle_to_world[0][3] += 0.05;
    std::fs::write(&zip, rogs::bundle::write_zip(&m2, &files).expect("zip")).expect("write");
    std::fs::remove_dir_all(tiles.join(&names[0])).ok();
    let (code, err) = job(&names[0]);
    assert_eq!(code, Some(3), "{err}");
    assert!(
        err.contains("fingerprint") && err.contains("rogs plan"),
        "{err}"
    );

    for d in [&plan, &tiles, &merged, &single] {
        std::fs::remove_dir_all(d).ok();
    }
    std::fs::remove_file(zip).ok();
}
