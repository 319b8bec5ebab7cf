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
        }
        found.sort_by(|a, b| a.0.total_cmp(&b.0));
        found.truncate(k);
        found
    }
}
