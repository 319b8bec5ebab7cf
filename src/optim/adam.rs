//! Oracle of `shaders/adam.wgsl` and the learning rates: one Adam step of every
//! learnable surfel parameter (x, y fixed) and of one camera's exposure.

use crate::render::Params;
use serde::Serialize;

/// Per-group learning rates and Adam's constants. All are the paper's except z: a
/// ratio of the scene extent decaying exponentially from `z_start` to `z_end` over
/// the run, 10× the paper's 1.6e-4 → 1.6e-6. The paper's schedule runs over thousands
/// of steps per epoch; a small bundle has ~100, and at the paper's rate the surfels
/// can move only ~4 cm in total (measured on `demo`: elevation RMSE 4.4 cm at the
/// paper's rate, 1.2 cm at this one; docs/QUALITY.md).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LearningRates {
    pub z_start: f32,
    pub z_end: f32,
    pub rotation: f32,
    pub scale: f32,
    pub opacity: f32,
    pub rgb: f32,
    pub logits: f32,
    pub exposure: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl Default for LearningRates {
    fn default() -> Self {
        Self {
            z_start: 1.6e-3,
            z_end: 1.6e-5,
            rotation: 1e-4,
            scale: 1e-4,
            opacity: 1e-4,
            rgb: 8e-3,
            logits: 0.1,
            exposure: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

impl LearningRates {
    /// The z learning rate (metres) at `step` of `steps`, for a scene of `extent` m.
    pub fn z_at(&self, step: usize, steps: usize, extent: f32) -> f32 {
        let t = if steps > 1 {
            step as f32 / (steps - 1) as f32
        } else {
            0.0
        };
        extent * (self.z_start.ln() * (1.0 - t) + self.z_end.ln() * t).exp()
    }
}

/// The constants of one step (what the kernel's uniform carries).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepConstants {
    pub lr_z: f32,
    pub lr_rotation: f32,
    pub lr_scale: f32,
    pub lr_opacity: f32,
    pub lr_rgb: f32,
    pub lr_logits: f32,
    pub lr_exposure: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// 1 − β1ᵗ and 1 − β2ᵗ for step t (from 1).
    pub bias1: f32,
    pub bias2: f32,
}

impl StepConstants {
    pub fn new(lr: &LearningRates, lr_z: f32, t: u32) -> Self {
        Self {
            lr_z,
            lr_rotation: lr.rotation,
            lr_scale: lr.scale,
            lr_opacity: lr.opacity,
            lr_rgb: lr.rgb,
            lr_logits: lr.logits,
            lr_exposure: lr.exposure,
            beta1: lr.beta1,
            beta2: lr.beta2,
            eps: lr.eps,
            bias1: 1.0 - lr.beta1.powi(t as i32),
            bias2: 1.0 - lr.beta2.powi(t as i32),
        }
    }
}

fn adam(c: &StepConstants, m: &mut [f32], g: f32, lr: f32) -> f32 {
    let mm = c.beta1 * m[0] + (1.0 - c.beta1) * g;
    let v = c.beta2 * m[1] + (1.0 - c.beta2) * g * g;
    m[0] = mm;
    m[1] = v;
    -lr * (mm / c.bias1) / ((v / c.bias2).sqrt() + c.eps)
}

/// One step of every surfel parameter in `p` from gradients `g` (same layout);
/// `moments` holds m, v interleaved per packed slot (`2 (13 + channels)` per surfel).
pub fn step(p: &mut Params<f32>, g: &Params<f32>, moments: &mut [f32], c: &StepConstants) {
    let ch = p.channels;
    let stride = 13 + ch;
    for i in 0..p.len() {
        let m = &mut moments[2 * stride * i..2 * stride * (i + 1)];
        p.pos[i][2] += adam(c, &mut m[4..6], g.pos[i][2], c.lr_z);
        for k in 0..4 {
            let s = 2 * (3 + k);
            p.rotation[i][k] += adam(c, &mut m[s..s + 2], g.rotation[i][k], c.lr_rotation);
        }
        for k in 0..2 {
            let s = 2 * (7 + k);
            p.log_scale[i][k] += adam(c, &mut m[s..s + 2], g.log_scale[i][k], c.lr_scale);
        }
        p.opacity[i] += adam(c, &mut m[18..20], g.opacity[i], c.lr_opacity);
        for k in 0..3 {
            let s = 2 * (10 + k);
            let v = p.rgb[i][k] + adam(c, &mut m[s..s + 2], g.rgb[i][k], c.lr_rgb);
            p.rgb[i][k] = v.clamp(0.0, 1.0);
        }
        for q in 0..ch {
            let s = 2 * (13 + q);
            p.logits[ch * i + q] += adam(c, &mut m[s..s + 2], g.logits[ch * i + q], c.lr_logits);
        }
    }
}

/// One step of a camera's exposure (a, b); `m` holds its 4 moments.
pub fn step_exposure(e: &mut [f32; 2], g: [f32; 2], m: &mut [f32; 4], c: &StepConstants) {
    for k in 0..2 {
        e[k] += adam(c, &mut m[2 * k..2 * k + 2], g[k], c.lr_exposure);
    }
}
