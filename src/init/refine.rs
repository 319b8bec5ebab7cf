//! Road-structure-aware adaptive refinement (one level). Each base cell gets
//! `kappa = w_g G + w_s S + w_z Z` from its centre projected into its best view:
//! G, the strongest luminance gradient in the cell's footprint (marking edges, not
//! the weaker asphalt texture); S, 1 where the footprint holds more than one road
//! class (a semantic boundary); Z, the LiDAR height spread around the cell (its 3×3
//! neighbourhood) within one sweep (a curb; across sweeps pose noise would
//! dominate), or
//! without LiDAR the twist of the pose-consensus surface over the cell. With the
//! default weights (0.5 each) and tau_a = 0.6 no single cue refines a cell: a crack
//! (G alone), noisy labels (S alone) or pose noise in the LiDAR (Z alone) do not; a
//! marking edge (G and S) or a curb (Z and S) does. Cells above tau_a split 2×2: new surfels at the cell centre and edge midpoints, shared edge
//! vertices created once (the index map deduplicates).

use super::ipm::{candidate_frames, sample_best, Cams, Views};
use super::PoseIndex;
use crate::bundle::{Bundle, ClassRole, Problem};
use crate::grid::Grid;
use crate::spatial::CellMap;
use serde::Serialize;

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RefineConfig {
    pub enabled: bool,
    pub w_g: f64,
    pub w_s: f64,
    pub w_z: f64,
    pub tau_a: f64,
    /// Luminance gradient (per pixel, central difference) that counts as G = 1.
    pub gradient_full: f64,
    /// Height spread within a cell that counts as Z = 1, metres.
    pub height_full: f64,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            w_g: 0.5,
            w_s: 0.5,
            w_z: 0.5,
            tau_a: 0.6,
            gradient_full: 0.15,
            height_full: 0.06,
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct RefineReport {
    pub base_cells: usize,
    pub scored_cells: usize,
    pub refined_cells: usize,
    pub added_surfels: usize,
    /// Mean cue values over the scored cells (G, S, Z), for tuning and reports.
    pub mean_g: f64,
    pub mean_s: f64,
    pub mean_z: f64,
    /// Height spread treated as noise (median over cells with LiDAR), metres.
    pub z_noise_floor: f64,
    /// Time finding each cell's best views, and decoding and sampling the images.
    pub candidates_ms: f64,
    pub sampling_ms: f64,
}

/// Scores every base cell and splits those above the threshold. `z` holds the
/// initial elevation of every surfel; `lidar` the world LiDAR points and their sweep
/// indices, if any.
/// Returns the report and the refined cells (lower-left fine coordinates).
pub fn refine(
    b: &Bundle,
    grid: &mut Grid,
    z: &[f32],
    poses: &PoseIndex,
    lidar: Option<(&[[f64; 3]], &[u32])>,
    cfg: &RefineConfig,
) -> Result<(RefineReport, Vec<[i32; 2]>), Problem> {
    let cells = grid.base_cells();
    let mut report = RefineReport {
        base_cells: cells.len(),
        ..Default::default()
    };
    if !cfg.enabled || cells.is_empty() {
        return Ok((report, Vec::new()));
    }
    let corner_z = |c: [i32; 2], di: i32, dj: i32| {
        grid.index
            .get(c[0] + di, c[1] + dj)
            .map_or(0.0, |k| z[k as usize] as f64)
    };
    let centres: Vec<[f64; 3]> = cells
        .iter()
        .map(|&c| {
            let [x, y] = grid.xy_of(c[0] + 1, c[1] + 1);
            let zc =
                (corner_z(c, 0, 0) + corner_z(c, 2, 0) + corner_z(c, 0, 2) + corner_z(c, 2, 2))
                    / 4.0;
            [x, y, zc]
        })
        .collect();
    let t0 = web_time::Instant::now();
    let cams = Cams::new(&b.manifest);
    // Candidate frames per block of 8×8 cells (0.4 m at 5 cm): one neighbour search
    // per block instead of per cell.
    let block_of = |c: [i32; 2]| (c[0].div_euclid(16), c[1].div_euclid(16));
    // Each block's frames are those searched for one of its cells (`Cams::views_near`).
    let mut blocks: Vec<((i32, i32), usize)> = cells
        .iter()
        .enumerate()
        .map(|(i, &c)| (block_of(c), i))
        .collect();
    blocks.sort_unstable();
    blocks.dedup_by_key(|b| b.0);
    let block_frames: Vec<Vec<usize>> = crate::par::par_map(blocks.len(), |k| {
        cams.views_near(poses, centres[blocks[k].1], candidate_frames(b), 2, &|_| {
            true
        })
        .0
    });
    let candidates: Vec<Views> = crate::par::par_map(centres.len(), |i| {
        let key = block_of(cells[i]);
        let k = blocks.partition_point(|b| b.0 < key);
        cams.candidates_in(&block_frames[k], centres[i], 2)
    });
    let classes = b.manifest.classes();
    let road: Vec<bool> = (0..=255u8)
        .map(|id| {
            classes
                .iter()
                .any(|c| c.id == id && c.role == ClassRole::Road)
        })
        .collect();
    let t_cand = t0.elapsed().as_secs_f64();
    let mut g = vec![0.0f64; cells.len()];
    let mut s = vec![0.0f64; cells.len()];
    report.scored_cells = sample_best(b, &cams, &candidates, |i, imgs, p| {
        // The cell's footprint in pixels, at least the 3×3 around the centre.
        let fx = cams.list[p.cam as usize].fx;
        let r = ((fx * grid.resolution / p.depth as f64) * 0.5).clamp(1.0, 4.0) as i64;
        let (w, h) = (imgs.rgb.width() as i64, imgs.rgb.height() as i64);
        let lum = |x: i64, y: i64| {
            let px = imgs
                .rgb
                .get_pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32)
                .0;
            (px[0] as f64 + px[1] as f64 + px[2] as f64) / 765.0
        };
        let (u, v) = (p.u as i64, p.v as i64);
        let mut gmax: f64 = 0.0;
        let mut first_class: Option<u8> = None;
        let mut boundary = false;
        for y in v - r..=v + r {
            for x in u - r..=u + r {
                let gx = 0.5 * (lum(x + 1, y) - lum(x - 1, y));
                let gy = 0.5 * (lum(x, y + 1) - lum(x, y - 1));
                gmax = gmax.max(gx.hypot(gy));
                let c = imgs
                    .label
                    .get_pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32)
                    .0[0];
                if road[c as usize] {
                    boundary |= first_class.is_some_and(|f| f != c);
                    first_class.get_or_insert(c);
                }
            }
        }
        g[i] = (gmax / cfg.gradient_full).min(1.0);
        s[i] = if boundary { 1.0 } else { 0.0 };
    })?;
    let t_sample = t0.elapsed().as_secs_f64();
    report.candidates_ms = t_cand * 1e3;
    report.sampling_ms = (t_sample - t_cand) * 1e3;
    let buckets = lidar.map(|(pts, sweep)| lidar_buckets(pts, sweep, grid));
    let spread: Vec<f64> = crate::par::par_map(cells.len(), |i| {
        let c = cells[i];
        match &buckets {
            Some(b) => {
                // Per sweep, lowest and highest point in the 3×3 cells around this one.
                let mut per: Vec<(u32, f32, f32)> = Vec::new();
                let (bi, bj) = (c[0] / 2, c[1] / 2);
                for dj in -1..=1 {
                    for di in -1..=1 {
                        for &(s, lo, hi) in b.get(&(bi + di, bj + dj)).into_iter().flatten() {
                            match per.iter_mut().find(|e| e.0 == s) {
                                Some(e) => (e.1, e.2) = (e.1.min(lo), e.2.max(hi)),
                                None => per.push((s, lo, hi)),
                            }
                        }
                    }
                }
                per.iter().map(|e| (e.2 - e.1) as f64).fold(0.0, f64::max)
            }
            None => (corner_z(c, 0, 0) + corner_z(c, 2, 2) - corner_z(c, 2, 0) - corner_z(c, 0, 2))
                .abs(),
        }
    });
    // Pose noise spreads the accumulated LiDAR of flat road too: only the spread above
    // the typical (median) one is structure.
    let floor = if lidar.is_some() {
        let mut v: Vec<f64> = spread.iter().copied().filter(|&x| x > 0.0).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    } else {
        0.0
    };
    let mut refined = Vec::new();
    let (mut sg, mut ss, mut sz) = (0.0, 0.0, 0.0);
    for (i, &c) in cells.iter().enumerate() {
        let zn = ((spread[i] - floor).max(0.0) / cfg.height_full).min(1.0);
        if !candidates[i].is_empty() {
            sg += g[i];
            ss += s[i];
            sz += zn;
        }
        let kappa = cfg.w_g * g[i] + cfg.w_s * s[i] + cfg.w_z * zn;
        if kappa > cfg.tau_a {
            refined.push(c);
        }
    }
    let n = report.scored_cells.max(1) as f64;
    (
        report.mean_g,
        report.mean_s,
        report.mean_z,
        report.z_noise_floor,
    ) = (sg / n, ss / n, sz / n, floor);
    let before = grid.len();
    for &c in &refined {
        for (di, dj) in [(1, 1), (1, 0), (0, 1), (2, 1), (1, 2)] {
            grid.insert(c[0] + di, c[1] + dj, 1);
        }
    }
    report.refined_cells = refined.len();
    report.added_surfels = grid.len() - before;
    Ok((report, refined))
}

/// Per base cell, per sweep: (sweep, lowest z, highest z).
type SweepSpans = CellMap<(i32, i32), Vec<(u32, f32, f32)>>;

/// Per base cell (lattice coordinates of its lower-left vertex), per sweep, the lowest
/// and highest LiDAR point: built once in O(points), so the per-cell height spread
/// needs no radius queries.
fn lidar_buckets(pts: &[[f64; 3]], sweep: &[u32], grid: &Grid) -> SweepSpans {
    let mut map = SweepSpans::default();
    for (p, &s) in pts.iter().zip(sweep) {
        let key = (
            ((p[0] - grid.origin[0]) / grid.resolution).floor() as i32,
            ((p[1] - grid.origin[1]) / grid.resolution).floor() as i32,
        );
        let z = p[2] as f32;
        let v = map.entry(key).or_default();
        match v.iter_mut().find(|e| e.0 == s) {
            Some(e) => (e.1, e.2) = (e.1.min(z), e.2.max(z)),
            None => v.push((s, z, z)),
        }
    }
    map
}
