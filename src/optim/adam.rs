//! Oracle of `shaders/adam.wgsl` and the learning rates: one Adam step of every
//! learnable surfel parameter (x, y fixed, so without moments) and of one camera's
//! exposure, applied only when every gradient is usable (shaders/guard.wgsl).

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
    /// Refuses constants that could make an update non-finite (with finite
    /// gradients below 1e18 and these, every Adam step is finite).
    pub fn check(&self) -> Result<(), String> {
        let rates = [
            ("z_start", self.z_start),
            ("z_end", self.z_end),
            ("rotation", self.rotation),
            ("scale", self.scale),
            ("opacity", self.opacity),
            ("rgb", self.rgb),
            ("logits", self.logits),
            ("exposure", self.exposure),
        ];
        for (name, v) in rates {
            let positive = name.starts_with("z_");
            if !((0.0..=1e3).contains(&v) && (!positive || v > 0.0)) {
                return Err(format!(
                    "the {name} learning rate is {v}; use a number {} and at most 1000",
                    if positive { "above 0" } else { "from 0" }
                ));
            }
        }
        for (name, v) in [("beta1", self.beta1), ("beta2", self.beta2)] {
            if !(0.0..1.0).contains(&v) {
                return Err(format!("Adam's {name} is {v}; use a number in [0, 1)"));
            }
        }
        if !(self.eps.is_finite() && self.eps > 0.0) {
            return Err(format!(
                "Adam's eps is {}; use a small positive number",
                self.eps
            ));
        }
        Ok(())
    }

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

/// Learnable slots per surfel (z, rotation 4, log-scales 2, opacity, rgb 3, logits):
/// the moments hold m and v for each, interleaved.
pub fn learnable(channels: usize) -> usize {
    11 + channels
}

fn adam(c: &StepConstants, m: &mut [f32], value: f32, g: f32, lr: f32) -> f32 {
    let mm = c.beta1 * m[0] + (1.0 - c.beta1) * g;
    let v = c.beta2 * m[1] + (1.0 - c.beta2) * g * g;
    m[0] = mm;
    m[1] = v;
    value - lr * (mm / c.bias1) / ((v / c.bias2).sqrt() + c.eps)
}

/// One camera's exposure (a, b), its gradient and its 4 moments.
pub struct Exposure<'a> {
    pub value: &'a mut [f32; 2],
    pub grad: [f32; 2],
    pub moments: &'a mut [f32; 4],
}

/// `usable` of shaders/guard.wgsl.
pub fn usable(x: f32) -> bool {
    x.is_finite() && x.abs() < 1e18
}

/// One step of every surfel parameter in `p` from gradients `g` (same layout) and of
/// the view's exposure; `moments` holds m, v interleaved per learnable slot
/// (`2 learnable(channels)` per surfel; the kernel stores them in blocks of 256
/// surfels, slot-major within a block, which changes no value). All or nothing: when any gradient is not
/// `usable`, nothing changes and the result is false.
pub fn step(
    p: &mut Params<f32>,
    g: &Params<f32>,
    moments: &mut [f32],
    e: Exposure,
    c: &StepConstants,
) -> bool {
    let grads = g.pos.iter().flatten().chain(g.rotation.iter().flatten());
    let grads = grads
        .chain(g.log_scale.iter().flatten())
        .chain(&g.opacity)
        .chain(g.rgb.iter().flatten())
        .chain(&g.logits)
        .chain(&e.grad);
    if !grads.copied().all(usable) {
        return false;
    }
    let ch = p.channels;
    let stride = 2 * learnable(ch);
    for i in 0..p.len() {
        let m = &mut moments[stride * i..stride * (i + 1)];
        p.pos[i][2] = adam(c, &mut m[0..2], p.pos[i][2], g.pos[i][2], c.lr_z);
        for k in 0..4 {
            let s = 2 * (1 + k);
            let r = &mut p.rotation[i][k];
            *r = adam(c, &mut m[s..s + 2], *r, g.rotation[i][k], c.lr_rotation);
        }
        for k in 0..2 {
            let s = 2 * (5 + k);
            let l = &mut p.log_scale[i][k];
            *l = adam(c, &mut m[s..s + 2], *l, g.log_scale[i][k], c.lr_scale);
        }
        p.opacity[i] = adam(c, &mut m[14..16], p.opacity[i], g.opacity[i], c.lr_opacity);
        for k in 0..3 {
            let s = 2 * (8 + k);
            let v = adam(c, &mut m[s..s + 2], p.rgb[i][k], g.rgb[i][k], c.lr_rgb);
            p.rgb[i][k] = v.clamp(0.0, 1.0);
        }
        for j in 0..ch {
            let s = 2 * (11 + j);
            let l = &mut p.logits[ch * i + j];
            *l = adam(c, &mut m[s..s + 2], *l, g.logits[ch * i + j], c.lr_logits);
        }
    }
    for k in 0..2 {
        let v = e.value[k];
        e.value[k] = adam(
            c,
            &mut e.moments[2 * k..2 * k + 2],
            v,
            e.grad[k],
            c.lr_exposure,
        );
    }
    true
}
