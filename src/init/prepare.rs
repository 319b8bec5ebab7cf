//! Grid → initialisation → refinement → surfels: everything before optimisation,
//! with the surfel count and memory reported before allocation.

use super::refine::{refine, RefineConfig, RefineReport};
use super::{initialise, initialise_into, InitConfig, InitResult, PoseIndex, PosePlanes};
use crate::bundle::transform::apply;
use crate::bundle::{Bundle, Mat4Rows, Problem};
use crate::grid::{Grid, GridConfig, GridError, Rect, Surfels};
use serde::Serialize;
use thiserror::Error;
use web_time::Instant;

#[derive(Clone, Debug, Default)]
pub struct PrepareConfig {
    pub grid: GridConfig,
    pub init: InitConfig,
    pub refine: RefineConfig,
    /// Use the bundle's LiDAR (when it has any) for the refinement's height cue.
    pub use_lidar: bool,
    /// Keep only the surfels inside this world rectangle (a map tile with its
    /// overlap); the lattice is the whole corridor's, so tiles share vertices.
    pub clip: Option<Rect>,
    /// Frames whose LiDAR sweeps are read (a tile's); `None` reads every sweep.
    pub frames: Option<Vec<bool>>,
}

#[derive(Debug, Error)]
pub enum PrepareError {
    #[error(transparent)]
    Grid(#[from] GridError),
    #[error(transparent)]
    Bundle(#[from] Problem),
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct PrepareReport {
    pub base_surfels: usize,
    pub added_surfels: usize,
    pub surfels: usize,
    pub bytes_per_surfel: u64,
    pub surfel_bytes: u64,
    pub index_map_bytes: usize,
    pub refine: RefineReport,
    pub grid_ms: f64,
    pub init_ms: f64,
    pub refine_ms: f64,
}

pub struct Prepared {
    pub grid: Grid,
    pub surfels: Surfels,
    pub init: InitResult,
    /// Refined base cells (lower-left fine coordinates), for the density layer.
    pub refined_cells: Vec<[i32; 2]>,
    pub report: PrepareReport,
}

/// Calls `f(frame index, vehicle-to-world pose, points in the vehicle frame)` for
/// every frame that has a LiDAR sweep.
pub fn for_each_sweep(
    b: &Bundle,
    f: impl FnMut(usize, &Mat4Rows, Vec<[f64; 3]>),
) -> Result<(), Problem> {
    for_each_sweep_of(b, None, f)
}

/// As `for_each_sweep`, over the frames marked in `frames` only (all when `None`).
pub fn for_each_sweep_of(
    b: &Bundle,
    frames: Option<&[bool]>,
    mut f: impl FnMut(usize, &Mat4Rows, Vec<[f64; 3]>),
) -> Result<(), Problem> {
    let m = &b.manifest;
    let Some(sensor) = &m.lidar else {
        return Ok(());
    };
    for (k, fr) in m.frames.iter().enumerate() {
        if frames.is_some_and(|s| !s.get(k).copied().unwrap_or(false)) {
            continue;
        }
        let Some(path) = &fr.lidar else { continue };
        let pts = b.read_lidar(path)?;
        let pts = pts
            .into_iter()
            .map(|p| apply(&sensor.lidar_to_vehicle, p.map(|v| v as f64)))
            .collect();
        f(k, &fr.vehicle_to_world, pts);
    }
    Ok(())
}

/// Every LiDAR point of the bundle in the world frame (through the bundle's poses),
/// with the index of the sweep it came from.
pub fn lidar_world(b: &Bundle) -> Result<(Vec<[f64; 3]>, Vec<u32>), Problem> {
    lidar_world_of(b, None)
}

/// As `lidar_world`, over the frames marked in `frames` only (all when `None`).
pub fn lidar_world_of(
    b: &Bundle,
    frames: Option<&[bool]>,
) -> Result<(Vec<[f64; 3]>, Vec<u32>), Problem> {
    let (mut out, mut sweep) = (Vec::new(), Vec::new());
    for_each_sweep_of(b, frames, |k, t, pts| {
        out.extend(pts.into_iter().map(|p| apply(t, p)));
        sweep.resize(out.len(), k as u32);
    })?;
    Ok((out, sweep))
}

pub fn prepare(b: &Bundle, cfg: &PrepareConfig) -> Result<Prepared, PrepareError> {
    let m = &b.manifest;
    // One logit per class of the table (dense index, not the class id).
    let classes = m.classes().len().max(1);
    let bps = Surfels::bytes_per_surfel(classes);
    let t0 = Instant::now();
    let planes = PosePlanes::from_manifest(m);
    // One polyline per drive: no corridor from one drive's end to the next's start.
    let paths: Vec<Vec<[f64; 2]>> = b
        .drives
        .iter()
        .map(|d| {
            planes.ground[d.frames.clone()]
                .iter()
                .map(|g| [g[0], g[1]])
                .collect()
        })
        .collect();
    let paths: Vec<&[[f64; 2]]> = paths.iter().map(|p| p.as_slice()).collect();
    let mut grid = Grid::corridor_of(&paths, &cfg.grid, bps, cfg.clip)?;
    let grid_ms = t0.elapsed().as_secs_f64() * 1e3;
    let t1 = Instant::now();
    let poses = PoseIndex::new(&planes);
    let mut init = initialise(&grid, &poses, &cfg.init);
    let base = grid.len();
    let init_ms = t1.elapsed().as_secs_f64() * 1e3;
    let t2 = Instant::now();
    let (lidar_pts, sweeps) = if cfg.use_lidar {
        lidar_world_of(b, cfg.frames.as_deref())?
    } else {
        Default::default()
    };
    let lidar = (!lidar_pts.is_empty()).then_some((lidar_pts.as_slice(), sweeps.as_slice()));
    let (refine_report, refined_cells) = refine(b, &mut grid, &init.z, &poses, lidar, &cfg.refine)?;
    initialise_into(&grid, &poses, &cfg.init, base, &mut init);
    let refine_ms = t2.elapsed().as_secs_f64() * 1e3;
    let surfels = Surfels::new(
        &grid,
        classes,
        &init.z,
        &init.z_hat,
        &init.q,
        &init.rotation,
    );
    let report = PrepareReport {
        base_surfels: base,
        added_surfels: grid.len() - base,
        surfels: grid.len(),
        bytes_per_surfel: bps,
        surfel_bytes: bps * grid.len() as u64,
        index_map_bytes: grid.index.bytes(),
        refine: refine_report,
        grid_ms,
        init_ms,
        refine_ms,
    };
    Ok(Prepared {
        grid,
        surfels,
        init,
        refined_cells,
        report,
    })
}
