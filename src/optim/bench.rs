//! The training-step benchmark, shared by `rogs bench step` (native) and the page's
//! `bench_step` (wasm, `scripts/bench-ratio.mjs`): a session on a bundle, one warm-up
//! step (first use of every pipeline and buffer size), then the timed steps. Wall
//! time per step, the part of it spent reading, decoding and packing the target
//! image on the host, and the GPU time of every kernel from timestamp queries
//! (`gpu::timing`, where the adapter has them), so that a browser's step can be
//! told apart into its kernels and the rest. The wall clock comes from the caller
//! (`Instant` natively, `Date.now()` in browsers).

use super::AdamScope;
use crate::bundle::Bundle;
use crate::gpu::timing::PassTimer;
use crate::gpu::GpuContext;
use crate::reconstruct::{ReconstructConfig, Session};
use crate::render::gpu::view_bytes_per_candidate;

/// What to time.
#[derive(Clone, Copy, Debug)]
pub struct StepBench {
    /// Timed steps (after one warm-up step).
    pub steps: usize,
    /// Base grid resolution, metres.
    pub resolution: f64,
    /// Corridor half width, metres.
    pub half_width: f64,
    pub moment_window: Option<usize>,
    pub adam: AdamScope,
    /// A gain per frame (`TrainConfig::frame_exposure`).
    pub frame_exposure: bool,
}

/// Runs the benchmark on `b` (named `name` in the figures) with `ctx`; the figures as
/// JSON. `now()` is wall-clock seconds.
pub async fn step(
    b: &mut Bundle,
    name: &str,
    o: &StepBench,
    ctx: GpuContext,
    now: &dyn Fn() -> f64,
) -> Result<serde_json::Value, String> {
    let mut cfg = ReconstructConfig::default();
    cfg.prepare.grid.resolution = o.resolution;
    cfg.prepare.grid.half_width = o.half_width;
    cfg.train.moment_window = o.moment_window;
    cfg.train.adam = o.adam;
    cfg.train.frame_exposure = o.frame_exposure;
    cfg.train.max_steps = Some(o.steps.max(1) + 1);
    let subgroups = ctx.report.subgroups;
    let mut s = Session::new(b, cfg, ctx).await.map_err(|e| e.to_string())?;
    s.step(b).await.map_err(|e| e.to_string())?;
    let mut timer = PassTimer::install(&s.trainer.ctx);
    let (mut wall, mut cands, mut pairs) = (Vec::new(), Vec::new(), Vec::new());
    let target_ms = s.timings.target_ms;
    while !s.is_done() {
        let t = now();
        s.step(b).await.map_err(|e| e.to_string())?;
        wall.push(now() - t);
        cands.push(s.trainer.last_candidates());
        pairs.push(s.trainer.last_pairs() as f64);
        if let Some(timer) = timer.as_mut() {
            timer
                .collect(&s.trainer.ctx)
                .await
                .map_err(|e| e.to_string())?;
        }
    }
    if wall.is_empty() {
        return Err(format!(
            "{name}: only {} training view(s), nothing left to time after the warm-up step; use a bundle with more views",
            s.train_views.len()
        ));
    }
    let n = wall.len() as f64;
    let mean = wall.iter().sum::<f64>() / n;
    let median = crate::render::bench::median(wall.clone());
    let kernels: Vec<serde_json::Value> = timer
        .as_ref()
        .map(|t| t.sorted())
        .unwrap_or_default()
        .into_iter()
        .map(|(k, sec, passes)| {
            serde_json::json!({"kernel": k, "ms_per_step": 1e3 * sec / n, "passes_per_step": passes as f64 / n})
        })
        .collect();
    // Kernel name → GPU ms per step, for scripts comparing runs.
    let kernels_ms: serde_json::Map<String, serde_json::Value> = kernels
        .iter()
        .filter_map(|k| Some((k["kernel"].as_str()?.to_string(), k["ms_per_step"].clone())))
        .collect();
    let gpu_ms: f64 = kernels
        .iter()
        .filter_map(|k| k["ms_per_step"].as_f64())
        .sum();
    let views = s.train_views.len();
    let surfels = s.prepare_report.surfels.max(1);
    let cand_max = cands.iter().copied().max().unwrap_or(0);
    let per_cand = view_bytes_per_candidate(s.trainer.params.channels);
    Ok(serde_json::json!({
        "bench": "step",
        "bundle": name,
        "adapter": s.trainer.ctx.report.name,
        "subgroup_reduction": subgroups,
        "adam": o.adam.name(),
        "resolution_m": o.resolution,
        "seconds_per_step": mean,
        "seconds_per_step_median": median,
        // Reading, decoding and packing the target image: host work inside the step.
        "target_ms_per_step": (s.timings.target_ms - target_ms) / n,
        "surfels": s.prepare_report.surfels,
        "training_views": views,
        "steps_timed": wall.len(),
        // An epoch pays for the slow steps too: the mean, not the median.
        "seconds_per_epoch": mean * views as f64,
        "gpu_kernel_ms_per_step": if timer.is_some() { serde_json::json!(gpu_ms) } else { serde_json::Value::Null },
        "kernels_ms": kernels_ms,
        "kernels": kernels,
        "candidates_per_view": cands.iter().sum::<usize>() as f64 / n,
        "pairs": pairs.iter().sum::<f64>() / n,
        "bytes_per_surfel_gpu": s.bytes_per_surfel_gpu,
        "candidates_per_view_mean": cands.iter().sum::<usize>() as f64 / n,
        "candidates_per_view_max": cand_max,
        "view_bytes_per_candidate": per_cand,
        "pair_overflows": s.trainer.pair_overflows,
        // Held between steps plus the largest view's per-candidate buffers, per surfel.
        "peak_bytes_per_surfel_gpu": s.bytes_per_surfel_gpu + (per_cand * cand_max as u64) as f64 / surfels as f64,
    }))
}
