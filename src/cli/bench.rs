//! `rogs bench`: measured figures for docs/PERFORMANCE.md.

use crate::bundle::{Bundle, Limits};
use crate::init::prepare::{prepare, PrepareConfig};
use crate::optim::bench::StepBench;
use crate::render::bench::median;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// The rasteriser on one view of a bundle (its culled surfel set after grid and
    /// initialisation): pixel×surfel pairs per second forward and forward+backward,
    /// median of the runs, wall time around each GPU submission.
    ///
    /// Prints JSON, with the keys `bench step` shares for scripts: seconds_per_step
    /// (one forward and backward pass), kernels_ms (kernel → GPU ms per run),
    /// surfels, candidates_per_view, pairs.
    Raster {
        /// The scene bundle.
        bundle: PathBuf,
        /// Frame and view (camera index within the frame) to render.
        #[arg(long, default_value_t = 0)]
        frame: usize,
        #[arg(long, default_value_t = 0)]
        view: usize,
        #[arg(long, default_value_t = 7)]
        runs: usize,
        /// Base grid resolution, metres.
        #[arg(long, default_value_t = 0.05)]
        resolution: f64,
        /// Skip adaptive refinement (faster set-up).
        #[arg(long)]
        no_adaptive: bool,
        /// Add each pixel's gradients with its own atomics instead of summing them
        /// over the subgroup first.
        #[arg(long)]
        no_subgroup_reduction: bool,
    },
    /// Optimisation steps of a bundle: wall time per step, GPU time per kernel from
    /// timestamp queries where the adapter has them, the implied time per epoch, and
    /// GPU bytes per surfel.
    ///
    /// Prints JSON: seconds_per_step (mean; seconds_per_step_median too),
    /// seconds_per_epoch, kernels_ms (kernel → GPU ms per step), surfels,
    /// candidates_per_view and pairs (means over the timed steps), and more.
    Step {
        /// The scene bundle.
        bundle: PathBuf,
        /// Steps to time (after one warm-up step).
        #[arg(long, default_value_t = 10)]
        steps: usize,
        /// Base grid resolution, metres.
        #[arg(long, default_value_t = 0.05)]
        resolution: f64,
        /// Corridor half-width, metres.
        #[arg(long, default_value_t = 8.0)]
        half_width: f64,
        /// Add each pixel's gradients with its own atomics instead of summing them
        /// over the subgroup first (to measure what the reduction gains).
        #[arg(long)]
        no_subgroup_reduction: bool,
        /// At most this many blocks of 256 surfels per Adam pass (the passes a model
        /// whose moments exceed one storage binding needs; to measure what they cost).
        #[arg(long)]
        moment_window: Option<usize>,
        /// Which surfels a step updates (to compare the two).
        #[arg(long, value_enum, default_value = "dense")]
        adam: super::reconstruct::AdamMode,
        /// One exposure per camera instead of a gain per frame too (as `rogs
        /// reconstruct --no-frame-exposure`; to measure what measuring the gains costs).
        #[arg(long)]
        no_frame_exposure: bool,
    },
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

pub fn run(b: Bench) -> Result<ExitCode, String> {
    match b {
        Bench::Raster {
            bundle,
            frame,
            view,
            runs,
            resolution,
            no_adaptive,
            no_subgroup_reduction,
        } => raster(
            &bundle,
            (frame, view),
            runs,
            resolution,
            no_adaptive,
            no_subgroup_reduction,
        ),
        Bench::Step {
            bundle,
            steps,
            resolution,
            half_width,
            no_subgroup_reduction,
            moment_window,
            adam,
            no_frame_exposure,
        } => super::bench_step::run(
            &bundle,
            StepBench {
                steps,
                resolution,
                half_width,
                moment_window,
                adam: adam.scope(),
                frame_exposure: !no_frame_exposure,
            },
            no_subgroup_reduction,
        ),
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

fn raster(
    bundle: &std::path::Path,
    (frame, view): (usize, usize),
    runs: usize,
    resolution: f64,
    no_adaptive: bool,
    no_subgroup_reduction: bool,
) -> Result<ExitCode, String> {
    use crate::gpu::GpuContext;
    use crate::render::bench::{raster_view, RasterBench};
    let b = Bundle::open(bundle, Limits::default(), &mut |_, _| {}).map_err(|e| e.to_string())?;
    let mut ctx = GpuContext::new_blocking().map_err(|e| e.to_string())?;
    ctx.report.subgroups &= !no_subgroup_reduction;
    let o = RasterBench {
        frame,
        view,
        runs,
        resolution,
        adaptive: !no_adaptive,
    };
    let t0 = Instant::now();
    let now = || t0.elapsed().as_secs_f64();
    let out = pollster::block_on(raster_view(&ctx, &b, &o, &now))?;
    println!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
    );
    Ok(ExitCode::SUCCESS)
}
