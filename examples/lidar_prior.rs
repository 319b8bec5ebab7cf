//! How good is the LiDAR elevation prior before any training? For a bundle with
//! ground truth: builds the grid as `rogs reconstruct` does, computes each surfel's
//! LiDAR prior (`RegData::new`) and prints its error against the true elevation, and
//! that of ẑ (the trajectory plane), as JSON. Seconds instead of a reconstruction, so
//! gate settings can be compared quickly.
//!
//! `cargo run --release --example lidar_prior -- BUNDLE.zip [RESOLUTION_M] [GATE_M]`
//! (environment: `BAND=M` sets the lowest-layer band, `NO_ALIGN=1` keeps the poses)

use rogs::bundle::{Bundle, Limits};
use rogs::eval::metrics::error_stats;
use rogs::eval::raster::BevRaster;
use rogs::init::align::{align_bundle, AlignConfig, AlignSummary};
use rogs::init::prepare::{lidar_world, prepare};
use rogs::loss::regularise::RegData;
use rogs::reconstruct::ReconstructConfig;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args
        .first()
        .ok_or("usage: lidar_prior BUNDLE [RES] [GATE]")?;
    // Read as bytes rather than with `Bundle::open`, so the example also builds for
    // wasm32, which `cargo test --target wasm32-unknown-unknown` compiles.
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    let b = Bundle::from_zip_bytes(bytes, Limits::default()).map_err(|e| e.to_string())?;
    let truth = BevRaster::from_bundle(&b)
        .map_err(|e| e.to_string())?
        .ok_or("the bundle has no ground truth")?;
    let mut cfg = ReconstructConfig::default();
    if let Some(r) = args.get(1) {
        cfg.prepare.grid.resolution = r.parse().map_err(|_| "RES: metres")?;
    }
    if let Some(g) = args.get(2) {
        cfg.train.loss.lidar_gate_m = g.parse().map_err(|_| "GATE: metres")?;
    }
    let mut b = b;
    if std::env::var_os("NO_ALIGN").is_none() {
        let t = std::time::Instant::now();
        let a = align_bundle(&mut b, &AlignConfig::default()).map_err(|e| e.to_string())?;
        if let Some(a) = a {
            eprintln!(
                "align: {:?}, {:.1} s",
                AlignSummary::new(&a),
                t.elapsed().as_secs_f64()
            );
        }
    }
    if let Some(v) = std::env::var_os("BAND") {
        cfg.train.loss.lidar_band_m = v.to_str().and_then(|v| v.parse().ok()).ok_or("BAND")?;
    }
    let p = prepare(&b, &cfg.prepare).map_err(|e| e.to_string())?;
    let (lidar, _) = lidar_world(&b).map_err(|e| e.to_string())?;
    let s = &p.surfels;
    let reg = RegData::new(&p.grid, &s.z_hat, &s.q, &lidar, 0.0, &cfg.train.loss);
    let (mut prior, mut plane, mut none) = (Vec::new(), Vec::new(), Vec::new());
    let mut both = Vec::new();
    for (i, pr) in reg.priors.iter().enumerate() {
        let [x, y] = p.grid.xy(i);
        let Some(t) = truth.elevation_xy(x, y) else {
            continue;
        };
        plane.push(pr[0] as f64 - t);
        if pr[3] > 0.0 {
            prior.push(pr[2] as f64 - t);
        } else {
            none.push(pr[0] as f64 - t);
        }
        both.push(if pr[3] > 0.0 { pr[2] } else { pr[0] } as f64 - t);
    }
    let stats = |v: &mut Vec<f64>| {
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        error_stats(v).map(|e| {
            format!(
                "{{\"count\": {}, \"mean_cm\": {:.2}, \"rmse_cm\": {:.2}, \"mae_cm\": {:.2}, \"p95_cm\": {:.2}}}",
                e.count,
                mean * 100.0,
                e.rmse * 100.0,
                e.mae * 100.0,
                e.p95 * 100.0
            )
        })
    };
    println!(
        "{{\"surfels\": {}, \"with_lidar\": {},\n \"prior\": {:?},\n \"plane\": {:?},\n \"no_prior_plane\": {:?},\n \"prior_else_plane\": {:?}}}",
        p.grid.len(),
        reg.with_lidar,
        stats(&mut prior),
        stats(&mut plane),
        stats(&mut none),
        stats(&mut both)
    );
    Ok(())
}
