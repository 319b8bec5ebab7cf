//! One optimisation step on the GPU against the CPU oracles, shared by the native and
//! the browser tests: the loss, regulariser and rasteriser gradients against
//! `loss::photometric` + the rasteriser oracle + `loss::regularise`, then the Adam
//! kernel against `optim::adam` applied to the GPU's own gradients (Adam's
//! normalisation turns a 1e-7 gradient difference into a full step, so the update is
//! checked from identical gradients), over four steps so that the moments matter: two
//! of one view, one of a view that sees a part of it, and the first view again, so
//! that selective Adam's surfels that missed a step decay their moments.

use super::adam::{learnable, step, Exposure, StepConstants, Touched};
use super::train::Trainer;
use super::TrainConfig;
use crate::gpu::{GpuContext, GpuError};
use crate::loss::photometric::photometric;
use crate::loss::regularise::{regularise_over, RegData};
use crate::render::check::test_scene;
use crate::render::rasterize::render;
use crate::render::{project_backward, rasterize_backward, Params};
use crate::synth::rng::Rng;

#[derive(Debug, Default)]
pub struct StepDifferences {
    /// Loss terms, relative: (GPU, CPU) per term.
    pub losses: Vec<(&'static str, f64, f64)>,
    /// Gradients of step 1, relative to each group's largest magnitude.
    pub grads: Vec<(&'static str, f32)>,
    /// Parameters after each step against the CPU Adam, max abs difference.
    pub params: [f32; 4],
    /// Exposure after the last step against the CPU Adam.
    pub exposure: f32,
    /// Largest parameter change of step 1 (so that a no-op step cannot pass).
    pub moved: f32,
    /// Whether the CPU Adam applied each step (it refuses non-finite updates).
    pub applied: [bool; 4],
    /// Surfels that step 4 updated after missing step 3 (their moments decayed);
    /// 0 under dense Adam.
    pub decayed: usize,
    /// `Trainer::pair_overflows` after steps 1 and 2.
    pub pair_overflows: [usize; 2],
    /// The view's log gain as step 1 measured it (`frame_gain` `None`): (GPU, CPU
    /// oracle, pixels counted on the GPU).
    pub gain: Option<(f32, f32, u32)>,
}

fn flat(p: &Params<f32>) -> Vec<f32> {
    let mut v: Vec<f32> = p.pos.iter().flatten().copied().collect();
    v.extend(p.rotation.iter().flatten());
    v.extend(p.log_scale.iter().flatten());
    v.extend(&p.opacity);
    v.extend(p.rgb.iter().flatten());
    v.extend(&p.logits);
    v
}

fn max_abs(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn rel(a: &[f32], b: &[f32]) -> f32 {
    max_abs(a, b) / b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-12)
}

/// A chain of neighbours along the surfel list and random priors, so that every
/// regulariser term is active.
fn reg_data(n: usize, z: &[f32], rng: &mut Rng) -> RegData {
    let mut adj_start = vec![0u32];
    let mut adj = Vec::new();
    for i in 0..n {
        if i > 0 {
            adj.push(i as u32 - 1);
        }
        if i + 1 < n {
            adj.push(i as u32 + 1);
        }
        adj_start.push(adj.len() as u32);
    }
    let priors = (0..n)
        .map(|i| {
            let dz = 0.1 * rng.normal() as f32;
            let has = (i % 3 != 0) as u8 as f32;
            [z[i] + dz, rng.uniform() as f32, z[i] - 0.5 * dz, has]
        })
        .collect();
    RegData {
        edges: adj.len() / 2,
        adj_start,
        adj,
        priors,
        with_lidar: 2 * n / 3,
    }
}

/// Four GPU steps against the oracles, with Adam's scope `mode`;
/// `moment_window` limits the blocks of 256 surfels whose moments one `adam` pass
/// binds (`None`: as many as fit, one pass here); `pair_margin` (`None`: the default)
/// sizes step 2's pair buffers from step 1's count (below 1 step 2 overflows them and
/// runs again); `robust_c` weighs the RGB term robustly (`LossConfig::robust_c`, 0:
/// plain L1); `frame_gain`: the view's own log gain on top of its camera's exposure,
/// which the oracle renders as exposure a, or `None`: step 1 measures it from its
/// forward pass (`optim::gain`, the target then darker than the render) and trains
/// at it, and the oracle measures it from its own render (`frame_gain_cpu`).
pub async fn compare_step(
    ctx: GpuContext,
    mode: super::AdamScope,
    moment_window: Option<usize>,
    pair_margin: Option<f64>,
    robust_c: f32,
    frame_gain: Option<f32>,
) -> Result<StepDifferences, GpuError> {
    let ch = 4;
    let (p0, mut cam) = test_scene(ch);
    // The trainer's exposures start at zero on the GPU, so that the view's exposure
    // is its frame gain alone.
    cam.exposure = [frame_gain.unwrap_or(0.0), 0.0];
    let measure = frame_gain.is_none();
    let n = p0.len();
    let mut rng = Rng::new(11);
    let z: Vec<f32> = p0.pos.iter().map(|q| q[2]).collect();
    let reg = reg_data(n, &z, &mut rng);
    let mut cfg = TrainConfig {
        moment_window,
        adam: mode,
        ..TrainConfig::default()
    };
    let selective = mode == super::AdamScope::Selective;
    cfg.pair_margin = pair_margin.unwrap_or(cfg.pair_margin);
    cfg.loss.min_alpha = 0.2;
    cfg.loss.robust_c = robust_c;
    let npx = (cam.width * cam.height) as usize;
    // Random colours (at most half as bright when the gain is measured, so that it
    // is far from 0); a tenth of the pixels masked out.
    let bits = if measure { 0x7f_7f7f } else { 0xff_ffff };
    let target: Vec<u32> = (0..npx)
        .map(|_| {
            let c = (rng.next_u64() & bits) as u32;
            let cls = if rng.uniform() < 0.1 {
                255
            } else {
                (rng.next_u64() % ch as u64) as u32
            };
            c | cls << 24
        })
        .collect();
    let mask = target.iter().filter(|t| *t >> 24 != 255).count();
    let extent = 10.0;
    let mut t = Trainer::new(ctx, &p0, &reg, 1, &cfg, extent, 4)
        .await
        .map_err(|e| GpuError::Validation(e.to_string()))?;
    let cull = cfg.cull;
    let mut out = StepDifferences::default();
    // CPU chain of step 1, at the gain the oracle measures when step 1 measures it.
    let mut cam1 = cam;
    let mut gain_cpu = None;
    if measure {
        let f0 = render(&p0, &cam, &cull);
        let m = super::gain::frame_gain_cpu(&f0.image, &target, cfg.loss.min_alpha);
        cam1.exposure[0] = m.log_gain;
        gain_cpu = Some(m.log_gain);
    }
    let f = render(&p0, &cam1, &cull);
    let (l, og) = photometric(&f.image, &target, &cfg.loss, 1.0 / mask as f32);
    let (vg, exp_g) = rasterize_backward::backward(&p0, &cam1, &f, &og);
    let mut g = project_backward::backward(&p0, &cam1, &vg);
    let w = reg.weights(&cfg.loss, true);
    let cand0 = crate::render::candidates::candidates(&p0.pos, &cam, &cull, None);
    let all: Vec<u32> = (0..n as u32).collect();
    // The surfels the regularisers cover: the candidates under selective Adam.
    let over = if selective { &cand0 } else { &all };
    let (rl, rz) = regularise_over(&reg, &w, &z, over);
    for (&i, dz) in over.iter().zip(&rz) {
        g.pos[i as usize][2] += dz;
    }
    let to_gpu = |e: super::train::TrainError| GpuError::Validation(e.to_string());
    let s1 = t
        .step_with(&cam, 0, &target, mask, None, measure)
        .await
        .map_err(to_gpu)?;
    let gl = s1.loss;
    out.gain = s1
        .gain
        .zip(gain_cpu)
        .map(|(g, c)| (g.log_gain, c, g.pixels));
    out.losses = vec![
        ("rgb", gl.rgb, l.rgb),
        ("ce", gl.ce, l.ce),
        ("smooth", gl.smooth, rl[0]),
        ("traj", gl.traj, rl[1]),
        ("lidar", gl.lidar, rl[2]),
    ];
    let (g1, e1) = t
        .read_grads()
        .await?
        .ok_or_else(|| GpuError::Validation("no gradients after a step".into()))?;
    out.pair_overflows[0] = t.pair_overflows;
    let zs = |p: &Params<f32>| p.pos.iter().map(|q| q[2]).collect::<Vec<f32>>();
    let f3 = |v: &[[f32; 3]]| v.iter().flatten().copied().collect::<Vec<f32>>();
    out.grads = vec![
        ("z", rel(&zs(&g1), &zs(&g))),
        ("rgb", rel(&f3(&g1.rgb), &f3(&g.rgb))),
        ("opacity", rel(&g1.opacity, &g.opacity)),
        ("logits", rel(&g1.logits, &g.logits)),
        (
            "rotation",
            rel(
                &g1.rotation.iter().flatten().copied().collect::<Vec<_>>(),
                &g.rotation.iter().flatten().copied().collect::<Vec<_>>(),
            ),
        ),
        ("exposure", rel(&e1, &exp_g)),
    ];
    // Adam from the GPU's gradients, step by step: views A, A, B (8 m further on, so
    // that it sees only a part of A's candidates), A.
    let mut near = cam;
    near.world_to_cam[2][3] -= 8.0;
    let lr = &cfg.lr;
    let mut moments = vec![0.0f32; 2 * learnable(ch) * n];
    let mut last = vec![0u32; n];
    let mut em = [0.0f32; 4];
    let mut exposure = [0.0f32; 2];
    let mut cpu = p0.clone();
    let (mut grads, mut exp_grad) = (g1, e1);
    let mut cands = vec![cand0.clone()];
    for (k, view) in [cam, cam, near, cam].iter().enumerate() {
        if k > 0 {
            cands.push(crate::render::candidates::candidates(
                &t.params.xyz,
                view,
                &cull,
                None,
            ));
            t.step(view, 0, &target, mask).await.map_err(to_gpu)?;
            (grads, exp_grad) = t
                .read_grads()
                .await?
                .ok_or_else(|| GpuError::Validation("no gradients after a step".into()))?;
            if k == 1 {
                out.pair_overflows[1] = t.pair_overflows;
            }
        }
        let c = StepConstants::new(lr, lr.z_at(k, 4, extent), k as u32 + 1);
        let e = Exposure {
            value: &mut exposure,
            grad: exp_grad,
            moments: &mut em,
        };
        let touched = match mode {
            super::AdamScope::Selective => Touched::Only(&cands[k]),
            super::AdamScope::Dense => Touched::All,
        };
        if k == 3 && mode != super::AdamScope::Dense {
            out.decayed = cands[3].iter().filter(|&&i| last[i as usize] == 2).count();
        }
        out.applied[k] = step(&mut cpu, &grads, &mut moments, &mut last, touched, e, &c);
        let pk = t.read_params().await?;
        out.params[k] = max_abs(&flat(&pk), &flat(&cpu));
        if k == 0 {
            out.moved = max_abs(&flat(&pk), &flat(&p0));
        }
    }
    let e = t.read_exposures().await?;
    out.exposure = max_abs(&e[0], &exposure);
    Ok(out)
}

/// What the trainer did about a surfel its candidate list missed.
#[derive(Debug)]
pub struct MissedCandidate {
    /// `Trainer::position_refreshes` after steps 1 and 2.
    pub refreshes: [usize; 2],
    /// The surfel's z in the host's copy: as uploaded, and after step 1.
    pub host_z: [f32; 2],
    /// Its z on the GPU after step 1.
    pub gpu_z: f32,
}

/// Dense Adam: a surfel uploaded 50 m up (out of the view's box, so no candidate) and
/// then put back on the road on the GPU alone: the first step must notice it and read
/// the positions back, the second must list it and need nothing. Selective Adam (only
/// candidates move, so only they can leave the host's margin): a candidate moved 2.5 m
/// up on the GPU alone, which its step must notice.
pub async fn missed_candidate(
    ctx: GpuContext,
    mode: super::AdamScope,
) -> Result<MissedCandidate, GpuError> {
    let selective = mode == super::AdamScope::Selective;
    let (mut p0, mut cam) = test_scene(2);
    cam.exposure = [0.0, 0.0];
    let k = 1;
    let road_z = p0.pos[k][2];
    let (uploaded, moved) = if selective {
        (road_z, road_z + 2.5)
    } else {
        (50.0, road_z)
    };
    p0.pos[k][2] = uploaded;
    let n = p0.len();
    let z: Vec<f32> = p0.pos.iter().map(|q| q[2]).collect();
    let reg = reg_data(n, &z, &mut Rng::new(5));
    let to_gpu = |e: super::train::TrainError| GpuError::Validation(e.to_string());
    let cfg = TrainConfig {
        adam: mode,
        ..TrainConfig::default()
    };
    let mut t = Trainer::new(ctx, &p0, &reg, 1, &cfg, 10.0, 4)
        .await
        .map_err(to_gpu)?;
    let uploaded = t.params.xyz[k][2];
    t.ctx.queue.write_buffer(
        &t.params.pos,
        4 * (3 * k as u64 + 2),
        bytemuck::bytes_of(&moved),
    );
    let npx = (cam.width * cam.height) as usize;
    let target = vec![0x0080_8080u32; npx];
    t.step(&cam, 0, &target, npx).await.map_err(to_gpu)?;
    let after_one = t.position_refreshes;
    let host_z = t.params.xyz[k][2];
    let gpu_z = t.read_params().await?.pos[k][2];
    t.step(&cam, 0, &target, npx).await.map_err(to_gpu)?;
    Ok(MissedCandidate {
        refreshes: [after_one, t.position_refreshes],
        host_z: [uploaded, host_z],
        gpu_z,
    })
}

/// The pose gradient of one step on the GPU (`pose_grad` after `project_backward`)
/// against the CPU chain (rasteriser oracle, loss, `optim::pose::gradient`): (GPU, CPU)
/// dL/d(ω, τ) about a vehicle centre off to one side of the camera.
pub async fn compare_pose_grad(ctx: GpuContext) -> Result<([f64; 6], [f64; 6]), GpuError> {
    let ch = 4;
    let (p0, mut cam) = test_scene(ch);
    cam.exposure = [0.0, 0.0];
    let n = p0.len();
    let mut rng = Rng::new(17);
    let z: Vec<f32> = p0.pos.iter().map(|q| q[2]).collect();
    let reg = reg_data(n, &z, &mut rng);
    let mut cfg = TrainConfig::default();
    cfg.loss.min_alpha = 0.2;
    let npx = (cam.width * cam.height) as usize;
    let target: Vec<u32> = (0..npx)
        .map(|_| (rng.next_u64() & 0xff_ffff) as u32 | ((rng.next_u64() % ch as u64) as u32) << 24)
        .collect();
    let mut t = Trainer::new(ctx, &p0, &reg, 1, &cfg, 10.0, 4)
        .await
        .map_err(|e| GpuError::Validation(e.to_string()))?;
    let centre = [0.5f32, -2.0, -1.5];
    let f = render(&p0, &cam, &cfg.cull);
    let (_, og) = photometric(&f.image, &target, &cfg.loss, 1.0 / npx as f32);
    let (vg, _) = rasterize_backward::backward(&p0, &cam, &f, &og);
    let g = project_backward::backward(&p0, &cam, &vg);
    let cpu = super::pose::gradient(&p0, &g, centre.map(|v| v as f64));
    let gpu = t
        .step_with(&cam, 0, &target, npx, Some(centre), false)
        .await
        .map_err(|e| GpuError::Validation(e.to_string()))?
        .pose;
    let gpu = gpu.ok_or_else(|| GpuError::Validation("no pose gradient".into()))?;
    Ok((gpu, cpu))
}
