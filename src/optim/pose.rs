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
//! the host, a few numbers per frame, and are stepped there with Adam (its second
//! moment shared by every frame, so that a weak gradient moves its frame little). What keeps
//! them near the given poses: a box (`PoseConfig::max_*`), a decoupled decay toward
//! zero, and a start after part of the schedule, once the map has formed (before
//! that the gradient says more about the map than about the poses).

use crate::bundle::transform::{apply, exp_so3, mat, mul};
use crate::bundle::{Manifest, Mat4Rows};
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
    /// Only x, y and yaw move (what the LiDAR alignment cannot see); else all six.
    pub planar: bool,
    /// Also learn one correction per camera of its mounting on the vehicle (the
    /// rig's extrinsics), shared by every frame, all six degrees of freedom.
    pub rig: bool,
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self {
            lr_translation_m: 0.02,
            lr_rotation_deg: 0.2,
            max_translation_m: 0.5,
            max_rotation_deg: 3.0,
            decay: 0.0,
            start: 0.1,
            planar: false,
            rig: false,
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

    /// The correction of a camera's mounting (`self` in the vehicle's frame, about
    /// its origin) as a correction in the world about the vehicle's position, for
    /// the vehicle pose `v2w`: V δ V⁻¹.
    pub fn rig_in_world(&self, v2w: &Mat4Rows) -> Correction {
        let r = |v: [f64; 3]| [0, 1, 2].map(|i| (0..3).map(|k| v2w[i][k] * v[k]).sum::<f64>());
        Correction {
            omega: r(self.omega),
            tau: r(self.tau),
        }
    }

    /// The corrected camera-to-vehicle transform of a camera mounted at `c2v`:
    /// δ ∘ c2v (`self` in the vehicle's frame).
    pub fn apply_to_mount(&self, c2v: &Mat4Rows) -> Mat4Rows {
        mul(&mat(exp_so3(self.omega), self.tau), c2v)
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
    /// Adam's first moment per frame.
    moments: Vec<[f64; 6]>,
    /// Its second moment, one per axis for every frame together (and the updates
    /// it has seen): a frame's step is its gradient against the typical gradient of
    /// all frames, so a view that says little moves its frame little.
    scale: [f64; 6],
    scale_updates: u32,
    updates: Vec<u32>,
    /// With `cfg.rig`: per camera, the correction of its mounting (vehicle frame),
    /// Adam's moments and the updates it has had.
    pub rig: Vec<Correction>,
    rig_adam: Vec<([f64; 6], [f64; 6])>,
    rig_updates: Vec<u32>,
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-12;

impl PoseRefiner {
    pub fn new(frames: usize, cameras: usize, cfg: PoseConfig) -> Self {
        let cameras = if cfg.rig { cameras } else { 0 };
        Self {
            cfg,
            corrections: vec![Correction::default(); frames],
            moments: vec![[0.0; 6]; frames],
            scale: [0.0; 6],
            scale_updates: 0,
            updates: vec![0; frames],
            rig: vec![Correction::default(); cameras],
            rig_adam: vec![([0.0; 6], [0.0; 6]); cameras],
            rig_updates: vec![0; cameras],
        }
    }

    /// The correction of a view of `camera` in `frame` (vehicle pose `v2w`), in the
    /// world about the vehicle's position: the frame's after its camera's mounting.
    pub fn view(&self, frame: usize, camera: usize, v2w: &Mat4Rows) -> [Correction; 2] {
        let rig = self.rig.get(camera).copied().unwrap_or_default();
        [rig.rig_in_world(v2w), self.correction(frame)]
    }

    /// One Adam step of `camera`'s mounting with a view's gradient dL/d(ω, τ) in the
    /// world (about the vehicle of pose `v2w`), turned into the vehicle's frame. Its
    /// own moments (a camera has many views), the frames' rates and box.
    pub fn update_rig(&mut self, camera: usize, g: [f64; 6], v2w: &Mat4Rows, progress: f64) {
        if camera >= self.rig.len() || g.iter().any(|v| !v.is_finite()) {
            return;
        }
        // Rᵀ g for the rotation and the translation parts.
        let rt = |v: [f64; 3]| [0, 1, 2].map(|i| (0..3).map(|k| v2w[k][i] * v[k]).sum::<f64>());
        let (gw, gt) = (rt([g[0], g[1], g[2]]), rt([g[3], g[4], g[5]]));
        let gv = [gw[0], gw[1], gw[2], gt[0], gt[1], gt[2]];
        let t = self.rig_updates[camera] + 1;
        self.rig_updates[camera] = t;
        let (m, v) = &mut self.rig_adam[camera];
        let bias = (1.0 - BETA1.powi(t as i32), 1.0 - BETA2.powi(t as i32));
        adam_step(
            &self.cfg,
            &mut self.rig[camera],
            m,
            v,
            gv,
            bias,
            progress,
            0.0,
        );
    }

    /// The correction of `frame` (zero for a frame it does not know).
    pub fn correction(&self, frame: usize) -> Correction {
        self.corrections.get(frame).copied().unwrap_or_default()
    }

    /// Updates of `frame` so far.
    pub fn updates(&self, frame: usize) -> u32 {
        self.updates.get(frame).copied().unwrap_or(0)
    }

    /// One Adam step of `frame`'s correction with the gradient dL/d(ω, τ), at
    /// `progress` (0 to 1) of the refining steps: the rates fall linearly to a tenth
    /// by the end, so that the corrections settle instead of wandering by a rate's
    /// worth each step. A gradient that is not finite is ignored.
    pub fn update(&mut self, frame: usize, g: [f64; 6], progress: f64) {
        if frame >= self.corrections.len() || g.iter().any(|v| !v.is_finite()) {
            return;
        }
        let t = self.updates[frame] + 1;
        self.updates[frame] = t;
        self.scale_updates += 1;
        let bias = (
            1.0 - BETA1.powi(t as i32),
            1.0 - BETA2.powi(self.scale_updates as i32),
        );
        let decay = self.cfg.decay;
        let (m, v) = (&mut self.moments[frame], &mut self.scale);
        adam_step(
            &self.cfg,
            &mut self.corrections[frame],
            m,
            v,
            g,
            bias,
            progress,
            decay,
        );
    }
}

/// One Adam step of correction `corr` with gradient `g` (moments `m`, `v`, their
/// bias corrections `bias`), at `progress` (0 to 1) of the refining steps: the rates
/// fall linearly to a tenth by the end; `decay` pulls toward zero; the box holds.
/// Roll, pitch and height (ω x, ω y, τ z) stay when `planar`.
#[allow(clippy::too_many_arguments)]
fn adam_step(
    c: &PoseConfig,
    corr: &mut Correction,
    m: &mut [f64; 6],
    v: &mut [f64; 6],
    g: [f64; 6],
    bias: (f64, f64),
    progress: f64,
    decay: f64,
) {
    let fall = 1.0 - 0.9 * progress.clamp(0.0, 1.0);
    for k in 0..6 {
        if c.planar && matches!(k, 0 | 1 | 5) {
            continue;
        }
        m[k] = BETA1 * m[k] + (1.0 - BETA1) * g[k];
        v[k] = BETA2 * v[k] + (1.0 - BETA2) * g[k] * g[k];
        let step = (m[k] / bias.0) / ((v[k] / bias.1).sqrt() + EPS);
        let (x, lr, max) = if k < 3 {
            (
                &mut corr.omega[k],
                fall * c.lr_rotation_deg.to_radians(),
                c.max_rotation_deg.to_radians(),
            )
        } else {
            (
                &mut corr.tau[k - 3],
                fall * c.lr_translation_m,
                c.max_translation_m,
            )
        };
        *x = ((*x - lr * step) * (1.0 - decay)).clamp(-max, max);
    }
}

/// Translation (m) and rotation (degrees) of `a` relative to `b`, the horizontal
/// part (x, y in m; yaw in degrees) that the LiDAR alignment cannot see, and what the
/// map sees of it: the RMS distance (m) between where the two poses put the ground
/// 5 to 15 m ahead of the vehicle and up to 3 m to either side (yaw and a sideways
/// shift can cancel there, or add up).
pub fn pose_error(a: &Mat4Rows, b: &Mat4Rows) -> [f64; 5] {
    let d = [0, 1, 2].map(|k| a[k][3] - b[k][3]);
    // R_a R_bᵀ: its angle, and its yaw (rotation about z).
    let r = |i: usize, j: usize| (0..3).map(|k| a[i][k] * b[j][k]).sum::<f64>();
    let tr = r(0, 0) + r(1, 1) + r(2, 2);
    let angle = ((tr - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
    let yaw = (r(1, 0) - r(0, 1)).atan2(r(0, 0) + r(1, 1)).to_degrees();
    let ground = rms([5.0, 10.0, 15.0].into_iter().flat_map(|x| {
        [-3.0, 0.0, 3.0].map(|y| {
            let p = [x, y, 0.0];
            let (pa, pb) = (apply(a, p), apply(b, p));
            (0..3).map(|k| (pa[k] - pb[k]).powi(2)).sum::<f64>().sqrt()
        })
    }));
    [
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(),
        angle,
        d[0].hypot(d[1]),
        yaw.abs(),
        ground,
    ]
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 {
        0.0
    } else {
        (s / n as f64).sqrt()
    }
}

impl PoseRefiner {
    /// Every frame's corrected vehicle pose (`poses` as the run used them).
    pub fn corrected(&self, poses: &[Mat4Rows]) -> Vec<Mat4Rows> {
        poses
            .iter()
            .enumerate()
            .map(|(k, p)| self.correction(k).apply_to_pose(p))
            .collect()
    }

    /// report.json's `pose_refinement`: the corrections' size over the frames that
    /// were updated, and with the exact poses (`truth`), the poses' error before
    /// (as the run was given them in `m`, after any LiDAR alignment) and after, RMS.
    pub fn summary(&self, m: &Manifest, truth: Option<&[Mat4Rows]>) -> serde_json::Value {
        let poses = &m.vehicle_poses();
        let frames: Vec<usize> = (0..poses.len()).filter(|&k| self.updates(k) > 0).collect();
        let mag = |k: &usize| self.correction(*k).magnitude();
        let mut r = serde_json::json!({
            "settings": self.cfg,
            "frames_refined": frames.len(),
            "updates_per_frame": if frames.is_empty() { 0.0 } else {
                frames.iter().map(|&k| self.updates(k) as f64).sum::<f64>() / frames.len() as f64
            },
            "correction_rms_m": rms(frames.iter().map(|k| mag(k).0)),
            "correction_rms_deg": rms(frames.iter().map(|k| mag(k).1)),
        });
        if !self.rig.is_empty() {
            r["rig"] = self.rig_file(m);
        }
        if let Some(t) = truth.filter(|t| t.len() == poses.len()) {
            let after = self.corrected(poses);
            let err = |set: &[Mat4Rows], i: usize| {
                rms(frames.iter().map(|&k| pose_error(&set[k], &t[k])[i]))
            };
            // The horizontal error less its mean over the frames: a shift shared by
            // every frame moves the map with it and no image can tell it.
            let mean = |set: &[Mat4Rows]| {
                let n = frames.len().max(1) as f64;
                frames.iter().fold([0.0; 2], |a, &k| {
                    [
                        a[0] + (set[k][0][3] - t[k][0][3]) / n,
                        a[1] + (set[k][1][3] - t[k][1][3]) / n,
                    ]
                })
            };
            let centred = |set: &[Mat4Rows]| {
                let m = mean(set);
                rms(frames.iter().map(|&k| {
                    (set[k][0][3] - t[k][0][3] - m[0]).hypot(set[k][1][3] - t[k][1][3] - m[1])
                }))
            };
            let keys = [
                "translation_m",
                "rotation_deg",
                "xy_m",
                "yaw_deg",
                "ground_m",
            ];
            let mut before = serde_json::Map::new();
            let mut now = serde_json::Map::new();
            for (i, k) in keys.iter().enumerate() {
                before.insert((*k).into(), err(poses, i).into());
                now.insert((*k).into(), err(&after, i).into());
            }
            before.insert("xy_centred_m".into(), centred(poses).into());
            now.insert("xy_centred_m".into(), centred(&after).into());
            r["error_before"] = before.into();
            r["error_after"] = now.into();
        }
        r
    }

    /// poses_refined.json: every frame's corrected `vehicle_to_world` (of `m`, as
    /// the run was given them) and its correction (degrees about the world axes at
    /// the vehicle, metres).
    pub fn file(&self, m: &Manifest) -> serde_json::Value {
        let frames: Vec<serde_json::Value> = self
            .corrected(&m.vehicle_poses())
            .iter()
            .enumerate()
            .map(|(k, p)| {
                let c = self.correction(k);
                serde_json::json!({
                    "frame": k,
                    "vehicle_to_world": p,
                    "rotation_deg": c.omega.map(f64::to_degrees),
                    "translation_m": c.tau,
                    "updates": self.updates(k),
                })
            })
            .collect();
        let mut out = serde_json::json!({ "frames": frames });
        if !self.rig.is_empty() {
            out["cameras"] = self.rig_file(m);
        }
        out
    }

    /// Each camera's corrected `camera_to_vehicle` and its correction (degrees about
    /// the vehicle's axes, metres), with the updates it had.
    fn rig_file(&self, m: &Manifest) -> serde_json::Value {
        m.cameras
            .iter()
            .zip(&self.rig)
            .zip(&self.rig_updates)
            .map(|((cam, c), n)| {
                serde_json::json!({
                    "camera": cam.name,
                    "camera_to_vehicle": c.apply_to_mount(&cam.camera_to_vehicle),
                    "rotation_deg": c.omega.map(f64::to_degrees),
                    "translation_m": c.tau,
                    "updates": n,
                })
            })
            .collect::<Vec<_>>()
            .into()
    }
}
