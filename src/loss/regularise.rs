//! Oracle of `shaders/regularise.wgsl` and the host data it needs: the symmetric
//! neighbour lists (CSR) from the grid's index map, and the per-surfel priors
//! (ẑ, q, LiDAR elevation and whether one was found).

use super::LossConfig;
use crate::grid::Grid;
use crate::spatial::PointGrid;

/// Host-side inputs of the regulariser.
#[derive(Clone, Debug, Default)]
pub struct RegData {
    /// CSR: the neighbours of surfel i are `adj[adj_start[i]..adj_start[i + 1]]`.
    pub adj_start: Vec<u32>,
    pub adj: Vec<u32>,
    /// Per surfel: ẑ, q, LiDAR z, LiDAR weight (0 or 1), in the local frame.
    pub priors: Vec<[f32; 4]>,
    /// Number of undirected edges and of surfels with a LiDAR elevation.
    pub edges: usize,
    pub with_lidar: usize,
}

/// Per-term weights as the kernel takes them (the means folded in).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RegWeights {
    pub smooth: f32,
    pub traj: f32,
    pub huber: f32,
    pub lidar: f32,
}

impl RegData {
    /// Symmetric 4-neighbour edges of the grid (an edge found from either end is
    /// stored at both), priors shifted by −`origin_z`, and for each surfel the median
    /// height of the LiDAR points within the radius in xy and within the gate of ẑ.
    pub fn new(
        grid: &Grid,
        z_hat: &[f32],
        q: &[f32],
        lidar: &[[f64; 3]],
        origin_z: f64,
        cfg: &LossConfig,
    ) -> Self {
        let n = grid.len();
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (i, list) in (0..n).map(|i| (i, grid.neighbours4(i).collect::<Vec<_>>())) {
            for j in list {
                let j = j as usize;
                if j == i {
                    continue;
                }
                if !lists[i].contains(&(j as u32)) {
                    lists[i].push(j as u32);
                }
                if !lists[j].contains(&(i as u32)) {
                    lists[j].push(i as u32);
                }
            }
        }
        let mut adj_start = Vec::with_capacity(n + 1);
        let mut adj = Vec::new();
        adj_start.push(0);
        for l in &lists {
            adj.extend_from_slice(l);
            adj_start.push(adj.len() as u32);
        }
        let pg = PointGrid::new(lidar, (cfg.lidar_radius_m as f64).max(0.05));
        let mut with_lidar = 0;
        let priors = (0..n)
            .map(|i| {
                let [x, y] = grid.xy(i);
                let zh = z_hat[i] as f64;
                // The median of the road returns around the surfel: one sweep's point
                // carries that sweep's pose error, several sweeps average it out.
                let mut zs = Vec::new();
                pg.within(x, y, cfg.lidar_radius_m as f64, |k| {
                    let z = lidar[k][2];
                    if (z - zh).abs() <= cfg.lidar_gate_m as f64 {
                        zs.push(z);
                    }
                });
                zs.sort_by(f64::total_cmp);
                if let Some(&low) = zs.get(zs.len() / 4) {
                    let band = cfg.lidar_band_m as f64;
                    zs.retain(|z| (z - low).abs() <= band);
                }
                let hit = (!zs.is_empty()).then(|| zs[zs.len() / 2]);
                with_lidar += hit.is_some() as usize;
                [
                    (zh - origin_z) as f32,
                    q[i],
                    hit.map_or(0.0, |z| (z - origin_z) as f32),
                    hit.map_or(0.0, |_| 1.0),
                ]
            })
            .collect();
        Self {
            edges: adj.len() / 2,
            adj_start,
            adj,
            priors,
            with_lidar,
        }
    }

    /// The kernel's weights. The per-surfel terms are sums over surfels, not means:
    /// a surfel's photometric gradient is a mean over a view's pixels (~1e-4 for a
    /// surfel covering a few pixels), and a mean over ~10⁵ surfels would make these
    /// terms 10⁵ times weaker than that, too weak to move any surfel a view sees.
    pub fn weights(&self, cfg: &LossConfig, use_lidar: bool) -> RegWeights {
        RegWeights {
            smooth: cfg.smooth,
            traj: cfg.traj,
            huber: cfg.huber_m,
            lidar: if use_lidar && self.with_lidar > 0 {
                cfg.lidar
            } else {
                0.0
            },
        }
    }
}

/// Loss sums (smooth, traj, lidar) and dL/dz per surfel, for elevations `z` (local).
pub fn regularise(d: &RegData, w: &RegWeights, z: &[f32]) -> ([f64; 3], Vec<f32>) {
    let all: Vec<u32> = (0..z.len() as u32).collect();
    regularise_over(d, w, z, &all)
}

/// The terms of the surfels `over` alone (a view's candidates, as selective Adam
/// steps them): their loss sums and dL/dz per entry of `over`. Each surfel's terms
/// are its own (an edge counts half at either end), so the sums over a partition of
/// the surfels add up to `regularise`'s.
pub fn regularise_over(
    d: &RegData,
    w: &RegWeights,
    z: &[f32],
    over: &[u32],
) -> ([f64; 3], Vec<f32>) {
    let mut loss = [0.0f64; 3];
    let mut grad = Vec::with_capacity(over.len());
    for &i in over {
        let i = i as usize;
        let mut g = 0.0f32;
        for &j in &d.adj[d.adj_start[i] as usize..d.adj_start[i + 1] as usize] {
            let dz = z[i] - z[j as usize];
            loss[0] += (0.5 * w.smooth * dz * dz) as f64;
            g += 2.0 * w.smooth * dz;
        }
        let [zh, q, zl, has] = d.priors[i];
        let r = z[i] - zh;
        let rho = if r.abs() <= w.huber {
            0.5 * r * r
        } else {
            w.huber * (r.abs() - 0.5 * w.huber)
        };
        loss[1] += (w.traj * q * rho) as f64;
        g += w.traj * q * r.clamp(-w.huber, w.huber);
        let e = z[i] - zl;
        loss[2] += (w.lidar * has * e * e) as f64;
        g += 2.0 * w.lidar * has * e;
        grad.push(g);
    }
    (loss, grad)
}
