//! The procedural road: a centreline of straights and arcs, and in road coordinates
//! (s along the centreline, t to the left of it) the true surface height and the
//! material (albedo and class) of every point. Everything is closed-form in (s, t);
//! `field.rs` maps world xy to (s, t).

use super::classes::*;
use super::rng::{fbm, value_noise};

/// Half width of the carriageway (two 3.5 m lanes), metres.
pub const HALF_WIDTH: f64 = 3.5;
pub const CURB_WIDTH: f64 = 0.15;
pub const SIDEWALK_WIDTH: f64 = 2.5;
/// |t| beyond which road coordinates are clamped (terrain continues flat-ish).
pub const T_MAX: f64 = 16.0;

/// Piece of centreline: length (m) and curvature (1/m, positive turns left).
pub type Piece = (f64, f64);

#[derive(Clone, Debug)]
pub struct RoadSpec {
    pub seed: u64,
    pub pieces: Vec<Piece>,
    /// Longitudinal grade (rise over run).
    pub slope: f64,
    /// Cross-fall of the carriageway from the crown (rise over run).
    pub crossfall: f64,
    /// Amplitude of a gentle vertical curve (90 m period) on top of the grade, metres.
    pub vertical_curve_m: f64,
    /// Curb height step, metres.
    pub curb_height: f64,
    /// Speed table: start s, height; 1 m ramps around a 2 m plateau.
    pub bump: Option<(f64, f64)>,
    /// Start s of the crosswalk (3 m deep); a stop line 2 m before it.
    pub crosswalk: Option<f64>,
    pub manhole: Option<(f64, f64)>,
}

impl RoadSpec {
    pub fn length(&self) -> f64 {
        self.pieces.iter().map(|p| p.0).sum()
    }

    /// Height of the road crown (t = 0) along s, without the speed table.
    fn base(&self, s: f64) -> f64 {
        // A gentle vertical curve on top of the grade.
        self.slope * s + self.vertical_curve_m * (1.0 - (s * std::f64::consts::TAU / 90.0).cos())
    }

    fn bump_at(&self, s: f64) -> f64 {
        let Some((s0, h)) = self.bump else { return 0.0 };
        let d = s - s0;
        let ramp = |x: f64| x.clamp(0.0, 1.0);
        h * ramp(d).min(ramp(4.0 - d))
    }

    /// True surface height at road coordinates (s, t).
    pub fn height(&self, s: f64, t: f64) -> f64 {
        let a = t.abs().min(T_MAX);
        if a <= HALF_WIDTH {
            return self.base(s) + self.bump_at(s) * (1.0 - (a / HALF_WIDTH).powi(8))
                - self.crossfall * a;
        }
        let edge = self.base(s) - self.crossfall * HALF_WIDTH + self.curb_height;
        let walk = HALF_WIDTH + CURB_WIDTH + SIDEWALK_WIDTH;
        if a <= walk {
            edge + 0.01 * (a - HALF_WIDTH)
        } else {
            edge + 0.01 * (walk - HALF_WIDTH) + 0.04 * (a - walk)
        }
    }

    /// Albedo (linear RGB, 0..1) and class at road coordinates (s, t).
    pub fn material(&self, s: f64, t: f64) -> ([f64; 3], u8) {
        let a = t.abs();
        let seed = self.seed;
        if a > HALF_WIDTH + CURB_WIDTH + SIDEWALK_WIDTH {
            let n = fbm(seed ^ 7, s * 0.7, t * 0.7, 4);
            let g = 0.6 + 0.8 * n;
            return ([0.22 * g, 0.32 * g, 0.12 * g], TERRAIN);
        }
        if a > HALF_WIDTH + CURB_WIDTH {
            // Paving slabs 0.4 m with darker joints.
            let (u, v) = ((s / 0.4).rem_euclid(1.0), (a / 0.4).rem_euclid(1.0));
            let joint = u < 0.06 || v < 0.06;
            let n = 0.9 + 0.2 * value_noise(seed ^ 11, s * 2.5, t * 2.5);
            let k = if joint { 0.55 } else { n };
            return ([0.62 * k, 0.52 * k, 0.47 * k], SIDEWALK);
        }
        if a > HALF_WIDTH {
            let k = 0.95 + 0.1 * value_noise(seed ^ 13, s * 4.0, t * 4.0);
            return ([0.68 * k, 0.68 * k, 0.66 * k], CURB);
        }
        if let Some((ms, mt)) = self.manhole {
            let r = ((s - ms).powi(2) + (t - mt).powi(2)).sqrt();
            if r < 0.35 {
                let ring = if (0.28..0.31).contains(&r) || ((s - ms) * 12.0).rem_euclid(1.0) < 0.2 {
                    0.08
                } else {
                    0.16
                };
                return ([ring, ring, ring * 1.1], MANHOLE);
            }
        }
        const WHITE: [f64; 3] = [0.86, 0.86, 0.84];
        if let Some(cw) = self.crosswalk {
            if (cw..cw + 3.0).contains(&s)
                && a < HALF_WIDTH - 0.4
                && (t + HALF_WIDTH).rem_euclid(1.0) < 0.5
            {
                return (WHITE, CROSSWALK);
            }
            if (cw - 2.4..cw - 2.0).contains(&s) && (-HALF_WIDTH + 0.4..0.0).contains(&t) {
                return (WHITE, LANE_MARKING);
            }
        }
        let centre_dash = a < 0.075 && s.rem_euclid(9.0) < 3.0;
        let edge_line = (HALF_WIDTH - 0.35..HALF_WIDTH - 0.2).contains(&a);
        if centre_dash || edge_line {
            return (WHITE, LANE_MARKING);
        }
        (self.asphalt(s, t), ROAD)
    }

    /// Asphalt with grain, cracks and patches: detail the optimiser must reconstruct.
    fn asphalt(&self, s: f64, t: f64) -> [f64; 3] {
        let seed = self.seed;
        let mut g = 0.30
            + 0.12 * (fbm(seed, s * 1.5, t * 1.5, 4) - 0.5)
            + 0.06 * (value_noise(seed ^ 3, s * 25.0, t * 25.0) - 0.5);
        // Patches: a repair every ~14 m, darker and smoother.
        let cell = (s / 14.0).floor();
        let ps = cell * 14.0 + 3.0 + 6.0 * value_noise(seed ^ 5, cell, 0.5);
        let pt = -2.5 + 4.0 * value_noise(seed ^ 6, cell, 1.5);
        if (ps..ps + 2.2).contains(&s) && (pt..pt + 1.3).contains(&t) {
            g = 0.21 + 0.02 * value_noise(seed ^ 9, s * 6.0, t * 6.0);
        }
        // Cracks: thin iso-lines of a low-frequency noise.
        if (fbm(seed ^ 17, s * 0.35, t * 0.35, 3) - 0.5).abs() < 0.004 {
            g *= 0.45;
        }
        [g * 0.97, g, g * 1.04]
    }
}

/// A centreline sampled every `STEP` metres by exact arc integration.
pub struct Centreline {
    /// (x, y, heading) per sample.
    pub pts: Vec<[f64; 3]>,
}

impl Centreline {
    pub const STEP: f64 = 0.25;

    pub fn new(pieces: &[Piece]) -> Self {
        let (mut x, mut y, mut h) = (0.0f64, 0.0f64, 0.0f64);
        let mut pts = vec![[x, y, h]];
        for &(len, k) in pieces {
            let n = (len / Self::STEP).round().max(1.0) as usize;
            let ds = len / n as f64;
            for _ in 0..n {
                if k.abs() < 1e-12 {
                    x += ds * h.cos();
                    y += ds * h.sin();
                } else {
                    x += ((h + k * ds).sin() - h.sin()) / k;
                    y -= ((h + k * ds).cos() - h.cos()) / k;
                }
                h += k * ds;
                pts.push([x, y, h]);
            }
        }
        Self { pts }
    }

    pub fn length(&self) -> f64 {
        (self.pts.len() - 1) as f64 * Self::STEP
    }

    /// World point and heading at (s, t), linear between samples.
    pub fn point(&self, s: f64, t: f64) -> (f64, f64, f64) {
        let f = (s / Self::STEP).clamp(0.0, (self.pts.len() - 1) as f64);
        let i = (f.floor() as usize).min(self.pts.len() - 2);
        let w = f - i as f64;
        let (a, b) = (self.pts[i], self.pts[i + 1]);
        let (x, y) = (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]));
        let h = (b[1] - a[1]).atan2(b[0] - a[0]);
        (x - t * h.sin(), y + t * h.cos(), h)
    }

    /// Road coordinates of world (x, y), searching the segments `lo..hi`.
    pub fn project(&self, x: f64, y: f64, lo: usize, hi: usize) -> (f64, f64, f64) {
        let mut best = (f64::INFINITY, 0.0, 0.0);
        for i in lo..hi.min(self.pts.len() - 1) {
            let (a, b) = (self.pts[i], self.pts[i + 1]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len2 = dx * dx + dy * dy;
            let w = (((x - a[0]) * dx + (y - a[1]) * dy) / len2).clamp(0.0, 1.0);
            let (px, py) = (a[0] + w * dx, a[1] + w * dy);
            let d2 = (x - px).powi(2) + (y - py).powi(2);
            if d2 < best.0 {
                let side = dx * (y - a[1]) - dy * (x - a[0]);
                let t = d2.sqrt().copysign(side);
                best = (d2, (i as f64 + w) * Self::STEP, t);
            }
        }
        best
    }
}
