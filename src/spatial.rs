//! A uniform grid hash of points in the xy-plane: nearest-within-radius and
//! k-nearest queries without sorting everything (pose neighbours, LiDAR lookups).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

/// A multiplicative hasher for small integer keys (grid cells): several times faster
/// than the default SipHash, and hash flooding is no concern for our own coordinates.
#[derive(Default, Clone, Copy)]
pub struct CellHasher(u64);

impl Hasher for CellHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    fn write_u32(&mut self, v: u32) {
        self.write_u64(v as u64);
    }
    fn write_i32(&mut self, v: i32) {
        self.write_u64(v as u32 as u64);
    }
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

/// A hash map keyed by grid cells.
pub type CellMap<K, V> = HashMap<K, V, BuildHasherDefault<CellHasher>>;

pub struct PointGrid<'a> {
    cell: f64,
    map: CellMap<(i64, i64), Vec<usize>>,
    pts: &'a [[f64; 3]],
}

impl<'a> PointGrid<'a> {
    /// Indexes `pts` by xy with square cells of side `cell` metres.
    pub fn new(pts: &'a [[f64; 3]], cell: f64) -> Self {
        let mut map: CellMap<(i64, i64), Vec<usize>> = CellMap::default();
        for (i, p) in pts.iter().enumerate() {
            map.entry(Self::key(p[0], p[1], cell)).or_default().push(i);
        }
        Self { cell, map, pts }
    }

    fn key(x: f64, y: f64, cell: f64) -> (i64, i64) {
        ((x / cell).floor() as i64, (y / cell).floor() as i64)
    }

    pub fn points(&self) -> &'a [[f64; 3]] {
        self.pts
    }

    /// Indices of the points in the cells of ring `r` around cell (ci, cj).
    fn ring(&self, ci: i64, cj: i64, r: i64, mut f: impl FnMut(usize)) {
        for j in cj - r..=cj + r {
            for i in ci - r..=ci + r {
                if (i - ci).abs() != r && (j - cj).abs() != r {
                    continue;
                }
                for &k in self.map.get(&(i, j)).into_iter().flatten() {
                    f(k);
                }
            }
        }
    }

    /// The nearest point within `radius` in xy.
    pub fn nearest(&self, x: f64, y: f64, radius: f64) -> Option<usize> {
        let (ci, cj) = Self::key(x, y, self.cell);
        let reach = (radius / self.cell).ceil() as i64;
        let mut best: Option<(f64, usize)> = None;
        for r in 0..=reach {
            self.ring(ci, cj, r, |k| {
                let p = self.pts[k];
                let d = (p[0] - x).hypot(p[1] - y);
                if d <= radius && best.is_none_or(|b| d < b.0) {
                    best = Some((d, k));
                }
            });
        }
        best.map(|b| b.1)
    }

    /// Calls `f(index)` for every point within `radius` of (x, y) in xy.
    pub fn within(&self, x: f64, y: f64, radius: f64, mut f: impl FnMut(usize)) {
        let (ci, cj) = Self::key(x, y, self.cell);
        let reach = (radius / self.cell).ceil() as i64;
        for r in 0..=reach {
            self.ring(ci, cj, r, |k| {
                let p = self.pts[k];
                if (p[0] - x).hypot(p[1] - y) <= radius {
                    f(k);
                }
            });
        }
    }

    /// The `k` nearest points in xy as (distance, index), nearest first. Rings grow
    /// until the k-th distance is certainly inside the searched square.
    pub fn knn(&self, x: f64, y: f64, k: usize) -> Vec<(f64, usize)> {
        let k = k.min(self.pts.len());
        let (ci, cj) = Self::key(x, y, self.cell);
        let mut found: Vec<(f64, usize)> = Vec::new();
        let mut r = 0;
        loop {
            self.ring(ci, cj, r, |i| {
                let p = self.pts[i];
                found.push(((p[0] - x).hypot(p[1] - y), i));
            });
            // Every point outside the searched rings is at least r·cell away.
            if found.len() >= k && k > 0 {
                let kth = found
                    .select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0))
                    .1
                     .0;
                if kth <= r as f64 * self.cell {
                    break;
                }
            }
            if found.len() == self.pts.len() {
                break;
            }
            r += 1;
            // Far from every point (a sparse set: a frame 100 km away), the rings
            // would visit more cells than there are points: measure them all instead.
            let side = 2 * r as u64 + 1;
            if side * side > 4 * self.pts.len() as u64 + 64 {
                found = (0..self.pts.len())
                    .map(|i| ((self.pts[i][0] - x).hypot(self.pts[i][1] - y), i))
                    .collect();
                break;
            }
        }
        found.sort_by(|a, b| a.0.total_cmp(&b.0));
        found.truncate(k);
        found
    }
}

#[cfg(test)]
mod tests {
    use super::PointGrid;

    /// Brute force: the k nearest in xy, nearest first.
    fn brute(pts: &[[f64; 3]], x: f64, y: f64, k: usize) -> Vec<usize> {
        let mut d: Vec<(f64, usize)> = pts
            .iter()
            .enumerate()
            .map(|(i, p)| ((p[0] - x).hypot(p[1] - y), i))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0));
        d.into_iter().take(k).map(|p| p.1).collect()
    }

    #[test]
    fn knn_matches_brute_force_on_dense_and_on_sparse_points() {
        // Dense: a 20 × 20 lattice of 0.3 m; sparse: a few points 100 km apart
        // (where the rings alone would visit billions of cells).
        let dense: Vec<[f64; 3]> = (0..400)
            .map(|i| {
                [
                    (i % 20) as f64 * 0.3,
                    (i / 20) as f64 * 0.3 + 0.01 * i as f64,
                    0.0,
                ]
            })
            .collect();
        let sparse = vec![
            [0.0, 0.0, 0.0],
            [1e5, 3.0, 0.0],
            [5e4, -2.0, 0.0],
            [1.0, 1.0, 0.0],
        ];
        for (pts, cell) in [(&dense, 0.5), (&sparse, 0.5)] {
            let g = PointGrid::new(pts, cell);
            for (x, y) in [(0.1, 0.2), (3.0, 3.0), (7e4, 0.0), (-20.0, 5.0)] {
                for k in [1, 3] {
                    let got: Vec<usize> = g.knn(x, y, k).into_iter().map(|p| p.1).collect();
                    assert_eq!(got, brute(pts, x, y, k), "({x}, {y}), k {k}");
                }
            }
        }
    }
}
