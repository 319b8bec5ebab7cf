//! Photometric pose refinement: a correction of every frame's vehicle pose (all six
//! degrees of freedom), learnt with the surfels from the rendering loss's gradient.
//!
//! The LiDAR alignment (`init::align`) fixes a frame's height, roll and pitch from its
//! sweep's ground; x, y and yaw leave the ground where it is and only the images can
//! tell them. A correction (ω, τ) moves the vehicle to R(ω)(x − c) + c + τ, c being
//! the vehicle's position: it rotates about the vehicle, so that a rotation does not
//! also translate it, and every camera of the frame moves with it (the rig stays as
//! the bundle gives it). The gradient comes from the GPU (`shaders/pose_grad.wgsl`,
//! host unit `PoseGrad`, oracle `gradient`) after each step; the corrections live on
//! the host, a few numbers per frame, and are stepped there with Adam. What keeps
//! them near the given poses: a box (`PoseConfig::max_*`), a decoupled decay toward
//! zero, and a start after part of the schedule, once the map has formed (before
//! that the gradient says more about the map than about the poses).

use crate::bundle::transform::{exp_so3, mat, mul};
use crate::bundle::Mat4Rows;
use crate::gpu::buffers::{bind, dispatch, pipeline, storage, uniform};
use crate::gpu::GpuContext;
use crate::render::gpu::{GpuForward, GpuParams};
use crate::render::project_backward::Grads;
use crate::render::rasterize_backward::VIEW_GRAD;
use crate::render::real::Real;
use crate::render::{Params, ViewCamera};
use serde::{Deserialize, Serialize};

/// Settings of the refinement.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PoseConfig {
    /// Adam's learning rate of the translation, metres per step.
    pub lr_translation_m: f64,
    /// Adam's learning rate of the rotation, degrees per step.
    pub lr_rotation_deg: f64,
    /// The correction stays within ± this per axis.
    pub max_translation_m: f64,
    pub max_rotation_deg: f64,
    /// Fraction of the correction removed per update (a prior toward the given pose).
    pub decay: f64,
    /// Fraction of the schedule's steps before the poses start to move.
    pub start: f64,
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self {
            lr_translation_m: 0.005,
            lr_rotation_deg: 0.05,
            max_translation_m: 0.5,
            max_rotation_deg: 3.0,
            decay: 0.0,
            start: 0.25,
        }
    }
}

/// A frame's correction: rotation ω (axis-angle, radians) about the vehicle's
/// position, then translation τ (m), both in the world frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Correction {
    pub omega: [f64; 3],
    pub tau: [f64; 3],
}

impl Correction {
    /// ΔT as a transform of world points (`centre`: the vehicle's position, in the
    /// frame of the points).
    fn delta(&self, centre: [f64; 3]) -> Mat4Rows {
        let r = exp_so3(self.omega);
        let t = [0, 1, 2]
            .map(|i| centre[i] + self.tau[i] - (0..3).map(|k| r[i][k] * centre[k]).sum::<f64>());
        mat(r, t)
    }

    /// The corrected vehicle-to-world pose: ΔT ∘ pose.
    pub fn apply_to_pose(&self, v2w: &Mat4Rows) -> Mat4Rows {
        mul(&self.delta([v2w[0][3], v2w[1][3], v2w[2][3]]), v2w)
    }

    /// The view from the corrected pose: world-to-camera W ∘ ΔT⁻¹, with `centre` the
    /// vehicle's position in the view's (local) frame.
    pub fn apply(&self, cam: &ViewCamera, centre: [f64; 3]) -> ViewCamera {
        let d = crate::bundle::transform::inverse(&self.delta(centre));
        let w = cam.world_to_cam.map(|r| r.map(|v| v as f64));
        let mut out = *cam;
        for (row, wr) in out.world_to_cam.iter_mut().zip(&w) {
            *row = [0, 1, 2, 3].map(|j| {
                let lin: f64 = (0..3).map(|k| wr[k] * d[k][j]).sum();
                (lin + if j == 3 { wr[3] } else { 0.0 }) as f32
            });
        }
        out
    }

    /// Size of the correction: translation (m) and rotation angle (degrees).
    pub fn magnitude(&self) -> (f64, f64) {
        let n = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        (n(self.tau), n(self.omega).to_degrees())
    }
}

/// Oracle of `shaders/pose_grad.wgsl`: dL/d(ω, τ) at a zero correction from the
/// surfels' parameter gradients (`project_backward`'s, rendering loss only), `centre`
/// the vehicle's position in the surfels' frame.
pub fn gradient<R: Real>(p: &Params<R>, g: &Grads<R>, centre: [f64; 3]) -> [f64; 6] {
    let mut out = [0.0; 6];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    for i in 0..p.len() {
        let gp = g.pos[i].map(|v| v.to_f64());
        let r = [0, 1, 2].map(|k| p.pos[i][k].to_f64() - centre[k]);
        let q = p.rotation[i].map(|v| v.to_f64());
        let gq = g.rotation[i].map(|v| v.to_f64());
        let (w, qv) = (q[0], [q[1], q[2], q[3]]);
        let (gw, gv) = (gq[0], [gq[1], gq[2], gq[3]]);
        let rg = cross(r, gp);
        let qg = cross(qv, gv);
        for k in 0..3 {
            let torque = 0.5 * (w * gv[k] - gw * qv[k] + qg[k]);
            out[k] -= rg[k] + torque;
            out[3 + k] -= gp[k];
        }
    }
    out
}

/// Workgroup size of `pose_grad` (the kernel's `WG`).
const WG: u32 = 256;

/// Host unit of `shaders/pose_grad.wgsl`.
pub struct PoseGrad {
    pipeline: wgpu::ComputePipeline,
}

/// The partial sums `PoseGrad::encode` leaves: six floats per workgroup.
pub struct PosePartials {
    pub buffer: wgpu::Buffer,
    pub groups: usize,
}

impl PosePartials {
    /// The gradient dL/d(ω, τ) from the partial sums read back.
    pub fn sum(partials: &[f32]) -> [f64; 6] {
        let mut g = [0.0; 6];
        for c in partials.chunks_exact(6) {
            for k in 0..6 {
                g[k] += c[k] as f64;
            }
        }
        g
    }
}

impl PoseGrad {
    pub fn new(ctx: &GpuContext) -> Self {
        Self {
            pipeline: pipeline(
                ctx,
                "pose_grad",
                &[include_str!("../../shaders/pose_grad.wgsl")],
                "main",
            ),
        }
    }

    /// Reduces the view's parameter gradients (`view_grad` after `project_backward`,
    /// `VIEW_GRAD + channels` floats per slot) to partial sums of dL/d(ω, τ) about `centre`.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        p: &GpuParams,
        f: &GpuForward,
        view_grad: &wgpu::Buffer,
        centre: [f32; 3],
    ) -> PosePartials {
        let n = f.cand.len() as u32;
        let stride = VIEW_GRAD as u32 + f.channels;
        let (gx, gy) = ctx.dispatch_2d(n.div_ceil(WG));
        let mut u: Vec<u32> = centre.iter().map(|v| v.to_bits()).collect();
        u.extend([0, n, gx * WG, stride, 0]);
        let u = uniform(ctx, "pose_params", bytemuck::cast_slice(&u));
        let groups = (gx * gy) as usize;
        let buffer = storage(ctx, "pose_partial", 4 * 6 * groups as u64);
        let bg = bind(
            ctx,
            &self.pipeline,
            &[
                (0, &u),
                (1, view_grad),
                (2, &p.pos),
                (3, &p.rotation),
                (4, &f.counts),
                (5, &f.cand_buf),
                (6, &buffer),
            ],
        );
        dispatch(enc, &self.pipeline, &bg, (gx, gy, 1));
        PosePartials { buffer, groups }
    }
}

/// Per-frame corrections and their Adam state.
#[derive(Clone, Debug)]
pub struct PoseRefiner {
    pub cfg: PoseConfig,
    pub corrections: Vec<Correction>,
    moments: Vec<[[f64; 6]; 2]>,
    updates: Vec<u32>,
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-12;

impl PoseRefiner {
    pub fn new(frames: usize, cfg: PoseConfig) -> Self {
        Self {
            cfg,
            corrections: vec![Correction::default(); frames],
            moments: vec![[[0.0; 6]; 2]; frames],
            updates: vec![0; frames],
        }
    }

    /// The correction of `frame` (zero for a frame it does not know).
    pub fn correction(&self, frame: usize) -> Correction {
        self.corrections.get(frame).copied().unwrap_or_default()
    }

    /// Updates of `frame` so far.
    pub fn updates(&self, frame: usize) -> u32 {
        self.updates.get(frame).copied().unwrap_or(0)
    }

    /// One Adam step of `frame`'s correction with the gradient dL/d(ω, τ). A gradient
    /// that is not finite is ignored.
    pub fn update(&mut self, frame: usize, g: [f64; 6]) {
        if frame >= self.corrections.len() || g.iter().any(|v| !v.is_finite()) {
            return;
        }
        let c = &self.cfg;
        let t = self.updates[frame] + 1;
        self.updates[frame] = t;
        let [m, v] = &mut self.moments[frame];
        let b1 = 1.0 - BETA1.powi(t as i32);
        let b2 = 1.0 - BETA2.powi(t as i32);
        let corr = &mut self.corrections[frame];
        let lr_r = c.lr_rotation_deg.to_radians();
        let max_r = c.max_rotation_deg.to_radians();
        for k in 0..6 {
            m[k] = BETA1 * m[k] + (1.0 - BETA1) * g[k];
            v[k] = BETA2 * v[k] + (1.0 - BETA2) * g[k] * g[k];
            let step = (m[k] / b1) / ((v[k] / b2).sqrt() + EPS);
            let (x, lr, max) = if k < 3 {
                (&mut corr.omega[k], lr_r, max_r)
            } else {
                (
                    &mut corr.tau[k - 3],
                    c.lr_translation_m,
                    c.max_translation_m,
                )
            };
            *x = ((*x - lr * step) * (1.0 - c.decay)).clamp(-max, max);
        }
    }
}
