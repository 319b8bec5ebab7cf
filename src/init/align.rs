//! Pose alignment in height from the LiDAR: each frame's height, roll and pitch are
//! corrected so that its sweep's ground agrees with the ground every other sweep sees.
//!
//! Why: a pose error of 0.5° in roll or pitch tilts that frame's whole sweep, 9 cm
//! at 10 m, and 5 cm of height error lifts it. Where a dozen sweeps overlap, the
//! median of their returns keeps a few centimetres of that error, and the LiDAR prior
//! then pins the map to it. The ground is seen by many sweeps, so these three degrees
//! of freedom are observable from the LiDAR alone; the horizontal ones (x, y, yaw)
//! are not, on a near-flat road, and are left alone.
//!
//! Model: to first order, a correction (a, b, c) of frame k moves a world point that
//! lies (dx, dy) from the vehicle's origin by a + b·dx + c·dy in z: a plane per sweep.
//! Each round takes, per cell of the ground raster, the median corrected height over
//! every sweep that sees it (the consensus), then fits each sweep's plane to its
//! residuals by Huber-weighted least squares. Only cells seen by several sweeps carry
//! information. The mean correction is then removed: a shared offset or tilt of every
//! frame is not observable from agreement, and the pose noise is taken to have none.
//!
//! Ground returns are chosen per sweep, in the vehicle frame: a ring of ranges, and
//! heights within a band of the sweep's own near-ground level (the median height of its
//! close returns), so objects well above the road do not enter; the residual cut and
//! Huber weights deal with the low parts of objects.

use crate::bundle::transform::apply;
use crate::bundle::{Bundle, Problem};
use crate::bundle::{Manifest, Mat4Rows};
use crate::init::prepare::for_each_sweep_of;
use crate::linalg::{accumulate3, solve3};
use glam::{DMat3, DVec3};

/// Settings of the alignment (defaults for driving sweeps).
#[derive(Clone, Debug, PartialEq)]
pub struct AlignConfig {
    /// Ground returns from this horizontal range band of the vehicle (m).
    pub min_range_m: f64,
    pub max_range_m: f64,
    /// Returns within this height of the sweep's near-ground level (m).
    pub ground_band_m: f64,
    /// Consensus raster cell (m).
    pub cell_m: f64,
    /// A cell informs the fit when at least this many sweeps see it.
    pub min_sweeps: usize,
    /// Residuals beyond this are not ground (m), halved every round down to
    /// `min_cut_m`; Huber threshold (m).
    pub residual_cut_m: f64,
    pub min_cut_m: f64,
    pub huber_m: f64,
    pub rounds: usize,
    /// The expected pose noise in height and in roll and pitch: only their ratio
    /// matters, to choose the unobservable shared plane (see `remove_gauge`).
    pub height_sigma_m: f64,
    pub tilt_sigma_deg: f64,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            min_range_m: 3.0,
            max_range_m: 30.0,
            ground_band_m: 0.5,
            cell_m: 0.25,
            min_sweeps: 3,
            residual_cut_m: 0.3,
            min_cut_m: 0.05,
            huber_m: 0.03,
            rounds: 8,
            height_sigma_m: 0.05,
            tilt_sigma_deg: 0.5,
        }
    }
}

/// Per frame (a, b, c): height (m) and slopes of the correction plane along world x
/// and y; zero for frames without a sweep.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Alignment {
    pub corrections: Vec<[f64; 3]>,
    /// Sweeps that took part and ground returns used.
    pub sweeps: usize,
    pub returns: usize,
    /// One consensus cell in this many kept its returns (`cell_stride`; 0 or 1: all).
    pub cell_stride: u32,
    /// RMS of the Huber-inlier residuals to the consensus, before and after (m).
    pub rms_before_m: f64,
    pub rms_after_m: f64,
}

/// The alignment in a report: how much it moved the poses, how well they agree.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AlignSummary {
    pub sweeps: usize,
    pub ground_returns: usize,
    /// One consensus cell in this many kept its returns (long drives: `cell_stride`).
    pub cells_kept_one_in: u32,
    pub height_rms_m: f64,
    pub tilt_rms_deg: f64,
    pub residual_rms_before_m: f64,
    pub residual_rms_after_m: f64,
}

impl AlignSummary {
    pub fn new(a: &Alignment) -> Self {
        let n = a.sweeps.max(1) as f64;
        let rms = |f: &dyn Fn(&[f64; 3]) -> f64| {
            (a.corrections.iter().map(|c| f(c).powi(2)).sum::<f64>() / n).sqrt()
        };
        Self {
            sweeps: a.sweeps,
            ground_returns: a.returns,
            cells_kept_one_in: a.cell_stride.max(1),
            height_rms_m: rms(&|c| c[0]),
            tilt_rms_deg: rms(&|c| c[1].hypot(c[2])).to_degrees(),
            residual_rms_before_m: a.rms_before_m,
            residual_rms_after_m: a.rms_after_m,
        }
    }
}

/// One ground return, 16 bytes (a long drive holds millions of them): its offset
/// from its sweep's origin along the world axes, its height above that origin, and
/// its sweep. Offsets are within the LiDAR's range, so f32 keeps them to micrometres
/// where world coordinates (UTM eastings, say) would lose centimetres.
#[derive(Clone, Copy, Debug)]
pub struct GroundReturn {
    pub d: [f32; 2],
    pub dz: f32,
    pub sweep: u32,
}

/// The ground returns of a drive: each sweep's world origin (its vehicle's position;
/// `None` for a sweep that gave no return) and the returns relative to it.
#[derive(Clone, Debug, Default)]
pub struct GroundReturns {
    pub origins: Vec<Option<[f64; 3]>>,
    pub points: Vec<GroundReturn>,
}

impl GroundReturns {
    /// No returns yet, for a drive of `frames` frames.
    pub fn new(frames: usize) -> Self {
        Self {
            origins: vec![None; frames],
            points: Vec::new(),
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    fn origin(&self, r: &GroundReturn) -> [f64; 3] {
        self.origins[r.sweep as usize].unwrap_or_default()
    }

    /// World xy of a return.
    pub fn xy(&self, r: &GroundReturn) -> [f64; 2] {
        let o = self.origin(r);
        [o[0] + r.d[0] as f64, o[1] + r.d[1] as f64]
    }

    /// World height of a return.
    pub fn z(&self, r: &GroundReturn) -> f64 {
        self.origin(r)[2] + r.dz as f64
    }

    /// Adds the ground returns of one sweep (points in the vehicle frame, `pose` its
    /// vehicle-to-world), in the consensus cells kept by `stride` (`cell_stride`; 1
    /// keeps all).
    pub fn add_sweep(
        &mut self,
        pts: &[[f64; 3]],
        pose: &Mat4Rows,
        sweep: u32,
        cfg: &AlignConfig,
        stride: u32,
    ) {
        let range = |p: &[f64; 3]| p[0].hypot(p[1]);
        // The sweep's near-ground level: the median height of its close returns.
        let mut near: Vec<f64> = pts
            .iter()
            .filter(|p| (cfg.min_range_m..cfg.min_range_m + 7.0).contains(&range(p)))
            .map(|p| p[2])
            .collect();
        if near.is_empty() {
            return;
        }
        let mid = near.len() / 2;
        let level = *near.select_nth_unstable_by(mid, f64::total_cmp).1;
        let o = [pose[0][3], pose[1][3], pose[2][3]];
        let before = self.points.len();
        self.points.extend(
            pts.iter()
                .filter(|p| {
                    (cfg.min_range_m..cfg.max_range_m).contains(&range(p))
                        && (p[2] - level).abs() <= cfg.ground_band_m
                })
                .map(|p| apply(pose, *p))
                .filter(|w| kept([w[0], w[1]], cfg.cell_m, stride))
                .map(|w| GroundReturn {
                    d: [(w[0] - o[0]) as f32, (w[1] - o[1]) as f32],
                    dz: (w[2] - o[2]) as f32,
                    sweep,
                }),
        );
        if self.points.len() > before {
            let k = sweep as usize;
            if self.origins.len() <= k {
                self.origins.resize(k + 1, None);
            }
            self.origins[k] = Some(o);
        }
    }
}

/// LiDAR points a drive's sweeps may hold before the alignment thins its returns
/// (`cell_stride`): its returns and their consensus raster take about 40 bytes each
/// (16 held, 24 while the alignment runs), and must fit a browser's heap with the
/// rest of the run.
pub const HELD_POINTS: u64 = 12_000_000;

/// One consensus cell in how many keeps its returns: 1 unless the drive's sweeps hold
/// more than `HELD_POINTS` points in all (told from the files' sizes, before any is
/// read), so that the returns held stay under about that whatever the drive's length
/// (the 3.7 km `long`: 70 M points, one cell in 6). The kept cells are one fixed
/// pseudo-random pattern of the world, the same for every sweep, so each kept cell
/// still has every sweep that sees it, and every sweep a plane's worth of returns.
pub fn cell_stride(b: &Bundle) -> u32 {
    let Some(l) = &b.manifest.lidar else {
        return 1;
    };
    let bytes: u64 = b
        .manifest
        .frames
        .iter()
        .filter_map(|f| f.lidar.as_ref())
        .map(|p| b.source().size(p).unwrap_or(0))
        .sum();
    let points = bytes / (4 * l.floats_per_point.max(1) as u64);
    points.div_ceil(HELD_POINTS).clamp(1, u32::MAX as u64) as u32
}

/// Whether the consensus cell at world `xy` keeps its returns (`cell_stride`).
fn kept(xy: [f64; 2], cell_m: f64, stride: u32) -> bool {
    if stride <= 1 {
        return true;
    }
    let i = (xy[0] / cell_m).floor() as i64 as u64;
    let j = (xy[1] / cell_m).floor() as i64 as u64;
    // splitmix64 of the cell's key.
    let mut h = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ j.rotate_left(32);
    h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (h ^ (h >> 31)).is_multiple_of(stride as u64)
}

/// The ground returns of every frame's sweep, through the bundle's poses.
pub fn ground_returns(b: &Bundle, cfg: &AlignConfig) -> Result<GroundReturns, Problem> {
    let mut out = GroundReturns::new(b.manifest.frames.len());
    gather_ground_returns(b, cfg, None, &mut out)?;
    Ok(out)
}

/// Adds to `out` the ground returns of the frames marked in `frames` (all when
/// `None`): a lazily read bundle gathers them a batch of sweeps at a time.
pub fn gather_ground_returns(
    b: &Bundle,
    cfg: &AlignConfig,
    frames: Option<&[bool]>,
    out: &mut GroundReturns,
) -> Result<(), Problem> {
    let stride = cell_stride(b);
    for_each_sweep_of(b, frames, |k, pose, pts| {
        out.add_sweep(&pts, pose, k as u32, cfg, stride)
    })
}

/// Aligns the bundle's poses in place when it has LiDAR, and says what it did.
pub fn align_bundle(b: &mut Bundle, cfg: &AlignConfig) -> Result<Option<Alignment>, Problem> {
    let returns = ground_returns(b, cfg)?;
    Ok(align_with_returns(b, returns, cfg))
}

/// As `align_bundle`, from ground returns already gathered.
pub fn align_with_returns(
    b: &mut Bundle,
    returns: GroundReturns,
    cfg: &AlignConfig,
) -> Option<Alignment> {
    if returns.is_empty() {
        return None;
    }
    let a = Alignment {
        cell_stride: cell_stride(b),
        ..align(&returns, b.manifest.frames.len(), cfg)
    };
    apply_to_poses(&a, &mut b.manifest);
    Some(a)
}

/// Estimates the corrections of `frames` frames from their ground returns.
pub fn align(returns: &GroundReturns, frames: usize, cfg: &AlignConfig) -> Alignment {
    let cells = Cells::new(returns, cfg);
    let origins = sweep_origins(returns, frames);
    let mut corr = vec![[0.0f64; 3]; frames];
    let mut rms = Vec::new();
    for round in 0..=cfg.rounds {
        let z: Vec<f64> = returns
            .points
            .iter()
            .map(|r| corrected(returns.z(r), r, &corr))
            .collect();
        let cons = cells.consensus(&z);
        // The cut narrows as the sweeps come together: wide enough at first for a
        // 0.5° tilt at 30 m, then only what ground returns still disagree by.
        let cut = (cfg.residual_cut_m * 0.5f64.powi(round as i32)).max(cfg.min_cut_m);
        // Per sweep, the normal equations of the plane fit to −residual.
        let mut ata = vec![[0.0f64; 6]; frames];
        let mut atb = vec![[0.0f64; 3]; frames];
        let (mut sq, mut inl) = (0.0, 0usize);
        for (i, r) in returns.points.iter().enumerate() {
            let Some(c) = cons[cells.cell_of[i] as usize] else {
                continue;
            };
            let e = z[i] - c;
            if e.abs() > cut {
                continue;
            }
            if e.abs() <= cfg.huber_m {
                sq += e * e;
                inl += 1;
            }
            let w = (cfg.huber_m / e.abs().max(1e-12)).min(1.0);
            let s = r.sweep as usize;
            let d = r.d.map(f64::from);
            accumulate3(&mut ata[s], &mut atb[s], [1.0, d[0], d[1]], w, -e);
        }
        rms.push((sq / inl.max(1) as f64).sqrt());
        if round == cfg.rounds {
            break;
        }
        for (s, c) in corr.iter_mut().enumerate() {
            // A sweep with too few or collinear returns keeps its correction.
            if let Some(d) = solve3(&ata[s], &atb[s], 30.0) {
                for p in 0..3 {
                    c[p] += d[p];
                }
            }
        }
        remove_gauge(&mut corr, &origins, cfg);
    }
    Alignment {
        corrections: corr,
        sweeps: origins.len(),
        returns: returns.len(),
        cell_stride: 1,
        rms_before_m: rms.first().copied().unwrap_or(0.0),
        rms_after_m: rms.last().copied().unwrap_or(0.0),
    }
}

/// The world height `z` of return `r` under its sweep's correction.
fn corrected(z: f64, r: &GroundReturn, corr: &[[f64; 3]]) -> f64 {
    let [a, b, c] = corr[r.sweep as usize];
    z + a + b * r.d[0] as f64 + c * r.d[1] as f64
}

/// Removes the part of the corrections no agreement can see: one world plane
/// (height A, slopes B, C) added to every sweep, which in each sweep's own terms is
/// a += A + B·ox + C·oy, b += B, c += C for its origin (ox, oy). The plane removed
/// is the one that leaves the smallest corrections, each weighed by its expected
/// noise: over a long drive the heights fix the tilt far better than the slopes do.
fn remove_gauge(corr: &mut [[f64; 3]], used: &[(usize, [f64; 2])], cfg: &AlignConfig) {
    let n = used.len().max(1) as f64;
    let o0 = used
        .iter()
        .fold([0.0; 2], |s, (_, o)| [s[0] + o[0] / n, s[1] + o[1] / n]);
    let wa = 1.0 / cfg.height_sigma_m.powi(2);
    let ws = 1.0 / cfg.tilt_sigma_deg.to_radians().powi(2);
    let (mut m, mut rhs) = ([0.0f64; 6], [0.0f64; 3]);
    for &(k, o) in used {
        let g = [1.0, o[0] - o0[0], o[1] - o0[1]];
        accumulate3(&mut m, &mut rhs, g, wa, corr[k][0]);
        m[3] += ws;
        m[5] += ws;
        rhs[1] += ws * corr[k][1];
        rhs[2] += ws * corr[k][2];
    }
    let Some([a, b, c]) = solve3(&m, &rhs, 1.0) else {
        return;
    };
    for &(k, o) in used {
        corr[k][0] -= a + b * (o[0] - o0[0]) + c * (o[1] - o0[1]);
        corr[k][1] -= b;
        corr[k][2] -= c;
    }
}

/// The world xy origin of each sweep that has returns, with its frame index.
fn sweep_origins(returns: &GroundReturns, frames: usize) -> Vec<(usize, [f64; 2])> {
    returns
        .origins
        .iter()
        .take(frames)
        .enumerate()
        .filter_map(|(k, o)| o.map(|o| (k, [o[0], o[1]])))
        .collect()
}

/// The consensus raster: returns grouped by cell, with the cells that enough sweeps see.
struct Cells {
    cell_of: Vec<u32>,
    /// Return indices of each cell, contiguous; `informative[c]` when enough sweeps.
    start: Vec<usize>,
    order: Vec<u32>,
    informative: Vec<bool>,
}

impl Cells {
    fn new(all: &GroundReturns, cfg: &AlignConfig) -> Self {
        let key = |r: &GroundReturn| {
            let xy = all.xy(r);
            let i = (xy[0] / cfg.cell_m).floor() as i64;
            let j = (xy[1] / cfg.cell_m).floor() as i64;
            (i, j)
        };
        let returns = &all.points;
        let mut order: Vec<u32> = (0..returns.len() as u32).collect();
        order.sort_by_key(|&i| key(&returns[i as usize]));
        let mut cell_of = vec![0u32; returns.len()];
        let (mut start, mut informative) = (vec![0usize], Vec::new());
        let mut sweeps: Vec<u32> = Vec::new();
        for (n, &i) in order.iter().enumerate() {
            let r = &returns[i as usize];
            if n > 0 && key(r) != key(&returns[order[n - 1] as usize]) {
                informative.push(distinct(&mut sweeps) >= cfg.min_sweeps);
                start.push(n);
            }
            sweeps.push(r.sweep);
            cell_of[i as usize] = start.len() as u32 - 1;
        }
        informative.push(distinct(&mut sweeps) >= cfg.min_sweeps);
        start.push(order.len());
        Self {
            cell_of,
            start,
            order,
            informative,
        }
    }

    /// The median height of each informative cell whose spread (median absolute
    /// deviation) is ground-like: at most `SPREAD` times the typical cell's. Cells on
    /// the sides of objects spread over their height, and would bias the sweeps that
    /// see only part of them.
    fn consensus(&self, z: &[f64]) -> Vec<Option<f64>> {
        const SPREAD: f64 = 3.0;
        let mut buf = Vec::new();
        let stats: Vec<Option<(f64, f64)>> = (0..self.informative.len())
            .map(|c| {
                if !self.informative[c] {
                    return None;
                }
                buf.clear();
                let ids = &self.order[self.start[c]..self.start[c + 1]];
                buf.extend(ids.iter().map(|&i| z[i as usize]));
                let med = median(&mut buf);
                for v in buf.iter_mut() {
                    *v = (*v - med).abs();
                }
                Some((med, median(&mut buf)))
            })
            .collect();
        let mut spreads: Vec<f64> = stats.iter().flatten().map(|s| s.1).collect();
        if spreads.is_empty() {
            return vec![None; stats.len()];
        }
        let limit = SPREAD * median(&mut spreads).max(0.003);
        stats
            .into_iter()
            .map(|s| s.filter(|s| s.1 <= limit).map(|s| s.0))
            .collect()
    }
}

fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The number of distinct values in `v`, which it empties.
fn distinct(v: &mut Vec<u32>) -> usize {
    v.sort_unstable();
    v.dedup();
    let n = v.len();
    v.clear();
    n
}

/// Applies the corrections to the frames' vehicle-to-world poses: a rotation about
/// the vehicle's origin by the slopes, then the height. Views with their own poses
/// (cameras that fired at other times) get the same correction, about the same point.
pub fn apply_to_poses(a: &Alignment, m: &mut Manifest) {
    for (f, &[h, bx, by]) in m.frames.iter_mut().zip(&a.corrections) {
        // z gains bx·dx + by·dy: a rotation by (by, −bx, 0) (small angles).
        let w = DVec3::new(by, -bx, 0.0);
        let rot = if w.length() > 0.0 {
            DMat3::from_axis_angle(w.normalize(), w.length())
        } else {
            DMat3::IDENTITY
        };
        let t = &f.vehicle_to_world;
        let pivot = DVec3::new(t[0][3], t[1][3], t[2][3]);
        correct(&mut f.vehicle_to_world, rot, pivot, h);
        for v in &mut f.views {
            if let Some(t) = &mut v.vehicle_to_world {
                correct(t, rot, pivot, h);
            }
        }
    }
}

/// `t` rotated by `rot` about `pivot`, then raised by `h`.
fn correct(t: &mut crate::bundle::Mat4Rows, rot: DMat3, pivot: DVec3, h: f64) {
    let r = DMat3::from_cols(
        DVec3::new(t[0][0], t[1][0], t[2][0]),
        DVec3::new(t[0][1], t[1][1], t[2][1]),
        DVec3::new(t[0][2], t[1][2], t[2][2]),
    );
    let r2 = rot * r;
    let p = DVec3::new(t[0][3], t[1][3], t[2][3]);
    let p2 = pivot + rot * (p - pivot);
    for (i, row) in t.iter_mut().take(3).enumerate() {
        for (j, v) in row.iter_mut().take(3).enumerate() {
            *v = r2.col(j)[i];
        }
        row[3] = p2[i];
    }
    t[2][3] += h;
}
