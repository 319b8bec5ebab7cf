//! `rogs gpu`: adapter report and a compute self-test.

use crate::gpu::scatter_add::{scatter_add_cpu, scatter_add_gpu};
use crate::gpu::GpuContext;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// Print the adapter report as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let ctx = GpuContext::new_blocking().map_err(|e| e.to_string())?;
    if a.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&ctx.report).map_err(|e| e.to_string())?
        );
    } else {
        print!("{}", ctx.report.to_text());
    }
    let n = 1 << 16;
    let index: Vec<u32> = (0..n).map(|i| (i * 7919 % 1000) as u32).collect();
    let values: Vec<f32> = (0..n).map(|i| ((i % 13) as f32 - 6.0) * 0.25).collect();
    let gpu = pollster::block_on(scatter_add_gpu(
        &ctx,
        ctx.report.accumulation,
        1000,
        &index,
        &values,
    ))
    .map_err(|e| e.to_string())?;
    let cpu = scatter_add_cpu(1000, &index, &values);
    let err = gpu
        .iter()
        .zip(&cpu)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    if err > 1e-3 {
        return Err(format!(
            "GPU self-test failed: scatter-add differs from the CPU by {err}"
        ));
    }
    eprintln!("self-test    scatter-add of {n} values matches the CPU (max error {err:.1e})");
    Ok(ExitCode::SUCCESS)
}
