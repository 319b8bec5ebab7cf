//! Host unit of `shaders/partial_sums.wgsl` (sums of runs of `RUN` values of `STRIDE`
//! floats, one invocation per run, no barrier) and its CPU oracle.

use super::buffers::{bind, dispatch, pipeline, uniform};
use super::GpuContext;

/// Values per run: a run's sum is one partial sum the host reads.
pub const RUN: u32 = 256;

/// CPU oracle: the sums of runs of `RUN` values of `stride` floats, in f64.
pub fn partial_sums_cpu(values: &[f32], stride: usize) -> Vec<f32> {
    values
        .chunks(stride * RUN as usize)
        .flat_map(|run| {
            (0..stride).map(move |k| {
                run.iter()
                    .skip(k)
                    .step_by(stride)
                    .map(|&v| v as f64)
                    .sum::<f64>() as f32
            })
        })
        .collect()
}

/// The kernel for one stride.
pub struct PartialSums {
    pipeline: wgpu::ComputePipeline,
    stride: u32,
}

impl PartialSums {
    /// The kernel named `label` (its name in the step's timings) for `stride`; with
    /// `guard`, a sum that is not usable raises `status[0]`.
    pub fn new(ctx: &GpuContext, label: &str, stride: u32, guard: bool) -> Self {
        let consts = format!(
            "const STRIDE: u32 = {stride}u;\nconst RUN: u32 = {RUN}u;\nconst GUARD: bool = {guard};"
        );
        Self {
            pipeline: pipeline(
                ctx,
                label,
                &[
                    crate::render::gpu::GUARD_WGSL,
                    &consts,
                    include_str!("../../shaders/partial_sums.wgsl"),
                ],
                "main",
            ),
            stride,
        }
    }

    /// Runs of `count` values (`stride` floats each) of `values`.
    pub fn runs(count: u32) -> u32 {
        count.div_ceil(RUN)
    }

    /// Encodes the sums of the `count` values of `values` into `sums` (`stride ×
    /// runs(count)` floats); with `guard`, a sum that is not usable raises `status[0]`.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        values: &wgpu::Buffer,
        count: u32,
        sums: &wgpu::Buffer,
        status: &wgpu::Buffer,
    ) {
        let runs = Self::runs(count);
        if runs == 0 {
            return;
        }
        let (gx, gy) = ctx.dispatch_2d(runs.div_ceil(64));
        let sp = uniform(
            ctx,
            "partial_sums",
            bytemuck::cast_slice(&[count, gx * 64, self.stride, 0]),
        );
        let bg = bind(
            ctx,
            &self.pipeline,
            &[(0, &sp), (1, values), (2, sums), (3, status)],
        );
        dispatch(enc, &self.pipeline, &bg, (gx, gy, 1));
    }
}

/// Runs the kernel on `values` (`stride` floats each): the sums and the status word
/// (tests; the trainer encodes it into its step).
pub async fn partial_sums_gpu(
    ctx: &GpuContext,
    values: &[f32],
    stride: u32,
    guard: bool,
) -> Result<(Vec<f32>, u32), super::GpuError> {
    use super::buffers::{init_storage, storage};
    use super::readback::read_f32;
    let count = (values.len() / stride as usize) as u32;
    let k = PartialSums::new(ctx, "partial_sums", stride, guard);
    let input = init_storage(ctx, "values", bytemuck::cast_slice(values));
    let n = (stride * PartialSums::runs(count)) as usize;
    let sums = storage(ctx, "sums", 4 * (n + 1) as u64);
    let status = storage(ctx, "status", 8);
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    k.encode(ctx, &mut enc, &input, count, &sums, &status);
    enc.copy_buffer_to_buffer(&status, 0, &sums, 4 * n as u64, 4);
    ctx.queue.submit([enc.finish()]);
    let mut out = read_f32(ctx, &sums, n + 1).await?;
    let word = out.pop().map_or(0, f32::to_bits);
    Ok((out, word))
}
