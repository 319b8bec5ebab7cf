//! Road-structure-aware adaptive refinement (one level). Each base cell gets
//! `kappa = w_g G + w_s S + w_z Z` from its centre projected into its best view:
//! G, the strongest luminance gradient in the cell's footprint (marking edges, not
//! the weaker asphalt texture); S, 1 where the footprint holds more than one road
//! class (a semantic boundary); Z, the LiDAR height spread in the cell within one
//! sweep (a curb; across sweeps pose noise would dominate), or
//! without LiDAR the twist of the pose-consensus surface over the cell. With the
//! default weights (0.5 each) and tau_a = 0.6 no single cue refines a cell: a crack
//! (G alone), noisy labels (S alone) or pose noise in the LiDAR (Z alone) do not; a
//! marking edge (G and S) or a curb (Z and S) does. Cells above tau_a split 2×2: new surfels at the cell centre and edge midpoints, shared edge
//! vertices created once (the index map deduplicates).

use super::ipm::{sample_best, Cams, Projection, CANDIDATE_FRAMES};
use super::PoseIndex;
use crate::bundle::{Bundle, ClassRole, Problem};
use crate::grid::Grid;
use crate::spatial::PointGrid;
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
    lidar: Option<(&PointGrid, &[u32])>,
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
    let candidates: Vec<Vec<Projection>> = crate::par::par_map(centres.len(), |i| {
        cams.candidates(poses, centres[i], CANDIDATE_FRAMES, 2)
    });
    let road: Vec<bool> = (0..=255u8)
        .map(|id| {
            b.manifest
                .semantic_classes
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
    let spread: Vec<f64> = crate::par::par_map(cells.len(), |i| {
        let c = cells[i];
        match lidar {
            Some((pts, sweep)) => {
                // (sweep, lowest, highest) of the points near the cell centre.
                let mut per: Vec<(u32, f64, f64)> = Vec::new();
                pts.within(centres[i][0], centres[i][1], 1.5 * grid.resolution, |k| {
                    let z = pts.points()[k][2];
                    match per.iter_mut().find(|e| e.0 == sweep[k]) {
                        Some(e) => (e.1, e.2) = (e.1.min(z), e.2.max(z)),
                        None => per.push((sweep[k], z, z)),
                    }
                });
                per.iter().map(|e| e.2 - e.1).fold(0.0, f64::max)
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
