//! The rasteriser benchmark, shared by `rogs bench raster` (native) and the page's
//! `bench_raster` (wasm, `scripts/bench-raster-page.mjs`): one view of a bundle with
//! the surfels of its culling box after grid and initialisation, forward and
//! forward + backward timed around each GPU submission, median of the runs. The wall
//! clock comes from the caller (`Instant` natively, `Date.now()` in browsers); GPU
//! timestamps are added where the adapter has `TIMESTAMP_QUERY`.

use super::from_bundle::{local_origin, params, view_camera};
use super::gpu::GpuRasterizer;
use super::rasterize_backward::OutputGrads;
use super::{CullConfig, Params, TILE};
use crate::bundle::Bundle;
use crate::gpu::readback::read_bytes;
use crate::gpu::timing::PassTimer;
use crate::gpu::GpuContext;
use crate::init::prepare::{prepare, PrepareConfig};

/// What to time.
#[derive(Clone, Copy, Debug)]
pub struct RasterBench {
    pub frame: usize,
    /// Camera index within the frame.
    pub view: usize,
    pub runs: usize,
    /// Base grid resolution, metres.
    pub resolution: f64,
    pub adaptive: bool,
}

pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The surfels of `all` that the culling box keeps for `cam`, in order.
fn in_view(all: &Params<f32>, cam: &super::ViewCamera, cull: &CullConfig) -> Params<f32> {
    let keep: Vec<usize> = (0..all.len())
        .filter(|&i| super::project::project(all, i, cam, cull).is_some())
        .collect();
    let ch = all.channels;
    Params {
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
    }
}

/// Runs the benchmark and returns its figures as JSON. `now()` is wall-clock seconds.
pub async fn raster_view(
    ctx: &GpuContext,
    b: &Bundle,
    o: &RasterBench,
    now: &dyn Fn() -> f64,
) -> Result<serde_json::Value, String> {
    let mut cfg = PrepareConfig::default();
    cfg.grid.resolution = o.resolution;
    cfg.refine.enabled = o.adaptive;
    let p = prepare(b, &cfg).map_err(|e| e.to_string())?;
    let origin = local_origin(&p.grid, &p.surfels);
    let cam = view_camera(&b.manifest, o.frame, o.view, origin, [0.0, 0.0]).ok_or(format!(
        "the bundle has no frame {} with a view {}",
        o.frame, o.view
    ))?;
    let cull = CullConfig::default();
    // Only the surfels in the view's culling box go to the GPU, as in training.
    let all = params(&p.grid, &p.surfels, origin);
    let sub = in_view(&all, &cam, &cull);
    let ch = all.channels;
    let r = GpuRasterizer::new(ctx, ch as u32)
        .await
        .map_err(|e| e.to_string())?;
    let gp = GpuRasterizer::upload(ctx, &sub);
    let npx = (cam.width * cam.height) as usize;
    let grads = OutputGrads {
        rgb: vec![1e-3; 3 * npx],
        logits: vec![1e-3; ch * npx],
        depth: vec![0.0; npx],
        alpha: vec![0.0; npx],
    };
    let (mut fwd, mut both) = (Vec::new(), Vec::new());
    let (mut gpu_fwd, mut gpu_both) = (Vec::new(), Vec::new());
    let mut timer = PassTimer::install(ctx);
    let mut pairs = 0;
    let err = |e: crate::gpu::GpuError| e.to_string();
    for _ in 0..o.runs.max(1) {
        let t = now();
        let f = r.forward(ctx, &gp, &cam, &cull).await.map_err(err)?;
        // A read-back waits for the work to finish.
        read_bytes(ctx, &f.px, 4).await.map_err(err)?;
        fwd.push(now() - t);
        gpu_fwd.push(gpu_seconds(ctx, &mut timer).await?);
        let t = now();
        let f = r.forward(ctx, &gp, &cam, &cull).await.map_err(err)?;
        r.backward(ctx, &gp, &f, &grads).await.map_err(err)?;
        both.push(now() - t);
        gpu_both.push(gpu_seconds(ctx, &mut timer).await?);
        pairs = f.pairs.unwrap_or(0);
    }
    // The platform probe at the view's size, timed the same way.
    let probe = super::probe::DenseBlend::new(
        ctx,
        cam.width,
        cam.height,
        &super::probe::blobs(cam.width, cam.height, super::probe::BENCH_BLOBS),
    );
    let (mut probe_wall, mut probe_gpu) = (Vec::new(), Vec::new());
    for _ in 0..o.runs.max(1) {
        let t = now();
        probe.run(ctx).await.map_err(err)?;
        probe_wall.push(now() - t);
        probe_gpu.push(gpu_seconds(ctx, &mut timer).await?);
    }
    // Pixel×surfel pairs: every pair of a tile against the tile's pixels (an upper
    // bound on evaluations: early termination skips some).
    let evaluations = pairs as u64 * (TILE * TILE) as u64;
    let (tf, tb) = (median(fwd), median(both));
    let (gf, gb) = (median(gpu_fwd), median(gpu_both));
    Ok(serde_json::json!({
        "bench": "raster",
        "adapter": ctx.report.name,
        "accumulation": ctx.report.accumulation,
        "subgroup_reduction": ctx.report.subgroups,
        "view": {"width": cam.width, "height": cam.height, "frame": o.frame, "view": o.view},
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
        // The platform's own speed: a dense blend with no lists, sort or atomics
        // (src/render/probe.rs); compare its ratio between adapters with the
        // rasteriser's. The wall time includes reading the image back.
        "probe": {
            "kernel": "dense_blend",
            "blobs": super::probe::BENCH_BLOBS,
            "pixels": npx,
            "wall_s": median(probe_wall),
            "gpu_s": timer.as_ref().map(|_| median(probe_gpu)),
        },
        "runs": o.runs.max(1),
        // The keys `rogs bench step` shares, for scripts comparing runs: a step here
        // is one forward and backward pass of the view (median); no epoch.
        "seconds_per_step": tb,
        "seconds_per_epoch": serde_json::Value::Null,
        "surfels": all.len(),
        "candidates_per_view": sub.len(),
        "pairs": pairs,
        // Kernel name → GPU ms per run (a forward pass, then a forward and backward,
        // then the probe).
        "kernels_ms": timer.as_ref().map(|t| t
            .sorted()
            .into_iter()
            .map(|(k, sec, _)| (k.to_string(), serde_json::json!(1e3 * sec / o.runs.max(1) as f64)))
            .collect::<serde_json::Map<_, _>>()),
    }))
}

/// GPU seconds of the kernels recorded since the last call (0 without a timer).
async fn gpu_seconds(ctx: &GpuContext, timer: &mut Option<PassTimer>) -> Result<f64, String> {
    let Some(t) = timer.as_mut() else {
        return Ok(0.0);
    };
    let before = t.total();
    t.collect(ctx).await.map_err(|e| e.to_string())?;
    Ok(t.total() - before)
}
