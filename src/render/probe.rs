//! The platform probe (`shaders/probe.wgsl`): a dense blend with no sort, no lists, no
//! barriers and no atomics, timed by `rogs bench raster` beside the rasteriser on the
//! same adapter. Its ratio between two adapters (SwiftShader in the browser against
//! lavapipe natively) is the platform's own; what the rasteriser's ratio adds to it is
//! the rasteriser's. Host unit, CPU oracle and the fixed list of Gaussians it blends.

use crate::gpu::buffers::{bind, dispatch, init_storage, pipeline, storage, uniform};
use crate::gpu::readback::read_f32;
use crate::gpu::{GpuContext, GpuError};

crate::uniform_block! {
    /// The probe's parameters (WGSL `ProbeParams`, generated from this declaration).
    pub struct ProbeParams {
        width: u32,
        height: u32,
        count: u32,
        pad: u32,
    }
}

/// Gaussians per pixel in the benchmark: enough that a dispatch takes tens of
/// milliseconds on a CPU adapter at the bench's view sizes.
pub const BENCH_BLOBS: usize = 256;

/// `count` Gaussians spread over a `width` × `height` image (a low-discrepancy
/// sequence, the same everywhere): 8 floats each, as the kernel reads them.
pub fn blobs(width: u32, height: u32, count: usize) -> Vec<f32> {
    let (w, h) = (width as f32, height as f32);
    (0..count)
        .flat_map(|i| {
            let f = i as f32;
            let x = (f * 0.618_034).fract() * w;
            let y = (f * 0.754_878).fract() * h;
            let sigma = 3.0 + 20.0 * (f * 0.569_840).fract();
            let opacity = 0.1 + 0.5 * (f * 0.445_042).fract();
            let rgb = [(f * 0.3).fract(), (f * 0.7).fract(), (f * 0.11).fract()];
            [
                x,
                y,
                1.0 / (sigma * sigma),
                opacity,
                rgb[0],
                rgb[1],
                rgb[2],
                0.0,
            ]
        })
        .collect()
}

/// CPU oracle: per pixel rgb and the transmittance left, as the kernel computes them.
pub fn dense_blend_cpu(width: u32, height: u32, blobs: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(4 * (width * height) as usize);
    for y in 0..height {
        for x in 0..width {
            let at = [x as f32 + 0.5, y as f32 + 0.5];
            let (mut t, mut c) = (1.0f32, [0.0f32; 3]);
            for g in blobs.chunks_exact(8) {
                let d = [at[0] - g[0], at[1] - g[1]];
                let a = (g[3] * (-0.5 * (d[0] * d[0] + d[1] * d[1]) * g[2]).exp()).min(0.99);
                for k in 0..3 {
                    c[k] += t * a * g[4 + k];
                }
                t *= 1.0 - a;
            }
            out.extend_from_slice(&[c[0], c[1], c[2], t]);
        }
    }
    out
}

/// The probe's pipeline and buffers for one image size and list.
pub struct DenseBlend {
    pipeline: wgpu::ComputePipeline,
    bind: wgpu::BindGroup,
    out: wgpu::Buffer,
    width: u32,
    height: u32,
}

impl DenseBlend {
    pub fn new(ctx: &GpuContext, width: u32, height: u32, blobs: &[f32]) -> Self {
        let header = ProbeParams::WGSL;
        let pipeline = pipeline(
            ctx,
            "probe_dense_blend",
            &[header, include_str!("../../shaders/probe.wgsl")],
            "main",
        );
        let params = ProbeParams {
            width,
            height,
            count: (blobs.len() / 8) as u32,
            pad: 0,
        };
        let p = uniform(ctx, "probe params", bytemuck::bytes_of(&params));
        let b = init_storage(ctx, "probe blobs", bytemuck::cast_slice(blobs));
        let out = storage(ctx, "probe out", 16 * (width * height) as u64);
        let bind = bind(ctx, &pipeline, &[(0, &p), (1, &b), (2, &out)]);
        Self {
            pipeline,
            bind,
            out,
            width,
            height,
        }
    }

    /// Records one dispatch over the image.
    pub fn encode(&self, enc: &mut wgpu::CommandEncoder) {
        let groups = (self.width.div_ceil(8), self.height.div_ceil(8), 1);
        dispatch(enc, &self.pipeline, &self.bind, groups);
    }

    /// Runs it once and reads the image back (rgb and transmittance per pixel).
    pub async fn run(&self, ctx: &GpuContext) -> Result<Vec<f32>, GpuError> {
        let mut enc = ctx.device.create_command_encoder(&Default::default());
        self.encode(&mut enc);
        ctx.queue.submit([enc.finish()]);
        read_f32(ctx, &self.out, 4 * (self.width * self.height) as usize).await
    }
}
