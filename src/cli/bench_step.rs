//! `rogs bench step`: optimisation steps of a bundle, timed per kernel.
//!
//! Wall time per step (median), the GPU time of every kernel per step from timestamp
//! queries (`gpu::timing`, where the adapter has them), the epoch it implies, and the
//! GPU bytes held per surfel.

use crate::bundle::{Bundle, Limits};
use crate::gpu::timing::PassTimer;
use crate::gpu::GpuContext;
use crate::reconstruct::{ReconstructConfig, Session};
use crate::render::gpu::view_bytes_per_candidate;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

pub fn run(
    bundle: &Path,
    steps: usize,
    resolution: f64,
    half_width: f64,
    no_subgroup_reduction: bool,
    moment_window: Option<usize>,
    adam: super::reconstruct::AdamMode,
) -> Result<ExitCode, String> {
    let mut b =
        Bundle::open(bundle, Limits::default(), &mut |_, _| {}).map_err(|e| e.to_string())?;
    let mut cfg = ReconstructConfig::default();
    cfg.prepare.grid.resolution = resolution;
    cfg.prepare.grid.half_width = half_width;
    cfg.train.moment_window = moment_window;
    cfg.train.adam = adam.scope();
    // One warm-up step (first use of every pipeline and buffer size), then the timed ones.
    cfg.train.max_steps = Some(steps.max(1) + 1);
    let mut ctx = GpuContext::new_blocking().map_err(|e| e.to_string())?;
    ctx.report.subgroups &= !no_subgroup_reduction;
    let subgroups = ctx.report.subgroups;
    let mut s = pollster::block_on(Session::new(&mut b, cfg, ctx)).map_err(|e| e.to_string())?;
    pollster::block_on(s.step(&b)).map_err(|e| e.to_string())?;
    let mut timer = PassTimer::install(&s.trainer.ctx);
    let mut wall = Vec::new();
    let mut cands = Vec::new();
    let mut pairs = Vec::new();
    while !s.is_done() {
        let t = Instant::now();
        pollster::block_on(s.step(&b)).map_err(|e| e.to_string())?;
        wall.push(t.elapsed().as_secs_f64());
        cands.push(s.trainer.last_candidates());
        pairs.push(s.trainer.last_pairs() as f64);
        if let Some(timer) = timer.as_mut() {
            pollster::block_on(timer.collect(&s.trainer.ctx)).map_err(|e| e.to_string())?;
        }
    }
    if wall.is_empty() {
        return Err(format!(
            "{}: only {} training view(s), nothing left to time after the warm-up step; use a bundle with more views",
            bundle.display(),
            s.train_views.len()
        ));
    }
    let n = wall.len() as f64;
    wall.sort_by(f64::total_cmp);
    let median = wall[wall.len() / 2];
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
    let out = serde_json::json!({
        "bench": "step",
        "bundle": bundle.display().to_string(),
        "adapter": s.trainer.ctx.report.name,
        "subgroup_reduction": subgroups,
        "adam": adam.name(),
        "seconds_per_step": wall.iter().sum::<f64>() / n,
        "seconds_per_step_median": median,
        "surfels": s.prepare_report.surfels,
        "training_views": views,
        "steps_timed": wall.len(),
        // An epoch pays for the slow steps too: the mean, not the median.
        "seconds_per_epoch": wall.iter().sum::<f64>() / n * views as f64,
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
    });
    println!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
    );
    Ok(ExitCode::SUCCESS)
}
