//! `rogs bench`: measured figures for docs/PERFORMANCE.md.

use crate::bundle::{Bundle, Limits};
use crate::init::prepare::{prepare, PrepareConfig};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

#[derive(clap::Subcommand)]
pub enum Bench {
    /// The rasteriser on one view of a bundle (its culled surfel set after grid and
    /// initialisation): pixel×surfel pairs per second forward and forward+backward,
    /// median of the runs, wall time around each GPU submission.
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
    /// Optimisation steps of a bundle: wall time per step (median), GPU time per
    /// kernel from timestamp queries where the adapter has them, the implied time per
    /// epoch, and GPU bytes per surfel.
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

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
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
        } => super::bench_step::run(
            &bundle,
            steps,
            resolution,
            half_width,
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
    use crate::render::from_bundle::{local_origin, params, view_camera};
    use crate::render::gpu::GpuRasterizer;
    use crate::render::rasterize_backward::OutputGrads;
    use crate::render::CullConfig;
    let b = Bundle::open(bundle, Limits::default(), &mut |_, _| {}).map_err(|e| e.to_string())?;
    let mut cfg = PrepareConfig::default();
    cfg.grid.resolution = resolution;
    cfg.refine.enabled = !no_adaptive;
    let p = prepare(&b, &cfg).map_err(|e| e.to_string())?;
    let origin = local_origin(&p.grid, &p.surfels);
    let cam =
        view_camera(&b.manifest, frame, view, origin, [0.0, 0.0]).ok_or("no such frame or view")?;
    let cull = CullConfig::default();
    // Only the surfels in the view's culling box go to the GPU, as in training.
    let all = params(&p.grid, &p.surfels, origin);
    let keep: Vec<usize> = (0..all.len())
        .filter(|&i| crate::render::project::project(&all, i, &cam, &cull).is_some())
        .collect();
    let ch = all.channels;
    let sub = crate::render::Params {
        pos: keep.iter().map(|&i| all.pos[i]).collect(),
        rgb: keep.iter().map(|&i| all.rgb[i]).collect(),
        log_scale: keep.iter().map(|&i| all.log_scale[i]).collect(),
        opacity: keep.iter().map(|&i| all.opacity[i]).collect(),
        rotation: keep.iter().map(|&i| all.rotation[i]).collect(),
        logits: keep
            .iter()
            .flat_map(|&i| all.logits[i * ch..(i + 1) * ch].to_vec())
            .collect(),
        channels: ch,
    };
    let mut ctx = GpuContext::new_blocking().map_err(|e| e.to_string())?;
    ctx.report.subgroups &= !no_subgroup_reduction;
    let r = pollster::block_on(GpuRasterizer::new(&ctx)).map_err(|e| e.to_string())?;
    let gp = GpuRasterizer::upload(&ctx, &sub);
    let npx = (cam.width * cam.height) as usize;
    let grads = OutputGrads {
        rgb: vec![1e-3; 3 * npx],
        logits: vec![1e-3; ch * npx],
        depth: vec![0.0; npx],
        alpha: vec![0.0; npx],
    };
    let (mut fwd, mut both) = (Vec::new(), Vec::new());
    let (mut gpu_fwd, mut gpu_both) = (Vec::new(), Vec::new());
    let mut timer = crate::gpu::timing::PassTimer::install(&ctx);
    // GPU seconds of the kernels recorded since the last call.
    let gpu_time = |timer: &mut Option<crate::gpu::timing::PassTimer>| -> Result<f64, String> {
        let Some(t) = timer.as_mut() else {
            return Ok(0.0);
        };
        let before = t.total();
        pollster::block_on(t.collect(&ctx)).map_err(|e| e.to_string())?;
        Ok(t.total() - before)
    };
    let mut pairs = 0;
    let mut evaluations = 0u64;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let f = pollster::block_on(r.forward(&ctx, &gp, &cam, &cull)).map_err(|e| e.to_string())?;
        let _ = pollster::block_on(crate::gpu::readback::read_bytes(&ctx, &f.px, 4))
            .map_err(|e| e.to_string())?;
        fwd.push(t.elapsed().as_secs_f64());
        gpu_fwd.push(gpu_time(&mut timer)?);
        let t = Instant::now();
        let f = pollster::block_on(r.forward(&ctx, &gp, &cam, &cull)).map_err(|e| e.to_string())?;
        pollster::block_on(r.backward(&ctx, &gp, &f, &grads)).map_err(|e| e.to_string())?;
        both.push(t.elapsed().as_secs_f64());
        gpu_both.push(gpu_time(&mut timer)?);
        pairs = f.pairs;
        // Pixel×surfel pairs: every pair of a tile against the tile's pixels
        // (an upper bound on evaluations: early termination skips some).
        evaluations = pairs as u64 * (crate::render::TILE * crate::render::TILE) as u64;
    }
    let (tf, tb) = (median(fwd), median(both));
    let (gf, gb) = (median(gpu_fwd), median(gpu_both));
    let out = serde_json::json!({
        "bench": "raster",
        "adapter": ctx.report.name,
        "accumulation": ctx.report.accumulation,
        "subgroup_reduction": ctx.report.subgroups,
        "view": {"width": cam.width, "height": cam.height, "frame": frame, "view": view},
        "surfels_total": all.len(),
        "surfels_in_view": sub.len(),
        "surfel_tile_pairs": pairs,
        "pixel_surfel_pairs": evaluations,
        "forward_s": tf,
        "forward_backward_s": tb,
        "forward_pairs_per_s": evaluations as f64 / tf,
        "forward_backward_pairs_per_s": evaluations as f64 / tb,
        // Kernel time alone from GPU timestamps (null without TIMESTAMP_QUERY).
        "gpu_timestamps": timer.as_ref().map(|t| serde_json::json!({
            "forward_s": gf,
            "forward_backward_s": gb,
            "forward_pairs_per_s": evaluations as f64 / gf,
            "forward_backward_pairs_per_s": evaluations as f64 / gb,
            "kernels_s_total": t.sorted(),
        })),
        "runs": runs,
    });
    println!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
    );
    Ok(ExitCode::SUCCESS)
}
