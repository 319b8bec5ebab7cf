//! GPU-against-oracle comparison shared by the native and the browser tests: the same
//! scene rendered by the kernels and by the CPU oracle, and the largest differences.

use super::gpu::GpuRasterizer;
use super::rasterize::render;
use super::rasterize_backward::{backward, OutputGrads};
use super::scene::{road_camera, road_patch};
use super::{project_backward, CullConfig, Params, ViewCamera};
use crate::gpu::{AccumStrategy, GpuContext, GpuError};
use crate::synth::rng::Rng;

/// Largest absolute differences, forward outputs and per gradient group (relative to
/// the group's largest magnitude).
#[derive(Debug, Default)]
pub struct Differences {
    pub forward: f32,
    pub pairs: (u32, usize),
    pub grads: Vec<(&'static str, f32)>,
}

/// A 70×50 view (partial tiles) of ~2k surfels seen at a grazing angle.
pub fn test_scene(channels: usize) -> (Params<f32>, ViewCamera) {
    let cam = road_camera(70, 50, 6.0);
    let mut p = road_patch(45, 45, 0.12, -2.7, 2.5, channels, 21).cast::<f32>();
    // Every 7th surfel moved behind the camera: outside the view's candidates, so
    // candidate slots differ from surfel indices.
    for q in p.pos.iter_mut().skip(3).step_by(7) {
        q[1] -= 12.0;
    }
    // One surfel seen edge-on must stay finite.
    p.rotation[100] = [
        std::f32::consts::FRAC_1_SQRT_2,
        0.0,
        std::f32::consts::FRAC_1_SQRT_2,
        0.0,
    ];
    (p, cam)
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn rel_diff(a: &[f32], b: &[f32]) -> f32 {
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-12);
    max_diff(a, b) / scale
}

/// GPU against the oracle with an accumulation `strategy`, reducing over subgroups
/// first or not (`subgroups`), gathering colours and logits in windows of at most
/// `attr_window` surfels (`None`: one window, as for any model whose logits fit a
/// binding).
pub async fn compare(
    ctx: &GpuContext,
    strategy: AccumStrategy,
    subgroups: bool,
    attr_window: Option<u32>,
) -> Result<Differences, GpuError> {
    let ch = 3;
    let (p, cam) = test_scene(ch);
    let cull = CullConfig::default();
    let oracle = render(&p, &cam, &cull);
    let mut r = GpuRasterizer::with_strategy(ctx, strategy, subgroups, ch as u32).await?;
    r.attr_window = attr_window;
    let gp = GpuRasterizer::upload(ctx, &p);
    let f = r.forward(ctx, &gp, &cam, &cull).await?;
    let img = GpuRasterizer::read_image(ctx, &f).await?;
    let o = &oracle.image;
    let forward = [
        max_diff(&img.rgb, &o.rgb),
        max_diff(&img.logits, &o.logits),
        max_diff(&img.depth, &o.depth),
        max_diff(&img.alpha, &o.alpha),
    ]
    .into_iter()
    .fold(0.0, f32::max);
    let mut rng = Rng::new(3);
    let npx = (cam.width * cam.height) as usize;
    let mut v = |k: usize| (0..k).map(|_| rng.normal() as f32).collect::<Vec<f32>>();
    let g = OutputGrads {
        rgb: v(3 * npx),
        logits: v(ch * npx),
        depth: v(npx),
        alpha: v(npx),
    };
    let (vg, exp_cpu) = backward(&p, &cam, &oracle, &g);
    let cpu = project_backward::backward(&p, &cam, &vg);
    let (gpu, exp_gpu) = r.backward(ctx, &gp, &f, &g).await?;
    let flat3 = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
    let z = |v: &[[f32; 3]]| v.iter().map(|p| p[2]).collect::<Vec<f32>>();
    let grads = vec![
        ("z", rel_diff(&z(&gpu.pos), &z(&cpu.pos))),
        ("rgb", rel_diff(&flat3(&gpu.rgb), &flat3(&cpu.rgb))),
        (
            "log_scale",
            rel_diff(
                &gpu.log_scale.iter().flatten().copied().collect::<Vec<_>>(),
                &cpu.log_scale.iter().flatten().copied().collect::<Vec<_>>(),
            ),
        ),
        ("opacity", rel_diff(&gpu.opacity, &cpu.opacity)),
        (
            "rotation",
            rel_diff(
                &gpu.rotation.iter().flatten().copied().collect::<Vec<_>>(),
                &cpu.rotation.iter().flatten().copied().collect::<Vec<_>>(),
            ),
        ),
        ("logits", rel_diff(&gpu.logits, &cpu.logits)),
        ("exposure", rel_diff(&exp_gpu, &exp_cpu)),
    ];
    Ok(Differences {
        forward,
        pairs: (f.pairs.unwrap_or(0), oracle.pairs.len()),
        grads,
    })
}

/// The map's view (`Compositing::Average`) on the GPU against the oracle, on the
/// test scene seen from its road camera: max abs difference of colour, logits,
/// depth and alpha.
pub async fn compare_forward_average(ctx: &GpuContext) -> Result<f32, GpuError> {
    let ch = 3;
    let (p, cam) = test_scene(ch);
    let cull = CullConfig::default();
    let oracle = super::rasterize::render_with(&p, &cam, &cull, super::Compositing::Average);
    let r = GpuRasterizer::new(ctx, ch as u32).await?;
    let gp = GpuRasterizer::upload(ctx, &p);
    let f = r.forward_map(ctx, &gp, &cam, &cull, None).await?;
    let img = GpuRasterizer::read_image(ctx, &f).await?;
    let o = &oracle.image;
    Ok([
        max_diff(&img.rgb, &o.rgb),
        max_diff(&img.logits, &o.logits),
        max_diff(&img.depth, &o.depth),
        max_diff(&img.alpha, &o.alpha),
    ]
    .into_iter()
    .fold(0.0, f32::max))
}

/// A forward pass over more candidates than one scan block holds.
#[derive(Debug)]
pub struct LargeForward {
    pub candidates: usize,
    /// Surfel–tile pairs: GPU, oracle.
    pub pairs: (u32, usize),
    /// Max abs difference of colour and depth.
    pub forward: f32,
}

/// The GPU forward pass against the oracle on a 9 000-surfel patch, whose tile
/// counts span several blocks of the scan (shaders/scan.wgsl).
pub async fn compare_forward_large(ctx: &GpuContext) -> Result<LargeForward, GpuError> {
    let cam = road_camera(64, 48, 8.0);
    let p = road_patch(60, 150, 0.05, -1.5, 2.0, 2, 5).cast::<f32>();
    let cull = CullConfig::default();
    let oracle = render(&p, &cam, &cull);
    let r = GpuRasterizer::new(ctx, p.channels as u32).await?;
    let gp = GpuRasterizer::upload(ctx, &p);
    let f = r.forward(ctx, &gp, &cam, &cull).await?;
    let img = GpuRasterizer::read_image(ctx, &f).await?;
    let o = &oracle.image;
    Ok(LargeForward {
        candidates: f.cand.len(),
        pairs: (f.pairs.unwrap_or(0), oracle.pairs.len()),
        forward: max_diff(&img.rgb, &o.rgb).max(max_diff(&img.depth, &o.depth)),
    })
}
