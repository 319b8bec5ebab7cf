//! Host unit of shaders/frame_gain.wgsl (a view's own log gain, measured on the GPU
//! from its step's forward pass and copied into the view uniform's `frame_a` before
//! the loss) and its CPU oracle.

use crate::gpu::buffers::{bind, dispatch, pipeline, storage, uniform};
use crate::gpu::GpuContext;
use crate::render::gpu::{GpuForward, VIEW_FRAME_A_OFFSET, VIEW_WGSL};
use crate::render::Image;

/// Pixels a gain is measured over, at least: a view of more is sampled every
/// `stride` pixels. Fewer cost `demo` (192 × 108) 0.35 dB at 4 096 and 0.8 dB at a
/// quarter of its pixels (docs/PERFORMANCE.md, "Frame gains").
pub const GAIN_PIXELS: f64 = 16384.0;
/// Fewer counted pixels say nothing about the frame's exposure: gain 0.
pub const MIN_GAIN_PIXELS: u32 = 64;
/// Only pixels the model covers at least this much count: a partly covered pixel's
/// render is darker than its surfels' colour, which would raise the gain.
pub const GAIN_MIN_ALPHA: f32 = 0.95;
/// The largest log gain a frame takes (a factor of e either way).
pub const MAX_FRAME_LOG_GAIN: f32 = 1.0;

crate::uniform_block! {
    /// The uniform of shaders/frame_gain.wgsl.
    pub struct GainParams {
        width: u32,
        height: u32,
        /// Every `stride`-th pixel of every `stride`-th row counts.
        stride: u32,
        min_pixels: u32,
        /// Pixels the model covers less than this are left out: the loss's
        /// threshold or `GAIN_MIN_ALPHA`, the larger.
        min_alpha: f32,
        max_log_gain: f32,
        pad0: u32,
        pad1: u32,
    }
}

/// The sampling stride of a `width` × `height` view: at least `GAIN_PIXELS` pixels.
pub fn stride(width: u32, height: u32) -> u32 {
    (((width as f64 * height as f64) / GAIN_PIXELS).sqrt() as u32).max(1)
}

/// A measured gain: the log gain and what it came from (read back with the step).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Measured {
    pub log_gain: f32,
    pub pixels: u32,
    pub sum_target: f32,
    pub sum_render: f32,
}

impl Measured {
    pub fn from_words(w: &[f32]) -> Self {
        Self {
            log_gain: w.first().copied().unwrap_or(0.0),
            pixels: w.get(1).map_or(0, |&n| n as u32),
            sum_target: w.get(2).copied().unwrap_or(0.0),
            sum_render: w.get(3).copied().unwrap_or(0.0),
        }
    }
}

/// CPU oracle: the log gain of `target` (packed, `loss::targets`) over `render`
/// (rendered with a frame gain of 0), in f64, as shaders/frame_gain.wgsl measures it.
pub fn frame_gain_cpu(render: &Image<f32>, target: &[u32], min_alpha: f32) -> Measured {
    let (w, h) = (render.width, render.height);
    let s = stride(w, h);
    let (mut st, mut sr, mut n) = (0.0f64, 0.0f64, 0u32);
    for ky in 0..h / s {
        for kx in 0..w / s {
            let i = ((ky * s + s / 2) * w + kx * s + s / 2) as usize;
            let (Some(&t), Some(&a)) = (target.get(i), render.alpha.get(i)) else {
                continue;
            };
            if t >> 24 == 255 || a < min_alpha.max(GAIN_MIN_ALPHA) {
                continue;
            }
            for c in 0..3 {
                st += ((t >> (8 * c)) & 255) as f64 / 255.0;
                sr += render.rgb[3 * i + c] as f64;
            }
            n += 1;
        }
    }
    let log_gain = if n >= MIN_GAIN_PIXELS && sr > 1e-3 * n as f64 {
        ((st / sr).ln() as f32).clamp(-MAX_FRAME_LOG_GAIN, MAX_FRAME_LOG_GAIN)
    } else {
        0.0
    };
    Measured {
        log_gain,
        pixels: n,
        sum_target: st as f32,
        sum_render: sr as f32,
    }
}

/// The kernel.
pub struct FrameGain {
    pipeline: wgpu::ComputePipeline,
}

impl FrameGain {
    pub fn new(ctx: &GpuContext) -> Self {
        Self {
            pipeline: pipeline(
                ctx,
                "frame_gain",
                &[
                    &VIEW_WGSL,
                    GainParams::WGSL,
                    include_str!("../../shaders/frame_gain.wgsl"),
                ],
                "main",
            ),
        }
    }

    /// Encodes the gain of the forward pass `f` (rendered with `frame_a` 0) against
    /// `target` and copies it into `f`'s view uniform, so that the passes encoded
    /// after it see the view at its gain. Returns the four words (`Measured`) to read
    /// back with the step.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        f: &GpuForward,
        target: &wgpu::Buffer,
        min_alpha: f32,
    ) -> wgpu::Buffer {
        let gp = GainParams {
            width: f.width,
            height: f.height,
            stride: stride(f.width, f.height),
            min_pixels: MIN_GAIN_PIXELS,
            min_alpha: min_alpha.max(GAIN_MIN_ALPHA),
            max_log_gain: MAX_FRAME_LOG_GAIN,
            ..GainParams::default()
        };
        let gp = uniform(ctx, "gain_params", bytemuck::bytes_of(&gp));
        let out = storage(ctx, "frame_gain", 16);
        let bg = bind(
            ctx,
            &self.pipeline,
            &[(0, &gp), (1, &f.px), (2, target), (3, &out)],
        );
        dispatch(enc, &self.pipeline, &bg, (1, 1, 1));
        enc.copy_buffer_to_buffer(&out, 0, &f.view, VIEW_FRAME_A_OFFSET, 4);
        out
    }
}
