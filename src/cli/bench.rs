//! `rogs bench`: measured figures for docs/PERFORMANCE.md.

use crate::bundle::{Bundle, Limits};
use crate::init::prepare::{prepare, PrepareConfig};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// Grid, initialisation and refinement of a bundle: time per stage, surfel
    /// counts and bytes per surfel (median of the runs).
    Init {
        /// The scene bundle.
        bundle: PathBuf,
        /// Number of runs; the median is reported.
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Base grid resolution, metres.
        #[arg(long, default_value_t = 0.05)]
        resolution: f64,
        /// Corridor half-width, metres.
        #[arg(long, default_value_t = 8.0)]
        half_width: f64,
    },
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

pub fn run(b: Bench) -> Result<ExitCode, String> {
    match b {
        Bench::Init {
            bundle,
            runs,
            resolution,
            half_width,
        } => {
            let t = Instant::now();
            let b = Bundle::open(&bundle, Limits::default(), &mut |_, _| {})
                .map_err(|e| e.to_string())?;
            eprintln!("opened and validated in {:.2} s", t.elapsed().as_secs_f64());
            let mut cfg = PrepareConfig {
                use_lidar: true,
                ..Default::default()
            };
            cfg.grid.resolution = resolution;
            cfg.grid.half_width = half_width;
            let (mut total, mut grid, mut init, mut refine) = (vec![], vec![], vec![], vec![]);
            let mut last = None;
            for _ in 0..runs.max(1) {
                let t = Instant::now();
                let p = prepare(&b, &cfg).map_err(|e| e.to_string())?;
                total.push(t.elapsed().as_secs_f64());
                grid.push(p.report.grid_ms);
                init.push(p.report.init_ms);
                refine.push(p.report.refine_ms);
                last = Some(p.report);
            }
            let r = last.ok_or("no run")?;
            let out = serde_json::json!({
                "bench": "init",
                "bundle": bundle.display().to_string(),
                "frames": b.manifest.frames.len(),
                "runs": runs,
                "total_s": median(total),
                "grid_ms": median(grid),
                "init_ms": median(init),
                "refine_ms": median(refine),
                "report": r,
            });
            println!(
                "{}",
                serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
            );
            Ok(ExitCode::SUCCESS)
        }
    }
}
