//! Oracle of `shaders/adam.wgsl` and the learning rates: one Adam step of the
//! learnable surfel parameters (x, y fixed, so without moments) of every surfel
//! (dense) or of the view's candidates alone (selective, with lazy moment decay), and
//! of one camera's exposure, applied only when every gradient is usable
//! (shaders/guard.wgsl).

use crate::render::Params;
use serde::Serialize;

/// Per-group learning rates and Adam's constants. All are the paper's except z: a
/// ratio of the scene extent decaying exponentially from `z_start` to `z_end` over
/// the run, 10× the paper's 1.6e-4 → 1.6e-6. The paper's schedule runs over thousands
/// of steps per epoch; a small bundle has ~100, and at the paper's rate the surfels
/// can move only ~4 cm in total (measured on `demo`: elevation RMSE 4.4 cm at the
/// paper's rate, 1.2 cm at this one; docs/QUALITY.md). Colour: the paper's 8e-3, but
/// `rgb_on_lidar` (a quarter of it) when the colours start from the best view's pixels
/// on the LiDAR surface, where larger steps only add noise (`demo`: 27.67 dB at 2e-3,
/// 27.44 at 4e-3, 26.57 at 8e-3), while a start on the pose plane needs the larger
/// steps (KITTI, no LiDAR: held-out 22.53 dB at 8e-3, 21.91 at 2e-3; docs/QUALITY.md).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LearningRates {
    pub z_start: f32,
    pub z_end: f32,
    pub rotation: f32,
    pub scale: f32,
    pub opacity: f32,
    pub rgb: f32,
    /// The colour rate when training starts from colours on the LiDAR surface
    /// (`TrainConfig::lidar_colours`).
    pub rgb_on_lidar: f32,
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
            rgb_on_lidar: 2e-3,
            logits: 0.1,
            exposure: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

impl LearningRates {
    /// The rates a front end may set by name, and where each lives.
    fn named(&mut self) -> [(&'static str, &mut f32); 9] {
        [
            ("z_start", &mut self.z_start),
            ("z_end", &mut self.z_end),
            ("rotation", &mut self.rotation),
            ("scale", &mut self.scale),
            ("opacity", &mut self.opacity),
            ("rgb", &mut self.rgb),
            ("rgb_on_lidar", &mut self.rgb_on_lidar),
            ("logits", &mut self.logits),
            ("exposure", &mut self.exposure),
        ]
    }

    /// Sets the rate called `name` (`check` then judges the value).
    pub fn set(&mut self, name: &str, v: f32) -> Result<(), String> {
        let mut rates = self.named();
        let known: Vec<&str> = rates.iter().map(|r| r.0).collect();
        let known = known.join(", ");
        match rates.iter_mut().find(|r| r.0 == name) {
            Some(r) => {
                *r.1 = v;
                Ok(())
            }
            None => Err(format!(
                "no learning rate is called {name:?}; the rates are {known}"
            )),
        }
    }

    /// Refuses constants that could make an update non-finite (with finite
    /// gradients below 1e18 and these, every Adam step is finite).
    pub fn check(&self) -> Result<(), String> {
        let mut copy = self.clone();
        for (name, v) in copy.named().map(|(n, v)| (n, *v)) {
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
    /// t, the step (from 1): a surfel last stepped at step s < t − 1 missed
    /// t − 1 − s steps, and its moments decay by β1 and β2 to that power first.
    pub t: u32,
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
            t,
        }
    }
}

/// Learnable slots per surfel (z, rotation 4, log-scales 2, opacity, rgb 3, logits):
/// the moments hold m and v for each, interleaved.
pub fn learnable(channels: usize) -> usize {
    11 + channels
}

/// What a surfel that missed k steps (selective Adam) catches up before its step: k
/// steps of zero gradient decay its moments by β1ᵏ and β2ᵏ and would have moved it
/// by Σⱼ₌₁..ₖ rʲ (r = β1/√β2) times its last normalised moment, with this step's
/// learning rate and bias corrections (shaders/adam.wgsl, `missed`).
#[derive(Clone, Copy, Debug)]
pub struct Missed {
    pub decay1: f32,
    pub decay2: f32,
    pub drift: f32,
}

impl Missed {
    pub const NONE: Self = Self {
        decay1: 1.0,
        decay2: 1.0,
        drift: 0.0,
    };

    pub fn of(c: &StepConstants, k: u32) -> Self {
        if k == 0 {
            return Self::NONE;
        }
        let k = k as f32;
        let r = c.beta1 / c.beta2.sqrt();
        Self {
            decay1: c.beta1.powf(k),
            decay2: c.beta2.powf(k),
            drift: r * (1.0 - r.powf(k)) / (1.0 - r),
        }
    }
}

fn adam(c: &StepConstants, m: &mut [f32], value: f32, g: f32, lr: f32, k: Missed) -> f32 {
    let (m0, v0) = (m[0], m[1]);
    let value = value - lr * k.drift * (m0 / c.bias1) / ((v0 / c.bias2).sqrt() + c.eps);
    let mm = c.beta1 * (k.decay1 * m0) + (1.0 - c.beta1) * g;
    let v = c.beta2 * (k.decay2 * v0) + (1.0 - c.beta2) * g * g;
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

/// Which surfels a step updates.
#[derive(Clone, Copy, Debug)]
pub enum Touched<'a> {
    /// Every surfel, every step (dense Adam): a surfel out of view moves by its
    /// regularisers' gradient and its momentum.
    All,
    /// These surfels (increasing; the view's candidates) and no other (selective
    /// Adam): the rest keep their values and moments until a view lists them again.
    Only(&'a [u32]),
}

/// One step of the surfel parameters in `p` that `touched` names, from gradients `g`
/// (same layout), and of the view's exposure. `moments` holds m, v interleaved per
/// learnable slot (`2 learnable(channels)` per surfel; the kernel stores them in
/// blocks of 256 surfels, slot-major within a block, which changes no value); `last`
/// the step (from 1, 0: never) at which each surfel was last stepped. A surfel that
/// missed k steps first catches up what k steps of zero gradient would have done
/// (`Missed`); under `All` k is 0. All
/// or nothing: when any gradient is not `usable`, nothing changes and the result is
/// false.
pub fn step(
    p: &mut Params<f32>,
    g: &Params<f32>,
    moments: &mut [f32],
    last: &mut [u32],
    touched: Touched,
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
    let all: Vec<u32>;
    let surfels = match touched {
        Touched::All => {
            all = (0..p.len() as u32).collect();
            &all[..]
        }
        Touched::Only(s) => s,
    };
    for &i in surfels {
        let i = i as usize;
        let m = &mut moments[stride * i..stride * (i + 1)];
        let k = Missed::of(c, c.t.saturating_sub(1).saturating_sub(last[i]));
        last[i] = c.t;
        p.pos[i][2] = adam(c, &mut m[0..2], p.pos[i][2], g.pos[i][2], c.lr_z, k);
        for q in 0..4 {
            let s = 2 * (1 + q);
            let r = &mut p.rotation[i][q];
            *r = adam(c, &mut m[s..s + 2], *r, g.rotation[i][q], c.lr_rotation, k);
        }
        for q in 0..2 {
            let s = 2 * (5 + q);
            let l = &mut p.log_scale[i][q];
            *l = adam(c, &mut m[s..s + 2], *l, g.log_scale[i][q], c.lr_scale, k);
        }
        p.opacity[i] = adam(
            c,
            &mut m[14..16],
            p.opacity[i],
            g.opacity[i],
            c.lr_opacity,
            k,
        );
        for q in 0..3 {
            let s = 2 * (8 + q);
            let v = adam(c, &mut m[s..s + 2], p.rgb[i][q], g.rgb[i][q], c.lr_rgb, k);
            p.rgb[i][q] = v.clamp(0.0, 1.0);
        }
        for j in 0..ch {
            let s = 2 * (11 + j);
            let l = &mut p.logits[ch * i + j];
            *l = adam(
                c,
                &mut m[s..s + 2],
                *l,
                g.logits[ch * i + j],
                c.lr_logits,
                k,
            );
        }
    }
    for q in 0..2 {
        let v = e.value[q];
        e.value[q] = adam(
            c,
            &mut e.moments[2 * q..2 * q + 2],
            v,
            e.grad[q],
            c.lr_exposure,
            Missed::NONE,
        );
    }
    true
}
