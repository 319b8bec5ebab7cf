//! The true heightfield: (height, s, t) sampled on a fine world-xy raster and read back
//! bilinearly. Bilinear interpolation of this raster *is* the truth the generator's
//! images, LiDAR and BEV rasters all come from, so they agree by construction.
//!
//! Ray marching skips 16×16-cell blocks by their maximum height (a one-level max
//! mip), so most of a ray's length costs one lookup per block.

use super::road::{Centreline, RoadSpec, T_MAX};
use crate::par::par_chunks;

const BLOCK: usize = 16;

/// One raster row of heights, s and t, filled in parallel.
type RowSlices<'a> = (&'a mut [f32], (&'a mut [f32], &'a mut [f32]));

pub struct Field {
    /// World xy of vertex (0, 0), metres.
    pub origin: [f64; 2],
    pub cell: f64,
    pub nx: usize,
    pub ny: usize,
    /// Per vertex, row-major (y then x): height, s, t.
    h: Vec<f32>,
    s: Vec<f32>,
    t: Vec<f32>,
    block_max: Vec<f32>,
    bnx: usize,
}

/// A surface sample: height and road coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Sample {
    pub h: f64,
    pub s: f64,
    pub t: f64,
}

impl Field {
    pub fn build(road: &RoadSpec, line: &Centreline, cell: f64) -> Self {
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in &line.pts {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        let m = T_MAX + 2.0;
        let origin = [x0 - m, y0 - m];
        let nx = ((x1 - x0 + 2.0 * m) / cell).ceil() as usize + 1;
        let ny = ((y1 - y0 + 2.0 * m) / cell).ceil() as usize + 1;
        let nearest = CoarseIndex::build(line, origin, nx as f64 * cell, ny as f64 * cell);
        let n = nx * ny;
        let (mut h, mut s, mut t) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
        let mut rows: Vec<RowSlices> = h
            .chunks_mut(nx)
            .zip(s.chunks_mut(nx).zip(t.chunks_mut(nx)))
            .collect();
        par_chunks(&mut rows, |j, (hr, (sr, tr))| {
            let y = origin[1] + j as f64 * cell;
            for i in 0..nx {
                let x = origin[0] + i as f64 * cell;
                let k = nearest.get(x, y);
                let (_, ss, tt) = line.project(x, y, k.saturating_sub(12), k + 12);
                hr[i] = road.height(ss, tt) as f32;
                sr[i] = ss as f32;
                tr[i] = tt as f32;
            }
        });
        let bnx = (nx - 1).div_ceil(BLOCK);
        let bny = (ny - 1).div_ceil(BLOCK);
        let mut block_max = vec![f32::MIN; bnx * bny];
        for j in 0..ny {
            for i in 0..nx {
                let v = h[j * nx + i];
                // A vertex on a block border belongs to both neighbours.
                for bj in [j / BLOCK, j.saturating_sub(1) / BLOCK] {
                    for bi in [i / BLOCK, i.saturating_sub(1) / BLOCK] {
                        if bi < bnx && bj < bny {
                            let b = &mut block_max[bj * bnx + bi];
                            *b = b.max(v);
                        }
                    }
                }
            }
        }
        Self {
            origin,
            cell,
            nx,
            ny,
            h,
            s,
            t,
            block_max,
            bnx,
        }
    }

    /// Bilinear sample at world (x, y); `None` outside the raster.
    pub fn sample(&self, x: f64, y: f64) -> Option<Sample> {
        let fx = (x - self.origin[0]) / self.cell;
        let fy = (y - self.origin[1]) / self.cell;
        if !(fx >= 0.0 && fy >= 0.0 && fx < (self.nx - 1) as f64 && fy < (self.ny - 1) as f64) {
            return None;
        }
        let (i, j) = (fx as usize, fy as usize);
        let (wx, wy) = (fx - i as f64, fy - j as f64);
        let k = j * self.nx + i;
        let lerp = |v: &[f32]| {
            let a = v[k] as f64 + wx * (v[k + 1] as f64 - v[k] as f64);
            let b =
                v[k + self.nx] as f64 + wx * (v[k + self.nx + 1] as f64 - v[k + self.nx] as f64);
            a + wy * (b - a)
        };
        Some(Sample {
            h: lerp(&self.h),
            s: lerp(&self.s),
            t: lerp(&self.t),
        })
    }

    pub fn height(&self, x: f64, y: f64) -> Option<f64> {
        self.sample(x, y).map(|s| s.h)
    }

    /// Upward unit normal from the bilinear heights around (x, y).
    pub fn normal(&self, x: f64, y: f64) -> [f64; 3] {
        let e = self.cell * 0.5;
        let h = |x, y| self.height(x, y).unwrap_or(0.0);
        let gx = (h(x + e, y) - h(x - e, y)) / (2.0 * e);
        let gy = (h(x, y + e) - h(x, y - e)) / (2.0 * e);
        let n = (gx * gx + gy * gy + 1.0).sqrt();
        [-gx / n, -gy / n, 1.0 / n]
    }

    /// First intersection of the ray `o + τ d` (τ in `τ0..τ1`) with the surface.
    pub fn intersect(&self, o: [f64; 3], d: [f64; 3], t0: f64, t1: f64) -> Option<f64> {
        let block = self.cell * BLOCK as f64;
        let dxy = d[0].hypot(d[1]).max(1e-9);
        let fine = (self.cell / dxy).min(if d[2].abs() > 1e-9 {
            0.02 / d[2].abs()
        } else {
            f64::MAX
        });
        let mut tau = t0;
        let mut above = t0;
        while tau < t1 {
            let p = [o[0] + tau * d[0], o[1] + tau * d[1], o[2] + tau * d[2]];
            let fx = (p[0] - self.origin[0]) / self.cell;
            let fy = (p[1] - self.origin[1]) / self.cell;
            if !(fx >= 0.0 && fy >= 0.0 && fx < (self.nx - 1) as f64 && fy < (self.ny - 1) as f64) {
                return None;
            }
            let (bi, bj) = (fx as usize / BLOCK, fy as usize / BLOCK);
            let hb = self.block_max[bj * self.bnx + bi] as f64;
            if p[2] > hb + 1e-3 {
                // Above everything in this block: jump to its exit or to height hb.
                let exit = |f: f64, dir: f64, b: usize| {
                    if dir > 1e-12 {
                        ((b + 1) as f64 * block - f * self.cell) / dir
                    } else if dir < -1e-12 {
                        (b as f64 * block - f * self.cell) / dir
                    } else {
                        f64::MAX
                    }
                };
                let mut step = exit(fx, d[0], bi).min(exit(fy, d[1], bj));
                if d[2] < 0.0 {
                    step = step.min((p[2] - hb) / -d[2]);
                }
                above = tau + step.max(0.0);
                tau = above + 1e-6;
                continue;
            }
            let h = self.height(p[0], p[1])?;
            if p[2] < h {
                // Bisect between the last point above and this one.
                let (mut lo, mut hi) = (above, tau);
                for _ in 0..20 {
                    let mid = 0.5 * (lo + hi);
                    let q = [o[0] + mid * d[0], o[1] + mid * d[1], o[2] + mid * d[2]];
                    match self.height(q[0], q[1]) {
                        Some(hq) if q[2] < hq => hi = mid,
                        _ => lo = mid,
                    }
                }
                return Some(0.5 * (lo + hi));
            }
            above = tau;
            tau += fine;
        }
        None
    }
}

/// Nearest centreline sample per 1 m cell: the starting guess for exact projection.
struct CoarseIndex {
    origin: [f64; 2],
    nx: usize,
    ny: usize,
    idx: Vec<usize>,
}

impl CoarseIndex {
    fn build(line: &Centreline, origin: [f64; 2], w: f64, h: f64) -> Self {
        let (nx, ny) = (w.ceil() as usize + 1, h.ceil() as usize + 1);
        let mut best = vec![(f64::MAX, 0usize); nx * ny];
        let r = (T_MAX + 6.0) as isize;
        for (k, p) in line.pts.iter().enumerate().step_by(2) {
            let (ci, cj) = ((p[0] - origin[0]) as isize, (p[1] - origin[1]) as isize);
            for j in (cj - r).max(0)..(cj + r + 1).min(ny as isize) {
                for i in (ci - r).max(0)..(ci + r + 1).min(nx as isize) {
                    let (x, y) = (origin[0] + i as f64 + 0.5, origin[1] + j as f64 + 0.5);
                    let d = (x - p[0]).powi(2) + (y - p[1]).powi(2);
                    let b = &mut best[j as usize * nx + i as usize];
                    if d < b.0 {
                        *b = (d, k);
                    }
                }
            }
        }
        Self {
            origin,
            nx,
            ny,
            idx: best.into_iter().map(|b| b.1).collect(),
        }
    }

    fn get(&self, x: f64, y: f64) -> usize {
        let i = ((x - self.origin[0]).max(0.0) as usize).min(self.nx - 1);
        let j = ((y - self.origin[1]).max(0.0) as usize).min(self.ny - 1);
        self.idx[j * self.nx + i]
    }
}
