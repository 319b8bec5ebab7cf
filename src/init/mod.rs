//! Stage 3: surfel elevation and orientation from the vehicle poses.
//!
//! Each pose j defines a road plane through its ground contact point with normal n_j
//! (the pose's z axis) and predicts a surfel's height as
//! `z_ij = z_j − (n_x (x_i − x_j) + n_y (y_i − y_j)) / n_z`. The *consensus* over the
//! K nearest poses, weighted by `exp(−d²/2σ_d²)`, gives ẑ, its weighted variance σ_z²
//! and the confidence `q = exp(−σ_z²/τ_z²)`; the *nearest* method (the paper's
//! baseline) takes the nearest pose's prediction alone. Pose neighbours come from a
//! grid hash, never from all pairs.

pub mod align;
pub mod ipm;
pub mod prepare;
pub mod refine;

use crate::bundle::Manifest;
use crate::grid::Grid;
use crate::spatial::PointGrid;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InitMethod {
    Nearest,
    Consensus,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RotationSource {
    Nearest,
    WeightedMean,
}

#[derive(Clone, Debug, PartialEq)]
pub struct InitConfig {
    pub method: InitMethod,
    pub rotation: RotationSource,
    /// Neighbouring poses per surfel.
    pub k: usize,
    /// Spatial influence of a pose, metres.
    pub sigma_d: f64,
    /// Height inconsistency scale of the confidence q, metres.
    pub tau_z: f64,
}

impl Default for InitConfig {
    fn default() -> Self {
        Self {
            method: InitMethod::Consensus,
            rotation: RotationSource::Nearest,
            k: 8,
            sigma_d: 3.0,
            tau_z: 0.05,
        }
    }
}

/// The road planes of the poses: ground contact point, unit normal, rotation.
pub struct PosePlanes {
    pub ground: Vec<[f64; 3]>,
    pub normal: Vec<[f64; 3]>,
    pub rotation: Vec<[f32; 4]>,
}

impl PosePlanes {
    pub fn from_manifest(m: &Manifest) -> Self {
        let (mut ground, mut normal, mut rotation) = (Vec::new(), Vec::new(), Vec::new());
        for f in &m.frames {
            let t = &f.vehicle_to_world;
            let n = [t[0][2], t[1][2], t[2][2]];
            let h = m.vehicle_height_m;
            ground.push([t[0][3] - h * n[0], t[1][3] - h * n[1], t[2][3] - h * n[2]]);
            normal.push(n);
            rotation.push(quat_from_rows(t));
        }
        Self {
            ground,
            normal,
            rotation,
        }
    }

    /// Height predicted by pose j at (x, y).
    pub fn predict(&self, j: usize, x: f64, y: f64) -> f64 {
        let (g, n) = (self.ground[j], self.normal[j]);
        g[2] - (n[0] * (x - g[0]) + n[1] * (y - g[1])) / n[2].max(1e-3)
    }
}

/// Unit quaternion (w, x, y, z) of the rotation part of a row-major transform.
pub fn quat_from_rows(m: &[[f64; 4]; 4]) -> [f32; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [
            0.25 * s,
            (m[2][1] - m[1][2]) / s,
            (m[0][2] - m[2][0]) / s,
            (m[1][0] - m[0][1]) / s,
        ]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt() * 2.0;
        [
            (m[2][1] - m[1][2]) / s,
            0.25 * s,
            (m[0][1] + m[1][0]) / s,
            (m[0][2] + m[2][0]) / s,
        ]
    } else if m[1][1] > m[2][2] {
        let s = (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt() * 2.0;
        [
            (m[0][2] - m[2][0]) / s,
            (m[0][1] + m[1][0]) / s,
            0.25 * s,
            (m[1][2] + m[2][1]) / s,
        ]
    } else {
        let s = (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt() * 2.0;
        [
            (m[1][0] - m[0][1]) / s,
            (m[0][2] + m[2][0]) / s,
            (m[1][2] + m[2][1]) / s,
            0.25 * s,
        ]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| (v / n) as f32)
}

/// Rotation (as a quaternion) whose z axis is `n` and whose x axis is `x_hint`
/// projected onto the plane orthogonal to `n`.
fn quat_from_normal(n: [f64; 3], x_hint: [f64; 3]) -> [f32; 4] {
    let d = x_hint[0] * n[0] + x_hint[1] * n[1] + x_hint[2] * n[2];
    let mut x = [
        x_hint[0] - d * n[0],
        x_hint[1] - d * n[1],
        x_hint[2] - d * n[2],
    ];
    let l = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt().max(1e-12);
    x = x.map(|v| v / l);
    let y = [
        n[1] * x[2] - n[2] * x[1],
        n[2] * x[0] - n[0] * x[2],
        n[0] * x[1] - n[1] * x[0],
    ];
    quat_from_rows(&[
        [x[0], y[0], n[0], 0.0],
        [x[1], y[1], n[1], 0.0],
        [x[2], y[2], n[2], 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ])
}

/// The prior at one point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prior {
    /// Initial elevation (consensus or nearest, per the config).
    pub z: f64,
    /// Pose-consensus elevation and its weighted variance and confidence.
    pub z_hat: f64,
    pub var: f64,
    pub q: f64,
    pub rotation: [f32; 4],
}

/// Poses indexed for neighbour queries.
pub struct PoseIndex<'a> {
    pub planes: &'a PosePlanes,
    grid: PointGrid<'a>,
}

impl<'a> PoseIndex<'a> {
    pub fn new(planes: &'a PosePlanes) -> Self {
        Self {
            planes,
            grid: PointGrid::new(&planes.ground, 2.0),
        }
    }

    /// The k nearest poses to (x, y) as (distance, index).
    pub fn nearest(&self, x: f64, y: f64, k: usize) -> Vec<(f64, usize)> {
        self.grid.knn(x, y, k)
    }

    pub fn prior(&self, x: f64, y: f64, cfg: &InitConfig) -> Prior {
        let nb = self.grid.knn(x, y, cfg.k.max(1));
        self.prior_from(&nb, x, y, cfg)
    }

    /// The prior using the `cfg.k` nearest of `candidates` (pose indices).
    pub fn prior_among(&self, candidates: &[usize], x: f64, y: f64, cfg: &InitConfig) -> Prior {
        let g = &self.planes.ground;
        let mut nb: Vec<(f64, usize)> = candidates
            .iter()
            .map(|&j| ((g[j][0] - x).hypot(g[j][1] - y), j))
            .collect();
        nb.sort_by(|a, b| a.0.total_cmp(&b.0));
        nb.truncate(cfg.k.max(1));
        self.prior_from(&nb, x, y, cfg)
    }

    fn prior_from(&self, nb: &[(f64, usize)], x: f64, y: f64, cfg: &InitConfig) -> Prior {
        let p = self.planes;
        let (mut sw, mut sz) = (0.0, 0.0);
        let mut preds = Vec::with_capacity(nb.len());
        let mut mean_n = [0.0; 3];
        for &(d, j) in nb {
            let w = (-d * d / (2.0 * cfg.sigma_d * cfg.sigma_d))
                .exp()
                .max(1e-300);
            let z = p.predict(j, x, y);
            preds.push((w, z));
            sw += w;
            sz += w * z;
            for (m, n) in mean_n.iter_mut().zip(p.normal[j]) {
                *m += w * n;
            }
        }
        let z_hat = sz / sw;
        let var = preds
            .iter()
            .map(|(w, z)| w * (z - z_hat).powi(2))
            .sum::<f64>()
            / sw;
        let q = (-var / (cfg.tau_z * cfg.tau_z)).exp();
        let nearest = nb[0].1;
        let z = match cfg.method {
            InitMethod::Consensus => z_hat,
            InitMethod::Nearest => p.predict(nearest, x, y),
        };
        let rotation = match cfg.rotation {
            RotationSource::Nearest => p.rotation[nearest],
            RotationSource::WeightedMean => {
                let l = (mean_n[0].powi(2) + mean_n[1].powi(2) + mean_n[2].powi(2)).sqrt();
                let r = p.rotation[nearest];
                // The nearest pose's x axis (first column of its rotation matrix).
                let (w, qx, qy, qz) = (r[0] as f64, r[1] as f64, r[2] as f64, r[3] as f64);
                let x_axis = [
                    1.0 - 2.0 * (qy * qy + qz * qz),
                    2.0 * (qx * qy + w * qz),
                    2.0 * (qx * qz - w * qy),
                ];
                quat_from_normal(mean_n.map(|v| v / l), x_axis)
            }
        };
        Prior {
            z,
            z_hat,
            var,
            q,
            rotation,
        }
    }
}

/// Priors for every surfel of the grid.
pub struct InitResult {
    pub z: Vec<f32>,
    pub z_hat: Vec<f32>,
    pub var: Vec<f32>,
    pub q: Vec<f32>,
    pub rotation: Vec<[f32; 4]>,
}

/// Priors for surfels `from..` of the grid (all of them with `from = 0`), appended to `out`.
pub fn initialise_into(
    grid: &Grid,
    poses: &PoseIndex,
    cfg: &InitConfig,
    from: usize,
    out: &mut InitResult,
) {
    // Pose candidates per block of 16×16 fine cells (0.4 m at 5 cm): one neighbour
    // search per block, then each surfel picks its k nearest among them. The 8 extra
    // candidates cover the block's extent (poses are ~1 m apart along the path).
    let block_of = |k: usize| {
        let c = grid.coords[k];
        (c[0].div_euclid(16), c[1].div_euclid(16))
    };
    let mut blocks: Vec<(i32, i32)> = (from..grid.len()).map(block_of).collect();
    blocks.sort_unstable();
    blocks.dedup();
    let candidates: Vec<Vec<usize>> = crate::par::par_map(blocks.len(), |b| {
        let [x, y] = grid.xy_of(blocks[b].0 * 16 + 8, blocks[b].1 * 16 + 8);
        poses
            .nearest(x, y, cfg.k.max(1) + 8)
            .into_iter()
            .map(|(_, j)| j)
            .collect()
    });
    let priors = crate::par::par_map(grid.len() - from, |i| {
        let k = from + i;
        let [x, y] = grid.xy(k);
        let b = blocks.binary_search(&block_of(k)).unwrap_or(0);
        Some(poses.prior_among(&candidates[b], x, y, cfg))
    });
    for p in priors.into_iter().flatten() {
        out.z.push(p.z as f32);
        out.z_hat.push(p.z_hat as f32);
        out.var.push(p.var as f32);
        out.q.push(p.q as f32);
        out.rotation.push(p.rotation);
    }
}

pub fn initialise(grid: &Grid, poses: &PoseIndex, cfg: &InitConfig) -> InitResult {
    let mut out = InitResult {
        z: Vec::new(),
        z_hat: Vec::new(),
        var: Vec::new(),
        q: Vec::new(),
        rotation: Vec::new(),
    };
    initialise_into(grid, poses, cfg, 0, &mut out);
    out
}
