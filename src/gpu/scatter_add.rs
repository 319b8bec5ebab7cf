//! Host side of `shaders/scatter_add.wgsl` and its CPU oracle.

use super::buffers::{init_storage, uniform};
use super::readback::read_f32;
use super::{AccumStrategy, GpuContext, GpuError};

/// CPU oracle: `bins[index[i]] += values[i]`, in f64 so that ordering effects vanish.
pub fn scatter_add_cpu(bins: usize, index: &[u32], values: &[f32]) -> Vec<f32> {
    let mut acc = vec![0.0f64; bins];
    for (&i, &v) in index.iter().zip(values) {
        acc[i as usize] += v as f64;
    }
    acc.into_iter().map(|v| v as f32).collect()
}

/// Runs the kernel with the given strategy (which the adapter must support).
pub async fn scatter_add_gpu(
    ctx: &GpuContext,
    strategy: AccumStrategy,
    bins: usize,
    index: &[u32],
    values: &[f32],
) -> Result<Vec<f32>, GpuError> {
    if index.len() != values.len() || index.iter().any(|&i| i as usize >= bins) {
        return Err(GpuError::Validation(
            "scatter_add: index out of range or length mismatch".into(),
        ));
    }
    let dev = &ctx.device;
    let module = ctx.shader(
        "scatter_add",
        &[
            strategy.wgsl(),
            include_str!("../../shaders/scatter_add.wgsl"),
        ],
    );
    let pipeline = dev.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("scatter_add"),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });
    let accum = init_storage(
        ctx,
        "accum",
        bytemuck::cast_slice(&vec![0.0f32; bins.max(1)]),
    );
    let index_buf = init_storage(ctx, "index", bytemuck::cast_slice(index));
    let values_buf = init_storage(ctx, "values", bytemuck::cast_slice(values));
    let groups = (index.len() as u32).div_ceil(256);
    let (gx, gy) = ctx.dispatch_2d(groups);
    let params = [index.len() as u32, gx * 256, 0, 0];
    let params_buf = uniform(ctx, "params", bytemuck::cast_slice(&params));
    let bind = dev.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("scatter_add"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: accum.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: index_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: values_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: params_buf.as_entire_binding(),
            },
        ],
    });
    let mut enc = dev.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(gx, gy, 1);
    }
    ctx.queue.submit([enc.finish()]);
    read_f32(ctx, &accum, bins).await
}
