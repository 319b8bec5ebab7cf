//! `rogs bench step`: optimisation steps of a bundle, timed per kernel
//! (`optim::bench`, which the page's `bench_step` runs too).

use crate::bundle::{Bundle, Limits};
use crate::gpu::GpuContext;
use crate::optim::bench::StepBench;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

pub fn run(bundle: &Path, o: StepBench, no_subgroup_reduction: bool) -> Result<ExitCode, String> {
    let mut b =
        Bundle::open(bundle, Limits::default(), &mut |_, _| {}).map_err(|e| e.to_string())?;
    let mut ctx = GpuContext::new_blocking().map_err(|e| e.to_string())?;
    ctx.report.subgroups &= !no_subgroup_reduction;
    let t0 = Instant::now();
    let now = || t0.elapsed().as_secs_f64();
    let name = bundle.display().to_string();
    let out = pollster::block_on(crate::optim::bench::step(&mut b, &name, &o, ctx, &now))?;
    println!(
        "{}",
        serde_json::to_string_pretty(&out).map_err(|e| e.to_string())?
    );
    Ok(ExitCode::SUCCESS)
}
