//! Spatial tiles: the map cut into squares of the world frame, trained one after the
//! other so that the GPU holds one tile's surfels (with their optimiser state) and
//! the views that see them, never the whole map.
//!
//! A tile is its *core* (a `size_m` square on a world-aligned lattice, so tiles of
//! every drive of a place coincide) widened by `overlap_m` on each side: the *rect*
//! whose surfels it trains. The lattice of surfels is the whole corridor's (its origin
//! depends on the trajectory only), so two tiles that overlap hold the same vertices
//! there; each trains them with the views that see its rect, from any pass of any
//! drive. A place seen twice (a loop, a revisit, a second drive) is therefore one set
//! of surfels trained by every view that sees it.
//!
//! Stitching (`Stitcher`): each finished tile renders its layers over its rect; the
//! map blends them with weights that fall linearly to zero over the last
//! `2·overlap_m` of each rect's edges, so that at every pixel of an overlap two (or
//! four) tiles' weights sum to one and the colour, classes and elevation pass from
//! one tile to the next without a step. The model (`surfels.ply`) keeps each surfel
//! from the tile whose core holds it.
//!
//! The schedule (docs/ARCHITECTURE.md): tiles in the order the drive first sees
//! them, each for the default schedule over its own views (epochs over the views
//! that see it); a view that sees two tiles trains both. Tiles are independent jobs:
//! the GPU working set is bounded by the largest tile, and a tile can be run apart.

pub mod checkpoint;
mod files;
pub mod jobs;
mod model;
pub mod stitch;
mod streamed;
pub mod tile;

pub use files::{
    finish_lazy, hold, start_files, start_lazy, step_lazy, tile_files, Fetch, Fetched,
};
pub use model::FinishedModel;
pub use stitch::{Stitcher, Window};
pub use streamed::StreamedMap;
pub use tile::Tile;

use crate::bev::BevGeometry;
use crate::bundle::{Bundle, Manifest};
use crate::eval::BevRaster;
use crate::gpu::{GpuContext, GpuError};
use crate::grid::{dist2_segment, Rect};
use crate::init::align::AlignSummary;
use crate::init::PosePlanes;
use crate::optim::train::StepLoss;
use crate::reconstruct::{
    align_from, frame_xy, report, HoldoutSums, MapFinish, Outcome, ReconstructConfig,
    ReconstructError, Session, UNSEEN_OPACITY_LOGIT,
};
use crate::render::from_bundle::view_camera;
use crate::render::Params;
use checkpoint::Finished;
use serde::Serialize;
use web_time::Instant;

/// How the map is cut.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct TileConfig {
    /// Side of a tile's core, metres.
    pub size_m: f64,
    /// Each tile also trains this many metres beyond its core on every side; the
    /// layers are blended over twice this width.
    pub overlap_m: f64,
    /// Where the lattice of cores starts (world xy, metres): tile (i, j)'s core is
    /// `origin + [i, j]·size_m`. `None` until a plan settles it (`lattice_origin`).
    #[serde(default)]
    pub origin_m: Option<[f64; 2]>,
}

impl Default for TileConfig {
    fn default() -> Self {
        Self {
            size_m: DEFAULT_TILE_M,
            overlap_m: DEFAULT_OVERLAP_M,
            origin_m: None,
        }
    }
}

/// The tile size chosen when a drive is too large to map in one piece.
pub const DEFAULT_TILE_M: f64 = 96.0;
pub const DEFAULT_OVERLAP_M: f64 = 4.0;
/// The report's `stopped` of a tile with no surfels or no training view.
pub const SKIPPED: &str = "skipped: no surfels, or no training view sees them";
/// A drive whose corridor is estimated above this many surfels is tiled by default.
pub const AUTO_TILE_SURFELS: f64 = 4.0e6;

/// The estimated surfel count of a bundle's corridor (path length × width / cell).
pub fn estimated_surfels(m: &Manifest, cfg: &ReconstructConfig) -> f64 {
    let g = &cfg.prepare.grid;
    let len = m.trajectory_length_m() + 2.0 * g.half_width;
    len * 2.0 * g.half_width / (g.resolution * g.resolution)
}

/// The surfels of a tile's corridor, estimated before any work: the corridor's area
/// inside `rect` (1 m cells whose centre is within `hw` of the trajectory `ground`;
/// points over 50 m apart are taken as a gap, as between two drives) over a grid
/// cell's. Refinement only adds surfels, so a tile over the adapter's limits by this
/// count is refused before the first tile trains.
pub fn estimated_tile_surfels(ground: &[[f64; 2]], rect: &Rect, hw: f64, res: f64) -> f64 {
    const CELL: f64 = 1.0;
    const GAP_M: f64 = 50.0;
    let nx = ((rect.max[0] - rect.min[0]) / CELL).ceil().max(0.0) as usize;
    let ny = ((rect.max[1] - rect.min[1]) / CELL).ceil().max(0.0) as usize;
    let mut hit = vec![false; nx * ny];
    let pairs = ground
        .windows(2)
        .map(|w| (w[0], w[1]))
        .chain(ground.first().map(|&p| (p, p)));
    for (a, b) in pairs {
        let b = if dist2_segment(a, b, b) > GAP_M * GAP_M {
            a
        } else {
            b
        };
        let cells = |lo: f64, hi: f64, min: f64, n: usize| {
            let first = ((lo - hw - min) / CELL).floor().max(0.0) as usize;
            let end = (((hi + hw - min) / CELL).ceil().max(0.0) as usize).min(n);
            first..end
        };
        let xs = cells(a[0].min(b[0]), a[0].max(b[0]), rect.min[0], nx);
        for j in cells(a[1].min(b[1]), a[1].max(b[1]), rect.min[1], ny) {
            for i in xs.clone() {
                let c = [
                    rect.min[0] + (i as f64 + 0.5) * CELL,
                    rect.min[1] + (j as f64 + 0.5) * CELL,
                ];
                if dist2_segment(c, a, b) <= hw * hw {
                    hit[j * nx + i] = true;
                }
            }
        }
    }
    hit.iter().filter(|&&h| h).count() as f64 * CELL * CELL / (res * res)
}

/// The tiling a run uses: the one asked for, else tiles of `DEFAULT_TILE_M` when the
/// corridor is too large to map whole, else none.
pub fn choose(
    m: &Manifest,
    cfg: &ReconstructConfig,
    asked: Option<TileConfig>,
) -> Option<TileConfig> {
    asked.or_else(|| (estimated_surfels(m, cfg) > AUTO_TILE_SURFELS).then(TileConfig::default))
}

/// Cuts the bundle's corridor into tiles, each with the views that see it, in the
/// order the drive first sees them. Tiles no view sees are left out. Returns the
/// tiling with its lattice's origin settled (`t.origin_m`, else the one of
/// `lattice_origin`).
pub fn plan(b: &Bundle, cfg: &ReconstructConfig, t: &TileConfig) -> (TileConfig, Vec<Tile>) {
    let m = &b.manifest;
    let planes = PosePlanes::from_manifest(m);
    let far = cfg.train.cull.far as f64;
    let size = t.size_m.max(1.0);
    let seen = seen_corridor(b, cfg, &planes);
    let origin = t
        .origin_m
        .unwrap_or_else(|| lattice_origin(&seen, size, t.overlap_m));
    let tiling = TileConfig {
        origin_m: Some(origin),
        ..*t
    };
    let mut cells: std::collections::BTreeMap<[i64; 2], Vec<(usize, usize)>> = Default::default();
    for (view, pts) in &seen {
        for id in cells_of(pts, origin, size, t.overlap_m) {
            cells.entry(id).or_default().push(*view);
        }
    }
    let mut tiles = Vec::new();
    for (id, mut views) in cells {
        let core = Rect {
            min: [
                origin[0] + id[0] as f64 * size,
                origin[1] + id[1] as f64 * size,
            ],
            max: [
                origin[0] + (id[0] + 1) as f64 * size,
                origin[1] + (id[1] + 1) as f64 * size,
            ],
        };
        let rect = core.grow(t.overlap_m);
        let mut near_frames = vec![false; m.frames.len()];
        let mut near_xy = Vec::new();
        for (f, g) in planes.ground.iter().enumerate() {
            if rect.dist2([g[0], g[1]]) <= (far + 5.0).powi(2) {
                near_frames[f] = true;
                near_xy.push(frame_xy(m, f));
            }
        }
        views.retain(|&(f, _)| near_frames[f]);
        if views.is_empty() {
            continue;
        }
        tiles.push(Tile {
            id,
            core,
            rect,
            near_frames,
            views,
            extent: crate::optim::extent_of(&near_xy),
        });
    }
    tiles.sort_by_key(|t| (t.views[0], t.id));
    (tiling, tiles)
}

/// A view (frame, view) and the corridor's ground samples it sees.
pub type Seen = ((usize, usize), Vec<[f64; 2]>);

/// Every view (frame, view), in order, with the corridor's ground samples it sees:
/// points on a lattice of at most 1 m within the half-width of any drive's ground
/// path.
fn seen_corridor(b: &Bundle, cfg: &ReconstructConfig, planes: &PosePlanes) -> Vec<Seen> {
    let m = &b.manifest;
    let hw = cfg.prepare.grid.half_width;
    let cull = &cfg.train.cull;
    let step = (hw / 2.0).clamp(0.25, 1.0);
    // The samples, bucketed in squares of `BUCKET` metres.
    const BUCKET: f64 = 16.0;
    let key = |p: [f64; 2]| {
        [
            (p[0] / BUCKET).floor() as i64,
            (p[1] / BUCKET).floor() as i64,
        ]
    };
    let mut lattice = std::collections::BTreeSet::new();
    for d in &b.drives {
        let g = &planes.ground[d.frames.clone()];
        let ends = |k: usize| [g[k][0], g[k][1]];
        let segs = (0..g.len().saturating_sub(1)).map(|k| (ends(k), ends(k + 1)));
        let single = (g.len() == 1).then(|| (ends(0), ends(0)));
        for (a, c) in segs.chain(single) {
            let lo = |k: usize| ((a[k].min(c[k]) - hw) / step).floor() as i64;
            let hi = |k: usize| ((a[k].max(c[k]) + hw) / step).ceil() as i64;
            for i in lo(0)..=hi(0) {
                for j in lo(1)..=hi(1) {
                    let p = [(i as f64 + 0.5) * step, (j as f64 + 0.5) * step];
                    if dist2_segment(p, a, c) <= hw * hw {
                        lattice.insert([i, j]);
                    }
                }
            }
        }
    }
    let mut buckets: std::collections::BTreeMap<[i64; 2], Vec<[f64; 2]>> = Default::default();
    for [i, j] in lattice {
        let p = [(i as f64 + 0.5) * step, (j as f64 + 0.5) * step];
        buckets.entry(key(p)).or_default().push(p);
    }
    // A view sees no farther than its culling box's far corner.
    let reach = (cull.far as f64).hypot(cull.half_width.min(cull.far) as f64) + 5.0;
    let r = (reach / BUCKET).ceil() as i64;
    let mut seen = Vec::new();
    for (f, fr) in m.frames.iter().enumerate() {
        let g = planes.ground[f];
        let k = key([g[0], g[1]]);
        let near: Vec<[f64; 2]> = (k[0] - r..=k[0] + r)
            .flat_map(|i| (k[1] - r..=k[1] + r).map(move |j| [i, j]))
            .filter_map(|c| buckets.get(&c))
            .flatten()
            .copied()
            .filter(|p| (p[0] - g[0]).hypot(p[1] - g[1]) <= reach)
            .collect();
        for v in 0..fr.views.len() {
            seen.push(((f, v), seen_by(m, f, v, g, &near, cull)));
        }
    }
    seen
}

/// The lattice cells whose rect (the core widened by `overlap`) holds any of `pts`.
fn cells_of(pts: &[[f64; 2]], origin: [f64; 2], size: f64, overlap: f64) -> Vec<[i64; 2]> {
    let span = |v: f64, o: f64| {
        ((v - o - overlap) / size).floor() as i64..=((v - o + overlap) / size).floor() as i64
    };
    let mut cells = Vec::new();
    for p in pts {
        for i in span(p[0], origin[0]) {
            for j in span(p[1], origin[1]) {
                cells.push([i, j]);
            }
        }
    }
    cells.sort_unstable();
    cells.dedup();
    cells
}

/// Where the tile lattice starts: of the origins on a quarter-tile lattice, the one
/// whose tiles make the fewest (view, tile) pairs, i.e. the fewest steps. A road that
/// runs along a lattice line would otherwise be trained twice by every view that sees
/// it, once in the tile on each side (`long` at 500 m: 2.4 tiles per view).
pub fn lattice_origin(seen: &[Seen], size: f64, overlap: f64) -> [f64; 2] {
    let mut best = ([0.0, 0.0], usize::MAX);
    for k in 0..16 {
        let o = [(k % 4) as f64 * size / 4.0, (k / 4) as f64 * size / 4.0];
        let pairs: usize = seen
            .iter()
            .map(|(_, pts)| cells_of(pts, o, size, overlap).len())
            .sum();
        if pairs < best.1 {
            best = (o, pairs);
        }
    }
    best.0
}

/// The ground samples (at the frame's ground height) view `v` of frame `f` sees:
/// inside the rasteriser's culling box and within the image, with a 10 % margin for
/// relief.
fn seen_by(
    m: &Manifest,
    f: usize,
    v: usize,
    ground: [f64; 3],
    samples: &[[f64; 2]],
    cull: &crate::render::CullConfig,
) -> Vec<[f64; 2]> {
    let Some(cam) = view_camera(m, f, v, ground, [0.0, 0.0]) else {
        return Vec::new();
    };
    let w = &cam.world_to_cam;
    let (mw, mh) = (0.1 * cam.width as f32, 0.1 * cam.height as f32);
    samples
        .iter()
        .copied()
        .filter(|s| {
            let p = [(s[0] - ground[0]) as f32, (s[1] - ground[1]) as f32, 0.0f32];
            let c = |r: usize| w[r][0] * p[0] + w[r][1] * p[1] + w[r][2] * p[2] + w[r][3];
            let (x, y, z) = (c(0), c(1), c(2));
            if !(z >= cull.near && z <= cull.far && x.abs() <= cull.half_width) {
                return false;
            }
            let u = cam.fx * x / z + cam.cx;
            let vv = cam.fy * y / z + cam.cy;
            u >= -mw && u <= cam.width as f32 + mw && vv >= -mh && vv <= cam.height as f32 + mh
        })
        .collect()
}

/// What one tile did (report.json's `tiles`).
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct TileReport {
    pub name: String,
    pub core: Option<Rect>,
    pub rect: Option<Rect>,
    pub surfels: usize,
    pub added_surfels: usize,
    pub training_views: usize,
    pub holdout_views: usize,
    pub steps: usize,
    pub train_ms: f64,
    pub prepare_ms: f64,
    pub bev_ms: f64,
    pub loss_last: StepLoss,
    pub position_refreshes: usize,
    pub pair_overflows: usize,
    pub surfels_with_lidar: usize,
    pub smoothness_edges: usize,
    /// Peak GPU memory the device allocated while this tile ran (native Vulkan).
    pub peak_gpu_bytes: Option<u64>,
    /// Why the tile was skipped (no surfels or no view) or stopped.
    pub stopped: Option<String>,
    /// Restored from a checkpoint of an earlier run (`--resume`), not trained here.
    #[serde(default)]
    pub restored: bool,
    /// The views' own gains (report.json's `frame_gains`).
    #[serde(default)]
    pub frame_gains: serde_json::Value,
    /// The process's resident memory as the tile was added to the map (natively).
    #[serde(default)]
    pub host_bytes: Option<u64>,
}

/// A reconstruction over tiles, stepped like a `Session` (one tile, the whole map,
/// when the run is not tiled): the CLI and the page drive it the same way.
pub struct TiledRun {
    pub cfg: ReconstructConfig,
    pub tiling: Option<TileConfig>,
    pub tiles: Vec<Tile>,
    /// The session of the tile being trained; after the run, the last tile's.
    pub session: Option<Session>,
    /// Tiles started so far (the current one included).
    pub started: usize,
    pub reports: Vec<TileReport>,
    pub alignment: Option<AlignSummary>,
    pub align_ms: f64,
    /// Time to stitch and score the map (`finish`).
    pub eval_ms: f64,
    /// The map's geometry (the truth raster's, or the corridor's bounding box).
    pub geometry: BevGeometry,
    truth: Option<BevRaster>,
    stitch: Stitcher,
    recorded: bool,
    /// Every finished tile's core surfels, in the frame shifted by `model_origin`
    /// (held, or natively left in the tiles' checkpoints: `spill_models`).
    model: FinishedModel,
    pub model_origin: [f64; 3],
    holdout: HoldoutSums,
    holdout_views: usize,
    z_change: (f64, usize),
    initial_error: (f64, usize),
    ctx: GpuContext,
    steps_done: usize,
    planned_steps: usize,
    pub peak_gpu_bytes: Option<u64>,
    /// The first tile that failed, and why (the run stops there; the finished
    /// tiles are kept).
    pub failed: Option<String>,
    /// The plan index of the tile that failed (`retry` trains it again).
    failed_index: Option<usize>,
    /// Per planned tile: finished (trained or restored).
    done: Vec<bool>,
    /// Encode a checkpoint of every tile as it finishes (`take_checkpoint`).
    pub checkpoints: bool,
    pending: std::collections::VecDeque<(String, Vec<u8>)>,
    /// Natively: where checkpoints are written as they are encoded
    /// (`write_checkpoints_into`) instead of queued in memory.
    checkpoint_dir: Option<std::path::PathBuf>,
    /// Hash of the manifest, the settings and the plan: checkpoints carry it.
    pub fingerprint: u64,
    /// Fault injection for tests of failure and resume: the GPU device is destroyed
    /// as the tile of this plan index starts (`rogs reconstruct --fault-tile`).
    pub fault_tile: Option<usize>,
    /// The pose corrections between two tiles' sessions (each session holds them
    /// while it trains).
    poses: Option<crate::optim::pose::PoseRefiner>,
    /// The map's whole layers would exceed the budget: it is written block by block
    /// (`finish_streamed`), never whole.
    pub streamed: bool,
    /// The blend's memory as of the last finished tile (report.json's `blend`).
    blend: serde_json::Value,
}

/// The map's layers may take this many times the surfel grid's memory budget.
pub const MAP_BUDGET_PER_GRID_BUDGET: u64 = 4;

/// Where files are written (`MapConfig::stream`), a tiled map whose whole layers
/// would take more than this is finished block by block even under the budget
/// (`MapFinish::Auto`), so that the finish of a long drive holds a row of blocks,
/// not the map (1 GiB).
pub const STREAM_OVER_BYTES: u64 = 1 << 30;

impl TiledRun {
    /// Aligns the poses (once, for every tile), plans the tiles and prepares the
    /// first one.
    pub async fn new(
        b: &mut Bundle,
        cfg: ReconstructConfig,
        tiling: Option<TileConfig>,
        ctx: GpuContext,
    ) -> Result<Self, ReconstructError> {
        Self::new_with(b, cfg, tiling, ctx, None).await
    }

    /// As `new`, with the LiDAR's ground returns already gathered (`returns`), so
    /// that the alignment reads no sweep (a lazily read bundle gathers them a batch
    /// of sweeps at a time, `align::gather_ground_returns`).
    pub async fn new_with(
        b: &mut Bundle,
        cfg: ReconstructConfig,
        tiling: Option<TileConfig>,
        ctx: GpuContext,
        returns: Option<crate::init::align::GroundReturns>,
    ) -> Result<Self, ReconstructError> {
        crate::reconstruct::check_cameras_fit(&b.manifest, &ctx)?;
        let t = Instant::now();
        let alignment = align_from(b, &cfg, returns)?;
        let align_ms = t.elapsed().as_secs_f64() * 1e3;
        let b: &Bundle = b;
        let truth = BevRaster::from_bundle(b)?;
        let min_alpha = cfg.train.loss.min_alpha;
        let channels = b.manifest.classes().len().max(1);
        let epochs = if cfg.baseline_ipm {
            0
        } else {
            cfg.train.epochs
        };
        let max_steps = cfg.train.max_steps.unwrap_or(usize::MAX);
        let per_tile = move |views: usize| (views * epochs).min(max_steps);
        let mut run = Self {
            tiling,
            tiles: Vec::new(),
            session: None,
            started: 0,
            reports: Vec::new(),
            alignment,
            align_ms,
            eval_ms: 0.0,
            geometry: BevGeometry::around(std::iter::empty(), 1.0, 0.0),
            stitch: Stitcher::new(BevGeometry::around(std::iter::empty(), 1.0, 0.0), 1, 0.0),
            truth,
            recorded: false,
            model: FinishedModel::new(channels),
            model_origin: [0.0; 3],
            holdout: HoldoutSums::default(),
            holdout_views: 0,
            z_change: (0.0, 0),
            initial_error: (0.0, 0),
            ctx,
            steps_done: 0,
            planned_steps: 0,
            peak_gpu_bytes: None,
            failed: None,
            failed_index: None,
            done: Vec::new(),
            checkpoints: false,
            checkpoint_dir: None,
            pending: Default::default(),
            fingerprint: 0,
            fault_tile: None,
            poses: None,
            streamed: false,
            blend: serde_json::Value::Null,
            cfg,
        };
        match tiling {
            None => {
                let s = Session::build(b, run.cfg.clone(), run.ctx.clone(), None).await?;
                run.geometry = s.geometry(run.truth.as_ref());
                run.planned_steps = s.total_steps();
                run.model_origin = s.origin;
                run.session = Some(s);
                run.started = 1;
            }
            Some(t) => {
                let (t, tiles) = plan(b, &run.cfg, &t);
                run.tiling = Some(t);
                run.tiles = tiles;
                if run.tiles.is_empty() {
                    return Err(ReconstructError::NoViews);
                }
                run.planned_steps = run.tiles.iter().map(|t| per_tile(t.views.len())).sum();
                let res = run.cfg.prepare.grid.resolution;
                let hw = run.cfg.prepare.grid.half_width;
                let pts = PosePlanes::from_manifest(&b.manifest).ground;
                let ground: Vec<[f64; 2]> = pts.iter().map(|g| [g[0], g[1]]).collect();
                // Every tile's model must fit the adapter: checked now, not when the
                // tile comes up after hours of the others.
                for tile in &run.tiles {
                    let n = estimated_tile_surfels(&ground, &tile.rect, hw, res);
                    crate::optim::train::check_fits(&run.ctx, n as usize, channels, 0).map_err(
                        |e| {
                            let why = match e {
                                GpuError::Validation(s) => s,
                                other => other.to_string(),
                            };
                            ReconstructError::Tile {
                                tile: tile.name(),
                                source: Box::new(ReconstructError::Gpu(GpuError::Validation(
                                    format!(
                                        "estimated before any work: {why}; or smaller tiles (--tile-m {:.0})",
                                        t.size_m / 2.0
                                    ),
                                ))),
                            }
                        },
                    )?;
                }
                let corridor = BevGeometry::around(ground.iter().copied(), res, hw + res);
                run.geometry = match &run.truth {
                    Some(t) => BevGeometry::of_raster(t).covering(&corridor),
                    None => corridor,
                };
                run.model_origin = [run.geometry.origin[0], run.geometry.origin[1], 0.0];
            }
        }
        // The map's layers are held whole after stitching: a map whose whole layers
        // would not fit is streamed (tiled, where the caller writes files), or refused
        // before anything is allocated.
        let g = run.geometry;
        let bytes = Stitcher::bytes(&g, channels);
        let budget = run
            .cfg
            .map
            .budget_bytes
            .unwrap_or(MAP_BUDGET_PER_GRID_BUDGET * run.cfg.prepare.grid.memory_budget);
        let can_stream = run.cfg.map.stream && run.tiling.is_some();
        let stream_over = match run.cfg.map.finish {
            MapFinish::Auto => STREAM_OVER_BYTES,
            MapFinish::Blocks => 0,
            MapFinish::Whole => u64::MAX,
        };
        if bytes > budget || (can_stream && bytes > stream_over) {
            let probe = Stitcher::new(g, channels, min_alpha);
            let windows: Vec<Window> = run
                .tiles
                .iter()
                .filter_map(|t| probe.window(&t.rect))
                .collect();
            let held = Stitcher::block_bytes(&g, channels, windows.iter());
            if can_stream && held <= budget {
                run.streamed = true;
            } else if bytes > budget {
                return Err(ReconstructError::MapTooLarge {
                    width: g.width,
                    height: g.height,
                    bytes,
                    budget,
                    resolution: g.resolution,
                    blocks: can_stream.then_some(held),
                });
            }
        }
        run.stitch = Stitcher::new(run.geometry, channels, min_alpha);
        run.done = vec![false; run.tiles.len()];
        let plan: Vec<_> = run
            .tiles
            .iter()
            .map(|t| (t.name(), t.views.clone()))
            .collect();
        // How the map is held does not change it: runs that hold it differently
        // resume each other's tiles.
        let cfg = ReconstructConfig {
            map: Default::default(),
            ..run.cfg.clone()
        };
        run.fingerprint = checkpoint::fnv1a(&[
            &serde_json::to_vec(&b.manifest).unwrap_or_default(),
            format!("{cfg:?}").as_bytes(),
            format!("{:?} {:?} {plan:?}", run.tiling, run.geometry).as_bytes(),
        ]);
        Ok(run)
    }

    pub fn total_steps(&self) -> usize {
        self.planned_steps.max(self.steps_done)
    }

    /// Whether the map is scored against a truth (it then has an error layer).
    pub fn has_truth(&self) -> bool {
        self.truth.is_some()
    }

    pub fn steps_done(&self) -> usize {
        self.steps_done
    }

    /// Tiles in the plan (1 when the run is not tiled).
    pub fn tile_count(&self) -> usize {
        self.tiles.len().max(1)
    }

    /// The tile being trained (its index in the plan and its name).
    pub fn current_tile(&self) -> Option<(usize, String)> {
        let k = self.started.checked_sub(1)?;
        self.tiles.get(k).map(|t| (k, t.name()))
    }

    pub fn surfels(&self) -> usize {
        self.reports.iter().map(|r| r.surfels).sum::<usize>()
            + match (&self.session, self.recorded) {
                (Some(s), false) => s.prepare_report.surfels,
                _ => 0,
            }
    }

    /// One optimisation step of the current tile, moving on to the next tile when
    /// it is done; `Ok(None)` once every tile is trained. A tile's failure is
    /// returned with the tile's name; the tiles finished before it are kept.
    pub async fn step(&mut self, b: &Bundle) -> Result<Option<StepLoss>, ReconstructError> {
        loop {
            if self.failed.is_some() {
                return Ok(None);
            }
            if self.session.is_none() || self.recorded {
                if !self.start_next(b).await? {
                    return Ok(None);
                }
                continue;
            }
            if self.fault_tile.is_some() && self.fault_tile == self.started.checked_sub(1) {
                // The injected fault is a real one: the device is destroyed and the
                // step below fails as it would after a driver reset.
                self.fault_tile = None;
                self.ctx.lose();
            }
            let Some(s) = self.session.as_mut() else {
                return Ok(None);
            };
            if s.is_done() {
                if self.tiling.is_none() {
                    return Ok(None);
                }
                self.record(b).await?;
                continue;
            }
            let r = s.step(b).await;
            sample_gpu(&self.ctx, &mut self.peak_gpu_bytes);
            match r {
                Ok(Some(l)) => {
                    self.steps_done += 1;
                    return Ok(Some(l));
                }
                Ok(None) => continue,
                // Nothing was changed: the step runs again once the file is there.
                Err(e) if e.not_loaded().is_some() => return Err(e),
                Err(e) => return Err(self.fail(e)),
            }
        }
    }

    fn fail(&mut self, e: ReconstructError) -> ReconstructError {
        // Whatever failed first on a lost device (a read-back, a mapping), the cause
        // to tell is the loss.
        let e = match self.ctx.check() {
            Err(lost) if self.ctx.is_lost() => ReconstructError::Gpu(lost),
            _ => e,
        };
        match self.current_tile() {
            Some((k, name)) => {
                // Bad input fails again the same way: only the machine's failures retry.
                self.failed_index = (!e.is_input()).then_some(k);
                let msg = format!(
                    "tile {name} failed: {e}; the {} tiles finished before it are kept",
                    self.reports.iter().filter(|r| r.stopped.is_none()).count()
                );
                self.failed = Some(msg);
                ReconstructError::Tile {
                    tile: name,
                    source: Box::new(e),
                }
            }
            None => {
                self.failed = Some(e.to_string());
                e
            }
        }
    }

    /// Starts the next tile with surfels and views; false when none is left.
    async fn start_next(&mut self, b: &Bundle) -> Result<bool, ReconstructError> {
        while self.started < self.tiles.len() {
            let tile = self.tiles[self.started].clone();
            self.started += 1;
            if self.done.get(self.started - 1).copied().unwrap_or(false) {
                continue;
            }
            self.park_poses();
            self.session = None;
            self.recorded = false;
            self.ctx.start_tile();
            match Session::build(b, self.cfg.clone(), self.ctx.clone(), Some(&tile)).await {
                Ok(mut s) => {
                    if let Some(p) = self.poses.take() {
                        s.poses = Some(p);
                    }
                    self.session = Some(s);
                    sample_gpu(&self.ctx, &mut self.peak_gpu_bytes);
                    return Ok(true);
                }
                Err(ReconstructError::EmptyTile) => {
                    // Its planned steps never come: the total follows what runs.
                    let planned = self.planned_steps_of(&tile);
                    self.planned_steps = self.planned_steps.saturating_sub(planned);
                    let skipped = Finished {
                        index: self.started - 1,
                        report: TileReport {
                            name: tile.name(),
                            core: Some(tile.core),
                            rect: Some(tile.rect),
                            stopped: Some(SKIPPED.into()),
                            ..Default::default()
                        },
                        ..Default::default()
                    };
                    // A skipped tile is finished too: its checkpoint says so, and a
                    // resumed run or a merge of tile jobs does not try it again.
                    if self.checkpoints {
                        self.keep_checkpoint(&skipped)?;
                    }
                    self.apply(skipped, None);
                }
                Err(e) if e.not_loaded().is_some() => {
                    // Not a failure: this tile starts again once its files are there.
                    self.started -= 1;
                    return Err(e);
                }
                Err(e) => return Err(self.fail(e)),
            }
        }
        Ok(false)
    }

    /// Renders the current tile's layers into the map and keeps its core surfels.
    async fn record(&mut self, b: &Bundle) -> Result<(), ReconstructError> {
        let index = self.started.checked_sub(1);
        let window = self.window_of(index);
        let tile = index.and_then(|k| self.tiles.get(k)).cloned();
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        let t0 = Instant::now();
        let p = s.model().await?;
        // The model first: a failure in the BEV below must not lose it.
        let keep: Vec<usize> = (0..p.len())
            .filter(|&k| {
                let xy = [
                    p.pos[k][0] as f64 + s.origin[0],
                    p.pos[k][1] as f64 + s.origin[1],
                ];
                tile.as_ref().is_none_or(|t| t.core.contains(xy))
            })
            .collect();
        let shift = [0, 1, 2].map(|c| (s.origin[c] - self.model_origin[c]) as f32);
        let mut done = Finished {
            index: index.unwrap_or(0),
            model: Params {
                channels: p.channels,
                ..Default::default()
            },
            ..Default::default()
        };
        append(&mut done.model, &p, &keep, shift);
        for &k in &keep {
            let dz = (p.pos[k][2] - s.initial.pos[k][2]) as f64;
            done.z_change.0 += dz * dz;
        }
        done.z_change.1 = keep.len();
        let seen: Vec<usize> = keep
            .iter()
            .copied()
            .filter(|&k| p.opacity[k] > UNSEEN_OPACITY_LOGIT + 1.0)
            .collect();
        done.centres = seen
            .iter()
            .map(|&k| [0, 1, 2].map(|c| p.pos[k][c] as f64 + s.origin[c]))
            .collect();
        if let Some(t) = &self.truth {
            done.initial_error = s.initial_error(&seen, t);
        }
        if let Some(w) = window {
            done.layers = Some(s.layers(&p, &w.geometry, &mut |_, _| {}).await?);
        }
        s.holdout_sums(b, &mut done.holdout).await?;
        done.holdout_views = s.holdout_views.len();
        sample_gpu(&self.ctx, &mut self.peak_gpu_bytes);
        let bev_ms = t0.elapsed().as_secs_f64() * 1e3;
        s.timings.bev_ms += bev_ms;
        done.report = TileReport {
            name: tile.as_ref().map_or("all".into(), |t| t.name()),
            core: tile.as_ref().map(|t| t.core),
            rect: tile.as_ref().map(|t| t.rect),
            surfels: s.prepare_report.surfels,
            added_surfels: s.prepare_report.added_surfels,
            training_views: s.train_views.len(),
            holdout_views: s.holdout_views.len(),
            steps: s.steps_done(),
            train_ms: s.timings.train_ms,
            prepare_ms: s.timings.prepare_ms,
            bev_ms,
            loss_last: s.losses.last().copied().unwrap_or_default(),
            position_refreshes: s.trainer.position_refreshes,
            pair_overflows: s.trainer.pair_overflows,
            surfels_with_lidar: s.with_lidar,
            smoothness_edges: s.edges,
            peak_gpu_bytes: self.peak_gpu_bytes,
            stopped: s.stopped.clone(),
            restored: false,
            frame_gains: crate::reconstruct::frame_gain_summary(&s.frame_gains),
            host_bytes: None,
        };
        let mut file = None;
        if self.checkpoints && tile.is_some() && s.stopped.is_none() {
            let name = format!("{}{}", done.report.name, checkpoint::SUFFIX);
            file = match self.keep_checkpoint(&done)? {
                Some(written) => Some(written),
                None => self.model.spill_to.as_ref().map(|d| d.join(&name)),
            };
        }
        self.apply(done, file);
        self.recorded = true;
        Ok(())
    }

    /// The window of the map that tile `index` renders (the whole map untiled).
    fn window_of(&self, index: Option<usize>) -> Option<Window> {
        match index.and_then(|k| self.tiles.get(k)) {
            Some(t) if self.tiling.is_some() => self.stitch.window(&t.rect),
            _ => Some(Window {
                col: 0,
                row: 0,
                geometry: self.geometry,
            }),
        }
    }

    /// Adds a finished tile to the map, the model, the metrics and the report;
    /// `file`: its checkpoint's path, where its surfels may be left (`spill_models`).
    fn apply(&mut self, f: Finished, file: Option<std::path::PathBuf>) {
        let tile = self.tiling.and(self.tiles.get(f.index));
        if let (Some(l), Some(w)) = (&f.layers, self.window_of(Some(f.index))) {
            let blend = tile.map(|t| (t.rect, 2.0 * self.tiling.map_or(0.0, |c| c.overlap_m)));
            self.stitch.add(&w, l, blend);
        }
        self.model.add(&f.model, &f.centres, file);
        self.z_change.0 += f.z_change.0;
        self.z_change.1 += f.z_change.1;
        self.initial_error.0 += f.initial_error.0;
        self.initial_error.1 += f.initial_error.1;
        self.holdout.merge(&f.holdout);
        self.holdout_views += f.holdout_views;
        if let Some(d) = self.done.get_mut(f.index) {
            *d = true;
        }
        self.seal_finished_blocks();
        let mut report = f.report;
        crate::mem::release_free_memory();
        report.host_bytes = crate::mem::host_bytes();
        self.reports.push(report);
    }

    /// Seals the blend's blocks that no unfinished tile renders into: the blend
    /// holds the blocks around the tiles still to come, not the whole drive's.
    fn seal_finished_blocks(&mut self) {
        if self.tiling.is_none() {
            return;
        }
        self.stitch.note_peak();
        let mut open = std::collections::BTreeSet::new();
        for (k, t) in self.tiles.iter().enumerate() {
            if self.done.get(k).is_some_and(|&d| !d) {
                if let Some(w) = self.stitch.window(&t.rect) {
                    open.extend(Stitcher::blocks_of(&w));
                }
            }
        }
        self.stitch.seal_except(&open);
        let (open, sealed) = self.stitch.counts();
        self.blend = serde_json::json!({
            "peak_held_bytes": self.stitch.peak_held_bytes,
            "held_bytes": self.stitch.held_bytes(),
            "blocks_open": open,
            "blocks_sealed": sealed,
        });
    }

    /// Keeps the checkpoint of a finished (or skipped) tile: natively straight into
    /// its file (`write_checkpoints_into`; returns the path), else queued for
    /// `take_checkpoint`.
    fn keep_checkpoint(&mut self, f: &Finished) -> Result<Option<std::path::PathBuf>, GpuError> {
        let name = format!("{}{}", f.report.name, checkpoint::SUFFIX);
        if let Some(dir) = &self.checkpoint_dir {
            return checkpoint::write_file(f, self.fingerprint, dir, &name)
                .map(Some)
                .map_err(GpuError::Failed);
        }
        let bytes = checkpoint::encode(f, self.fingerprint).map_err(GpuError::Failed)?;
        self.pending.push_back((name, bytes));
        Ok(None)
    }

    /// Natively: each checkpoint is written into `dir` as it is encoded, where
    /// `restore_file` finds it, instead of being held whole in memory until
    /// `take_checkpoint` (a 5 cm tile's is tens of MiB).
    pub fn write_checkpoints_into(&mut self, dir: std::path::PathBuf) {
        self.checkpoint_dir = Some(dir);
    }

    /// The checkpoint of a tile finished (or skipped) since the last call, once
    /// (`checkpoints` on): its file name (`x3_y-2.tile`) and bytes. Call until `None`
    /// and write each where `restore` will find it.
    pub fn take_checkpoint(&mut self) -> Option<(String, Vec<u8>)> {
        self.pending.pop_front()
    }

    /// Adds a tile finished by an earlier run of the same bundles and settings from
    /// its checkpoint (before the first step); that tile is not trained again.
    /// Returns the tile's name. A checkpoint of another run, of a tile not in the
    /// plan, or a damaged one is refused with what is wrong and changes nothing.
    pub fn restore(&mut self, bytes: &[u8]) -> Result<String, ReconstructError> {
        self.restore_file(bytes, None)
    }

    /// As `restore`, from the checkpoint file at `path` (read into `bytes`): with
    /// `spill_models` the tile's surfels are left there.
    pub fn restore_file(
        &mut self,
        bytes: &[u8],
        path: Option<&std::path::Path>,
    ) -> Result<String, ReconstructError> {
        let bad = |problem: String| ReconstructError::Checkpoint(problem);
        if self.tiling.is_none() {
            return Err(bad(
                "this run is not tiled: only tiled runs resume (--tile-m)".into(),
            ));
        }
        if self.started > 0 {
            return Err(bad(
                "checkpoints are restored before the run's first step".into()
            ));
        }
        let (mut f, fp) = checkpoint::decode(bytes).map_err(bad)?;
        if fp != self.fingerprint {
            return Err(bad(format!(
                "it was made by a run of other bundles or settings (fingerprint {fp:016x}, this run's is {:016x}); \
                 run with the same bundles and options, or delete it to train its tile again",
                self.fingerprint
            )));
        }
        let Some(tile) = self.tiles.get(f.index) else {
            return Err(bad(format!("tile {} is not in this run's plan", f.index)));
        };
        let name = tile.name();
        if f.report.name != name {
            return Err(bad(format!(
                "it names tile {}, the plan's tile {} is {name}",
                f.report.name, f.index
            )));
        }
        if self.done.get(f.index).copied().unwrap_or(false) {
            return Err(bad(format!("tile {name} was restored twice")));
        }
        let skipped = f.report.stopped.as_deref() == Some(SKIPPED) && f.layers.is_none();
        let want = self
            .stitch
            .window(&tile.rect)
            .filter(|_| !skipped)
            .map(|w| (w.geometry.width, w.geometry.height));
        let got = f.layers.as_ref().map(|l| (l.bev.width, l.bev.height));
        let channels_ok = f
            .layers
            .as_ref()
            .is_none_or(|l| l.bev.channels == self.model.channels())
            && (f.model.is_empty() || f.model.channels == self.model.channels());
        if want != got || !channels_ok {
            return Err(bad(format!(
                "tile {name}'s layers are {got:?} px, the map's window for it is {want:?} px"
            )));
        }
        let planned = self.planned_steps_of(tile);
        self.planned_steps = self.planned_steps.saturating_sub(planned);
        f.report.restored = true;
        let file = path.filter(|_| self.model.spill_to.is_some());
        self.apply(f, file.map(|p| p.to_path_buf()));
        Ok(name)
    }

    /// Narrows the run to the tile of plan index `index` (a tile job of a plan,
    /// `rogs reconstruct --plan --tile`): the others are neither trained nor
    /// stitched, and the run's steps are that tile's. Before the first step.
    pub fn only(&mut self, index: usize) -> Result<(), ReconstructError> {
        let Some(tile) = self.tiles.get(index) else {
            return Err(ReconstructError::Checkpoint(format!(
                "tile {index} is not in this run's plan of {} tiles",
                self.tiles.len()
            )));
        };
        if self.started > 0 {
            return Err(ReconstructError::Checkpoint(
                "a run is narrowed to one tile before its first step".into(),
            ));
        }
        self.planned_steps = self.planned_steps_of(tile);
        for (k, d) in self.done.iter_mut().enumerate() {
            *d = k != index;
        }
        Ok(())
    }

    /// The steps the schedule gives tile `t` (its views × epochs, within the limit).
    fn planned_steps_of(&self, t: &Tile) -> usize {
        let epochs = if self.cfg.baseline_ipm {
            0
        } else {
            self.cfg.train.epochs
        };
        (t.views.len() * epochs).min(self.cfg.train.max_steps.unwrap_or(usize::MAX))
    }

    /// After a tile failed for a reason of the machine (a lost device, not bad
    /// input): clears the failure so that the next `step` trains that tile again
    /// from the start (the tiles finished before it are kept). A lost device is
    /// replaced by a new one first (the finished tiles are host data). False when
    /// there is nothing to retry.
    pub async fn retry(&mut self) -> Result<bool, ReconstructError> {
        if self.failed_index.is_none() {
            return Ok(false);
        }
        if self.ctx.is_lost() {
            self.park_poses();
            self.session = None;
            self.ctx = GpuContext::new().await?;
        }
        Ok(self.retry_tile())
    }

    /// True once the run's GPU device is lost.
    pub fn device_lost(&self) -> bool {
        self.ctx.is_lost()
    }

    /// Frees the run's GPU memory at once (its device is destroyed): for an owner
    /// that is done with the run (the page, before its next run).
    pub fn release_gpu(&self) {
        self.ctx.release();
    }

    fn retry_tile(&mut self) -> bool {
        let Some(k) = self.failed_index.take() else {
            return false;
        };
        self.failed = None;
        self.park_poses();
        self.session = None;
        self.recorded = false;
        self.started = k;
        true
    }

    /// Takes the pose corrections out of the current session before it is dropped.
    fn park_poses(&mut self) {
        if let Some(p) = self.session.as_mut().and_then(|s| s.poses.take()) {
            self.poses = Some(p);
        }
    }

    /// The pose corrections so far (with `--refine-poses`).
    pub fn pose_refiner(&self) -> Option<&crate::optim::pose::PoseRefiner> {
        self.session
            .as_ref()
            .and_then(|s| s.poses.as_ref())
            .or(self.poses.as_ref())
    }

    /// Tiles finished (trained here or restored from checkpoints).
    pub fn tiles_done(&self) -> usize {
        self.done.iter().filter(|&&d| d).count()
    }

    /// The model of the tiles finished so far, and its origin.
    pub fn model(&self) -> (&FinishedModel, [f64; 3]) {
        (&self.model, self.model_origin)
    }

    /// Natively: the surfels of each tile checkpointed into `dir` (where the caller
    /// writes `take_checkpoint`'s files before the model is written) stay there
    /// instead of in memory; `FinishedModel::write` reads them back.
    pub fn spill_models(&mut self, dir: std::path::PathBuf) {
        self.model.spill_to = Some(dir);
    }

    /// The map: the blended layers of every finished tile, scored. Tiles not run
    /// (after a failure) are holes in it.
    pub async fn finish(
        &mut self,
        b: &Bundle,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Outcome, ReconstructError> {
        if self.session.is_some() && !self.recorded && self.failed.is_none() {
            self.record(b).await?;
        }
        progress(1, 1);
        let t = Instant::now();
        let g = self.geometry;
        let min_alpha = self.cfg.train.loss.min_alpha;
        let channels = self.model.channels();
        let stitch = std::mem::replace(&mut self.stitch, Stitcher::new(g, channels, min_alpha));
        let layers = stitch.finish();
        let holdout = self.holdout.holdout(self.holdout_views);
        let centres = self.model.centres().map_err(ReconstructError::Checkpoint)?;
        // The blend is handed over above, so a run finishes once: the truth (30 M
        // cells on the 3.7 km `long`) goes with it rather than being copied.
        let mut o = Outcome::assemble(
            b,
            // The whole model when it is held (the page); its files are written
            // from `model()`.
            match self.model.spilled_tiles() {
                0 => self.model.held().clone(),
                _ => Params {
                    channels,
                    ..Default::default()
                },
            },
            g,
            layers,
            self.truth.take(),
            &centres,
            holdout,
            min_alpha,
        )?;
        if let Some(m) = o.metrics.as_mut() {
            m.initial_elevation_rmse_m = self.initial_rmse();
        }
        self.eval_ms = t.elapsed().as_secs_f64() * 1e3;
        if let Some(s) = self.session.as_mut() {
            s.timings.eval_ms = self.eval_ms;
        }
        Ok(o)
    }

    /// The initial surface's elevation RMSE against the truth at the finished tiles'
    /// surfel centres.
    fn initial_rmse(&self) -> Option<f64> {
        let (se, n) = self.initial_error;
        (n > 0).then(|| (se / n as f64).sqrt())
    }

    /// The current map colour as RGBA over the map's geometry, while training: the
    /// finished tiles' blend with the current tile's model over its window.
    pub async fn preview(&self) -> Result<Vec<u8>, ReconstructError> {
        let min_alpha = self.cfg.train.loss.min_alpha;
        let Some(s) = &self.session else {
            return Ok(vec![
                0;
                (self.geometry.width * self.geometry.height * 4)
                    as usize
            ]);
        };
        if self.tiling.is_none() {
            return Ok(s.preview(&self.geometry).await?);
        }
        let g = self.geometry;
        let w = g.width as usize;
        let mut out = self.stitch.preview();
        let tile = self.started.checked_sub(1).and_then(|k| self.tiles.get(k));
        if let (Some(t), false) = (tile, self.recorded) {
            if let Some(win) = self.stitch.window(&t.rect) {
                let p = s.model().await?;
                let img = s.render_bev(&p, &win.geometry, &mut |_, _| {}).await?;
                let rgba = crate::reconstruct::rgba(&img.rgb, &img.alpha, min_alpha);
                let tw = win.geometry.width as usize;
                for y in 0..win.geometry.height as usize {
                    for x in 0..tw {
                        let li = y * tw + x;
                        let gi = (win.row as usize + y) * w + win.col as usize + x;
                        if rgba[4 * li + 3] > 0 {
                            out[4 * gi..4 * gi + 4].copy_from_slice(&rgba[4 * li..4 * li + 4]);
                        }
                    }
                }
            }
        }
        Ok(out)
    }

    /// report.json: the session's report for an untiled run, with the tiles and the
    /// run's peak memory; totals over the tiles for a tiled one.
    pub fn report(&self, b: &Bundle, o: &Outcome, bundle: &str) -> serde_json::Value {
        let mut r = match &self.session {
            Some(s) => report(s, o, bundle),
            // Every tile restored (a merge of tile jobs, a resume with nothing left).
            None if self.tiling.is_some() => crate::reconstruct::base_report(&self.cfg, o, bundle),
            None => return serde_json::json!({ "bundle": bundle, "stopped": self.failed }),
        };
        if self.session.is_none() {
            if let Some(last) = self.reports.iter().rev().find(|t| t.steps > 0) {
                r["loss_last"] = serde_json::to_value(last.loss_last).unwrap_or_default();
            }
        }
        r["pose_alignment"] = serde_json::to_value(&self.alignment).unwrap_or_default();
        if let Some(p) = self.pose_refiner() {
            // Exact poses that cannot be read are not scored; the map is unaffected.
            let truth = b.read_true_poses().ok().flatten();
            r["pose_refinement"] = p.summary(&b.manifest, truth.as_deref());
        }
        r["timings"]["align_ms"] = self.align_ms.into();
        r["timings"]["eval_ms"] = self.eval_ms.into();
        r["tiling"] = serde_json::to_value(self.tiling).unwrap_or_default();
        r["tiles"] = serde_json::to_value(&self.reports).unwrap_or_default();
        r["tile_count"] = self.reports.len().into();
        // Tiles trained elsewhere (restored) bring their own peaks.
        let peak_gpu = self
            .reports
            .iter()
            .filter_map(|t| t.peak_gpu_bytes)
            .chain(self.peak_gpu_bytes)
            .max();
        r["peak_gpu_bytes"] = serde_json::to_value(peak_gpu).unwrap_or_default();
        r["peak_host_bytes"] =
            serde_json::to_value(crate::mem::peak_host_bytes()).unwrap_or_default();
        // While training (the finish, which assembles the layers, comes after).
        r["peak_host_training_bytes"] =
            serde_json::to_value(self.reports.iter().filter_map(|t| t.host_bytes).max())
                .unwrap_or_default();
        if self.tiling.is_some() {
            r["blend"] = self.blend.clone();
        }
        r["world_frame"] = serde_json::to_value(&b.manifest.world_frame).unwrap_or_default();
        r["drives"] = b
            .drives
            .iter()
            .map(|d| serde_json::json!({ "name": d.name, "frames": d.frames.len() }))
            .collect::<Vec<_>>()
            .into();
        if self.tiling.is_some() {
            let rs = &self.reports;
            let sum = |f: fn(&TileReport) -> usize| rs.iter().map(f).sum::<usize>();
            let steps = sum(|t| t.steps);
            let train_s = rs.iter().map(|t| t.train_ms).sum::<f64>() / 1e3;
            r["surfels"] = serde_json::json!({
                "surfels": sum(|t| t.surfels),
                "added_surfels": sum(|t| t.added_surfels),
                "base_surfels": sum(|t| t.surfels) - sum(|t| t.added_surfels),
                "model_surfels": self.model.len(),
                "model_spilled_tiles": self.model.spilled_tiles(),
            });
            r["steps"] = steps.into();
            r["training_views"] = sum(|t| t.training_views).into();
            r["holdout_views"] = sum(|t| t.holdout_views).into();
            r["position_refreshes"] = sum(|t| t.position_refreshes).into();
            r["pair_overflows"] = sum(|t| t.pair_overflows).into();
            r["surfels_with_lidar"] = sum(|t| t.surfels_with_lidar).into();
            r["smoothness_edges"] = sum(|t| t.smoothness_edges).into();
            r["z_change_rms_m"] = ((self.z_change.0 / self.z_change.1.max(1) as f64).sqrt()).into();
            r["timings"]["train_ms"] = (train_s * 1e3).into();
            r["timings"]["prepare_ms"] = rs.iter().map(|t| t.prepare_ms).sum::<f64>().into();
            r["timings"]["bev_ms"] = rs.iter().map(|t| t.bev_ms).sum::<f64>().into();
            r["frame_gains"] =
                crate::reconstruct::merge_frame_gains(rs.iter().map(|t| &t.frame_gains));
            r["seconds_per_step"] =
                serde_json::to_value((steps > 0).then(|| train_s / steps as f64))
                    .unwrap_or_default();
            // Per epoch: every tile's views once (a view that sees two tiles counts twice).
            let epochs = self.cfg.train.epochs.max(1) as f64;
            let full = steps as f64 >= self.planned_steps as f64;
            r["seconds_per_epoch"] = serde_json::to_value((steps > 0).then(|| {
                if full {
                    train_s / epochs
                } else {
                    train_s / steps as f64 * self.planned_steps as f64 / epochs
                }
            }))
            .unwrap_or_default();
            r["stopped"] = serde_json::to_value(&self.failed).unwrap_or_default();
            if let Some(t) = self.tiling {
                r["seams"] = serde_json::to_value(seams(&o.raster, &t)).unwrap_or_default();
            }
        }
        r
    }
}

/// Steps between neighbouring map pixels across tile borders, against the same
/// statistic across lines halfway between borders (inside tiles): a seam shows as
/// border steps above the inside ones.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Seams {
    pub border_pairs: usize,
    /// Mean |Δ elevation| (metres) and mean |Δ colour| (0–1, over RGB) across borders.
    pub border_elevation_step_m: f64,
    pub border_rgb_step: f64,
    pub inside_pairs: usize,
    pub inside_elevation_step_m: f64,
    pub inside_rgb_step: f64,
}

/// The seam statistics of a map raster cut by the tiles of `t`.
pub fn seams(r: &BevRaster, t: &TileConfig) -> Seams {
    let mut s = SeamSums::default();
    s.add(r, t);
    s.seams()
}

/// The sums of `Seams`, added up over rasters (the blocks of a streamed map: pairs
/// across two blocks are not counted there).
#[derive(Clone, Copy, Debug, Default)]
pub struct SeamSums {
    /// Per class of line: 0 borders (offset 0), 1 inside (offset half a tile):
    /// pairs, sum of |Δ elevation|, sum of |Δ colour|.
    acc: [(usize, f64, f64); 2],
}

impl SeamSums {
    pub fn add(&mut self, r: &BevRaster, t: &TileConfig) {
        let acc = &mut self.acc;
        let half = t.size_m / 2.0;
        let o = t.origin_m.unwrap_or_default();
        let res = r.resolution;
        let mut pair = |kind: usize, a: (u32, u32), b: (u32, u32)| {
            if !(r.is_valid(a.0, a.1) && r.is_valid(b.0, b.1)) {
                return;
            }
            let dz = (r.elevation_at(a.0, a.1) - r.elevation_at(b.0, b.1)).abs() as f64;
            let (pa, pb) = (r.rgb.get_pixel(a.0, a.1).0, r.rgb.get_pixel(b.0, b.1).0);
            let dc = (0..3)
                .map(|c| (pa[c] as f64 - pb[c] as f64).abs() / 255.0)
                .sum::<f64>()
                / 3.0;
            acc[kind].0 += 1;
            acc[kind].1 += dz;
            acc[kind].2 += dc;
        };
        // Which line class, if any, passes between pixel centres at world u and u + res.
        let kind_between = |u: f64, o: f64| -> Option<usize> {
            let k0 = ((u - o) / half).floor();
            let k1 = ((u + res - o) / half).floor();
            (k1 > k0).then(|| (k1.rem_euclid(2.0) != 0.0) as usize)
        };
        for row in 0..r.height {
            for col in 0..r.width.saturating_sub(1) {
                let x = r.origin[0] + (col as f64 + 0.5) * res;
                if let Some(k) = kind_between(x, o[0]) {
                    pair(k, (col, row), (col + 1, row));
                }
            }
        }
        for row in 0..r.height.saturating_sub(1) {
            // Row + 1 lies south: its y is smaller.
            let y = r.origin[1] - (row as f64 + 1.5) * res;
            if let Some(k) = kind_between(y, o[1]) {
                for col in 0..r.width {
                    pair(k, (col, row + 1), (col, row));
                }
            }
        }
    }

    pub fn seams(&self) -> Seams {
        let mean = |a: (usize, f64, f64)| {
            let n = a.0.max(1) as f64;
            (a.1 / n, a.2 / n)
        };
        let (b, i) = (mean(self.acc[0]), mean(self.acc[1]));
        Seams {
            border_pairs: self.acc[0].0,
            border_elevation_step_m: b.0,
            border_rgb_step: b.1,
            inside_pairs: self.acc[1].0,
            inside_elevation_step_m: i.0,
            inside_rgb_step: i.1,
        }
    }
}

/// Raises `peak` to the device's reserved bytes now, where the backend says.
fn sample_gpu(ctx: &GpuContext, peak: &mut Option<u64>) {
    if let Some(b) = ctx.allocated_bytes() {
        *peak = Some(peak.unwrap_or(0).max(b));
    }
}

/// Appends surfels `keep` of `p`, shifted by `shift`, to `model`.
fn append(model: &mut Params<f32>, p: &Params<f32>, keep: &[usize], shift: [f32; 3]) {
    let ch = p.channels;
    model.channels = ch;
    for &k in keep {
        let q = p.pos[k];
        model
            .pos
            .push([q[0] + shift[0], q[1] + shift[1], q[2] + shift[2]]);
        model.rgb.push(p.rgb[k]);
        model.log_scale.push(p.log_scale[k]);
        model.opacity.push(p.opacity[k]);
        model.rotation.push(p.rotation[k]);
        model
            .logits
            .extend_from_slice(&p.logits[k * ch..(k + 1) * ch]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A road along the world's x axis: with the lattice at the origin every view sees
    /// the tiles on both sides of the y = 0 line; the chosen origin puts the road
    /// inside one row of tiles and halves the pairs.
    #[test]
    fn the_lattice_keeps_a_road_off_its_lines() {
        let seen: Vec<Seen> = (0..200)
            .map(|f| {
                let x0 = f as f64;
                let pts = (0..20)
                    .flat_map(|d| (-4..=4).map(move |y| [x0 + 1.0 + d as f64, y as f64]))
                    .collect();
                ((f, 0), pts)
            })
            .collect();
        let pairs = |o: [f64; 2]| -> usize {
            seen.iter()
                .map(|(_, p)| cells_of(p, o, 96.0, 4.0).len())
                .sum()
        };
        let o = lattice_origin(&seen, 96.0, 4.0);
        assert_ne!(o[1], 0.0, "{o:?}");
        assert!(
            2 * pairs(o) <= pairs([0.0, 0.0]) + 200,
            "{} pairs at {o:?}, {} at the origin",
            pairs(o),
            pairs([0.0, 0.0])
        );
        // Every view sees at least one tile, whatever the origin.
        assert!(pairs(o) >= seen.len());
    }

    /// Against the corridor's area by hand: a straight drive 16 m wide, a gap between
    /// two drives left out, a tile the drive misses empty.
    #[test]
    fn a_tiles_surfels_are_its_corridor_area_over_a_cells() {
        let line = |y: f64| (0..=100).map(move |x| [x as f64, y]);
        let ground: Vec<[f64; 2]> = line(0.0).collect();
        let rect = Rect {
            min: [10.0, -50.0],
            max: [60.0, 50.0],
        };
        let n = estimated_tile_surfels(&ground, &rect, 8.0, 0.5);
        let exact = 50.0 * 16.0 / 0.25;
        assert!((n / exact - 1.0).abs() < 0.07, "{n} against {exact}");
        // A second drive 200 m north: the jump between the drives is no corridor.
        let two: Vec<[f64; 2]> = line(0.0).chain(line(200.0)).collect();
        let between = Rect {
            min: [90.0, 50.0],
            max: [110.0, 150.0],
        };
        assert_eq!(estimated_tile_surfels(&two, &between, 8.0, 0.5), 0.0);
        let north = Rect {
            min: [10.0, 150.0],
            max: [60.0, 250.0],
        };
        let n2 = estimated_tile_surfels(&two, &north, 8.0, 0.5);
        assert!((n2 / exact - 1.0).abs() < 0.07, "{n2} against {exact}");
    }
}
