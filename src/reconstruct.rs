//! The whole job, bundle to map, as a session that the CLI and the page drive step by
//! step (so that the page can yield between steps and show progress):
//! prepare (grid, initialisation, refinement) → colours from the best training view
//! (the IPM baseline model) → optimisation steps → BEV layers, metrics, held-out views.
//! Nothing here is native-only: the same code runs in wasm.

use crate::bev::{self, BevGeometry, BevImage};
use crate::bundle::{Bundle, ClassRole, Problem};
use crate::eval::{BevRaster, Metrics};
use crate::gpu::{GpuContext, GpuError};
use crate::init::align::{
    align_bundle, align_with_returns, AlignConfig, AlignSummary, GroundReturns,
};
use crate::init::prepare::{lidar_world_of, prepare, PrepareConfig, PrepareError, PrepareReport};
use crate::init::{PoseIndex, PosePlanes};
use crate::loss::regularise::RegData;
use crate::loss::targets;
use crate::optim::pose::PoseRefiner;
use crate::optim::train::{read_params, StepLoss, TrainError, Trainer};
use crate::optim::{epoch_order, is_holdout, scene_extent, split_views, TrainConfig, ViewRef};
use crate::render::from_bundle::{local_origin, params, view_camera};
use crate::render::gpu::GpuRasterizer;
use crate::render::Params;
use crate::tiles::tile::Tile;
use serde::Serialize;
use thiserror::Error;
use web_time::Instant;

/// Opacity logit of surfels no training view sees (opacity 4.5e-5: below the
/// rasteriser's 1/255 alpha floor, so they are skipped and receive no gradient).
pub const UNSEEN_OPACITY_LOGIT: f32 = -10.0;

#[derive(Debug, Error)]
pub enum ReconstructError {
    #[error(transparent)]
    Prepare(#[from] PrepareError),
    #[error(transparent)]
    Bundle(#[from] Problem),
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(
        "the bundle has no training views (every frame is held out or no view names a camera)"
    )]
    NoViews,
    #[error(
        "the map would be {width}×{height} px at {resolution} m, {mib} MiB of layers, over the budget of {budget_mib} MiB; \
         use a coarser resolution (--resolution; twice as coarse needs a quarter), {tiles}\
         or map the drive in parts of a few km",
        mib = bytes >> 20, budget_mib = budget >> 20, tiles = tiles_advice(*blocks)
    )]
    MapTooLarge {
        width: u32,
        height: u32,
        bytes: u64,
        budget: u64,
        resolution: f64,
        /// Bytes of the blocks the drive covers, when the map could have streamed.
        blocks: Option<u64>,
    },
    #[error(
        "camera {camera}'s images are {width}×{height} px: a view's per-pixel buffers would take {mib} MiB, \
         over this GPU's {limit_mib} MiB per buffer; downscale the images (and intrinsics) to at most {max_px} \
         pixels, e.g. {fit_w}×{fit_h}",
        mib = bytes >> 20, limit_mib = limit >> 20
    )]
    ImageTooLargeForGpu {
        camera: String,
        width: u32,
        height: u32,
        bytes: u64,
        limit: u64,
        max_px: u64,
        fit_w: u32,
        fit_h: u32,
    },
    /// A tile with no surfels or no view that sees them (skipped by the tiled run).
    #[error("the tile has no surfels or no training view sees them")]
    EmptyTile,
    #[error("a tile checkpoint was refused: {0}")]
    Checkpoint(String),
    #[error("cannot write the map: {0}")]
    Write(String),
    #[error("tile {tile}: {source}")]
    Tile {
        tile: String,
        #[source]
        source: Box<ReconstructError>,
    },
}

/// Refuses a camera whose views would not fit the GPU's per-buffer limit, before any
/// work (a raw buffer error in the middle of a step otherwise).
pub fn check_cameras_fit(
    m: &crate::bundle::Manifest,
    ctx: &GpuContext,
) -> Result<(), ReconstructError> {
    let per_px = crate::render::gpu::view_bytes_per_pixel(m.classes().len().max(1));
    let limit = ctx.limits.max_storage_buffer_binding_size;
    for c in &m.cameras {
        let bytes = c.width as u64 * c.height as u64 * per_px;
        if bytes > limit {
            let max_px = limit / per_px;
            // The same aspect ratio, scaled down to fit.
            let k = (max_px as f64 / (c.width as f64 * c.height as f64)).sqrt();
            return Err(ReconstructError::ImageTooLargeForGpu {
                camera: c.name.clone(),
                width: c.width,
                height: c.height,
                bytes,
                limit,
                max_px,
                fit_w: (c.width as f64 * k).floor() as u32,
                fit_h: (c.height as f64 * k).floor() as u32,
            });
        }
    }
    Ok(())
}

/// Corrects the bundle's poses from its LiDAR when `cfg` asks for it (once per run,
/// before anything reads the poses).
pub fn align(
    b: &mut Bundle,
    cfg: &ReconstructConfig,
) -> Result<Option<AlignSummary>, ReconstructError> {
    align_from(b, cfg, None)
}

/// As `align`, from the ground returns already gathered when `returns` holds them
/// (the page gathers them a batch of sweeps at a time from a lazily read bundle).
pub fn align_from(
    b: &mut Bundle,
    cfg: &ReconstructConfig,
    returns: Option<GroundReturns>,
) -> Result<Option<AlignSummary>, ReconstructError> {
    Ok(match (aligns(cfg), returns) {
        (Some(a), Some(r)) => align_with_returns(b, r, a).map(|a| AlignSummary::new(&a)),
        (Some(a), None) => align_bundle(b, a)?.map(|a| AlignSummary::new(&a)),
        (None, _) => None,
    })
}

/// The alignment `cfg` asks for: only when the LiDAR is in use.
pub fn aligns(cfg: &ReconstructConfig) -> Option<&AlignConfig> {
    cfg.align
        .as_ref()
        .filter(|_| cfg.train.use_lidar && cfg.prepare.use_lidar)
}

/// `MapTooLarge`'s advice on tiles: where the map could stream, what its blocks need.
fn tiles_advice(blocks: Option<u64>) -> String {
    match blocks {
        Some(b) => format!(
            "raise --map-memory-mib above the {} MiB the map's blocks along the drive need, ",
            b.div_ceil(1 << 20)
        ),
        None => "map it in tiles (--tile-m: natively, a tiled map too large for whole layers \
                 is written block by block), "
            .into(),
    }
}

impl ReconstructError {
    /// True when the input (the bundle, or the settings for it) is at fault, not
    /// the machine: the user fixes this one.
    pub fn is_input(&self) -> bool {
        match self {
            Self::Prepare(_) | Self::Bundle(_) | Self::NoViews | Self::EmptyTile => true,
            Self::MapTooLarge { .. } | Self::Checkpoint(_) => true,
            Self::ImageTooLargeForGpu { .. } => true,
            Self::Gpu(_) | Self::Train(_) | Self::Write(_) => false,
            Self::Tile { source, .. } => source.is_input(),
        }
    }

    /// The bundle file this error waits for, when it is only that a lazily read
    /// bundle has not provided it yet (not a failure: provide it and step again).
    pub fn not_loaded(&self) -> Option<&str> {
        match self {
            Self::Bundle(Problem::NotLoaded { path })
            | Self::Prepare(PrepareError::Bundle(Problem::NotLoaded { path })) => Some(path),
            Self::Tile { source, .. } => source.not_loaded(),
            _ => None,
        }
    }
}

/// World xy of frame `f`'s vehicle.
pub fn frame_xy(m: &crate::bundle::Manifest, f: usize) -> [f64; 2] {
    let t = &m.frames[f].vehicle_to_world;
    [t[0][3], t[1][3]]
}

#[derive(Clone, Debug)]
pub struct ReconstructConfig {
    pub prepare: PrepareConfig,
    pub train: TrainConfig,
    /// Skip optimisation: the map is the IPM baseline (best-view colours on the
    /// initial surface).
    pub baseline_ipm: bool,
    /// Correct each frame's height, roll and pitch from its LiDAR sweep before
    /// anything uses the poses (when the LiDAR is in use); `None` keeps them.
    pub align: Option<AlignConfig>,
    /// Photometric pose refinement during training (`optim::pose`); `None`: off.
    pub poses: Option<crate::optim::pose::PoseConfig>,
    /// How the finished map is held.
    pub map: MapConfig,
}

/// How the finished map is held (`tiles::stitch`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MapConfig {
    /// Host bytes the map's whole layers may take; `None`: 4 × the grid's budget.
    pub budget_bytes: Option<u64>,
    /// A tiled map whose whole layers would exceed the budget, or
    /// `tiles::STREAM_OVER_BYTES`, is written block by block (map.rogsmap,
    /// `TiledRun::finish_streamed`, and its raster files, `TiledRun::write_layers`)
    /// instead of being refused or held whole; set where the caller writes files
    /// (the CLI), not in the page.
    pub stream: bool,
    /// Where `stream` is set, when a tiled map is finished block by block.
    pub finish: MapFinish,
}

/// When a tiled map whose files are written is finished block by block
/// (`MapConfig::finish`, `Settings::map_finish`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum MapFinish {
    /// When its whole layers would exceed `tiles::STREAM_OVER_BYTES` or the budget.
    #[default]
    Auto,
    /// Always: the finish holds a row of blocks, whatever the map's size.
    Blocks,
    /// Only over the budget: the whole layers are held (the seam statistics then
    /// count pairs across blocks too).
    Whole,
}

impl MapFinish {
    pub fn name(self) -> &'static str {
        match self {
            MapFinish::Auto => "auto",
            MapFinish::Blocks => "blocks",
            MapFinish::Whole => "whole",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        [MapFinish::Auto, MapFinish::Blocks, MapFinish::Whole]
            .into_iter()
            .find(|m| m.name() == s)
    }
}

impl Default for ReconstructConfig {
    fn default() -> Self {
        Self {
            // As the CLI and the page: the LiDAR, when a bundle has one, is used.
            prepare: PrepareConfig {
                use_lidar: true,
                ..Default::default()
            },
            train: TrainConfig::default(),
            baseline_ipm: false,
            align: Some(AlignConfig::default()),
            poses: None,
            map: MapConfig::default(),
        }
    }
}

/// Wall time of each stage, milliseconds.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    pub align_ms: f64,
    pub prepare_ms: f64,
    pub colour_ms: f64,
    pub gpu_setup_ms: f64,
    /// Compute pipelines the GPU set-up compiled: none on a device warmed for the
    /// run (the page's `warm_gpu`), where compiling is most of `gpu_setup_ms`.
    pub gpu_setup_pipelines: usize,
    pub train_ms: f64,
    /// Of `train_ms`: reading, decoding and packing the steps' target images.
    pub target_ms: f64,
    pub bev_ms: f64,
    pub eval_ms: f64,
}

/// Held-out evaluation: road-pixel PSNR of the held-out camera views.
#[derive(Clone, Debug, Serialize)]
pub struct Holdout {
    pub psnr_db: f64,
    pub ipm_psnr_db: f64,
    pub frames: usize,
    pub views: usize,
}

pub struct Session {
    pub cfg: ReconstructConfig,
    pub prepare_report: PrepareReport,
    pub grid: crate::grid::Grid,
    pub z_hat: Vec<f32>,
    pub q: Vec<f32>,
    /// Refinement level per surfel (0 base, 1 added).
    pub level: Vec<u8>,
    pub origin: [f64; 3],
    /// The model before optimisation (the IPM baseline).
    pub initial: Params<f32>,
    pub trainer: Trainer,
    pub train_views: Vec<ViewRef>,
    pub holdout_views: Vec<ViewRef>,
    order: Vec<usize>,
    pub losses: Vec<StepLoss>,
    pub timings: Timings,
    pub stopped: Option<String>,
    pub bytes_per_surfel_gpu: f64,
    /// Surfels with a LiDAR elevation for L_z, and smoothness edges.
    pub with_lidar: usize,
    pub edges: usize,
    /// What the pose alignment did, when it ran.
    pub alignment: Option<AlignSummary>,
    /// Per-frame pose corrections, when refinement is on (a tiled run hands them
    /// from tile to tile, so that a frame seen by two tiles has one correction).
    pub poses: Option<PoseRefiner>,
    /// Each training view's own log gain on top of its camera's exposure, by
    /// (camera, frame), measured in its first step (`optim::gain`).
    pub frame_gains: std::collections::BTreeMap<(usize, usize), f32>,
}

/// Sets each surfel's colour and class (a confident but not saturated start:
/// softmax ≈ 0.9 for 9 classes) from its best view; with `hide_unseen`, a surfel no
/// training view sees becomes transparent, so that the map shows a hole rather than
/// an invented grey road (otherwise it keeps what it had).
fn apply_colours(
    s: &mut crate::grid::Surfels,
    colours: &[Option<crate::init::ipm::SurfelColour>],
    chan: &[Option<u8>; 256],
    hide_unseen: bool,
) {
    for (k, c) in colours.iter().enumerate() {
        match c {
            None if hide_unseen => s.opacity[k] = UNSEEN_OPACITY_LOGIT,
            None => {}
            Some((rgb, id)) => {
                s.rgb[k] = *rgb;
                let logits = &mut s.logits[k * s.classes..(k + 1) * s.classes];
                logits.fill(0.0);
                if let Some(q) = chan[*id as usize] {
                    logits[q as usize] = 4.0;
                }
            }
        }
    }
}

/// Dense channel and class id of every road class (the BEV semantic layer's choices).
pub fn road_channels(b: &Bundle) -> Vec<(usize, u8)> {
    b.manifest
        .classes()
        .iter()
        .enumerate()
        .filter(|(_, c)| c.role == ClassRole::Road)
        .map(|(k, c)| (k, c.id))
        .collect()
}

impl Session {
    /// Prepares a run on `b`. With `cfg.align` and LiDAR in use, the bundle's poses
    /// are first corrected in place, so every later stage (and the caller) sees them.
    pub async fn new(
        b: &mut Bundle,
        cfg: ReconstructConfig,
        ctx: GpuContext,
    ) -> Result<Self, ReconstructError> {
        let t = Instant::now();
        let alignment = align(b, &cfg)?;
        let align_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut s = Self::build(b, cfg, ctx, None).await?;
        s.alignment = alignment;
        s.timings.align_ms = align_ms;
        Ok(s)
    }

    /// Prepares the surfels, initialises colours and uploads everything to the GPU,
    /// for the whole map (`tile` = `None`) or for one tile: its surfels (the corridor
    /// clipped to the tile's rectangle), the views that see them, the LiDAR sweeps
    /// near it. The poses are used as they are (`align` runs once, before).
    pub async fn build(
        b: &Bundle,
        cfg: ReconstructConfig,
        ctx: GpuContext,
        tile: Option<&Tile>,
    ) -> Result<Self, ReconstructError> {
        let mut timings = Timings::default();
        let m = &b.manifest;
        let t = Instant::now();
        let mut pcfg = cfg.prepare.clone();
        if let Some(tile) = tile {
            pcfg.clip = Some(tile.rect);
            pcfg.frames = Some(tile.near_frames.clone());
        }
        let near = |f: usize| tile.is_none_or(|t| t.near_frames.get(f).copied().unwrap_or(false));
        let prepared = prepare(b, &pcfg)?;
        if prepared.grid.is_empty() {
            return Err(ReconstructError::EmptyTile);
        }
        timings.prepare_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let planes = PosePlanes::from_manifest(m);
        let poses = PoseIndex::new(&planes);
        let holdout = cfg.train.holdout_every;
        let mut s = prepared.surfels;
        let origin = local_origin(&prepared.grid, &s);
        let lidar = if cfg.train.use_lidar && cfg.train.loss.lidar > 0.0 {
            lidar_world_of(b, pcfg.frames.as_deref())?.0
        } else {
            Vec::new()
        };
        let reg = RegData::new(
            &prepared.grid,
            &s.z_hat,
            &s.q,
            &lidar,
            origin[2],
            &cfg.train.loss,
        );
        let use_frame = |f: usize| !is_holdout(f, holdout) && near(f);
        let colours =
            crate::init::ipm::surfel_colours(b, &prepared.grid, &s.z, &poses, &use_frame)?;
        let chan = targets::channel_of(m);
        apply_colours(&mut s, &colours, &chan, true);
        // The model before optimisation: the IPM baseline, on the pose plane.
        let initial = params(&prepared.grid, &s, origin);
        // Not with pose refinement: colours copied from each surfel's nearest view
        // through its given pose agree with that pose's error from the start, and
        // leave refinement nothing to pull on (docs/QUALITY.md).
        let on_lidar = !cfg.baseline_ipm
            && cfg.train.lidar_colours
            && cfg.poses.is_none()
            && reg.with_lidar > 0;
        let start = if on_lidar {
            // Training starts from the colours where the LiDAR puts each surfel.
            let z: Vec<f32> =
                s.z.iter()
                    .zip(&reg.priors)
                    .map(|(&z, p)| {
                        if p[3] > 0.0 {
                            p[2] + origin[2] as f32
                        } else {
                            z
                        }
                    })
                    .collect();
            let colours =
                crate::init::ipm::surfel_colours(b, &prepared.grid, &z, &poses, &use_frame)?;
            let mut s = s.clone();
            apply_colours(&mut s, &colours, &chan, false);
            params(&prepared.grid, &s, origin)
        } else {
            initial.clone()
        };
        timings.colour_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let (mut train_views, mut holdout_views) = split_views(m, holdout);
        let mut extent = scene_extent(m);
        if let Some(tile) = tile {
            train_views.retain(|v| tile.views.contains(&(v.frame, v.view)));
            // A held-out view is scored in the tile whose core holds its vehicle.
            holdout_views.retain(|v| tile.core.contains(frame_xy(m, v.frame)));
            extent = tile.extent;
        }
        if train_views.is_empty() {
            return Err(if tile.is_some() {
                ReconstructError::EmptyTile
            } else {
                ReconstructError::NoViews
            });
        }
        let epochs = if cfg.baseline_ipm {
            0
        } else {
            cfg.train.epochs
        };
        let mut order: Vec<usize> = (0..epochs)
            .flat_map(|e| epoch_order(train_views.len(), cfg.train.seed, e))
            .collect();
        order.truncate(cfg.train.max_steps.unwrap_or(usize::MAX));
        let mut train = cfg.train.clone();
        if on_lidar {
            train.lr.rgb = train.lr.rgb_on_lidar;
        }
        // Each frame's measured gain takes the place of its camera's learned
        // exposure: a camera exposure still moving would shift every gain measured
        // against it before (on the KITTI sample, 23.74 dB held out when both ran
        // against 24.01 with the camera's frozen, docs/QUALITY.md).
        if train.frame_exposure {
            train.lr.exposure = 0.0;
        }
        let compiled = ctx.pipelines_compiled();
        let trainer = Trainer::new(
            ctx,
            &start,
            &reg,
            m.cameras.len(),
            &train,
            extent,
            order.len(),
        )
        .await?;
        timings.gpu_setup_ms = t.elapsed().as_secs_f64() * 1e3;
        timings.gpu_setup_pipelines = trainer.ctx.pipelines_compiled() - compiled;
        Ok(Self {
            bytes_per_surfel_gpu: trainer.bytes_per_surfel(),
            with_lidar: reg.with_lidar,
            edges: reg.edges,
            alignment: None,
            frame_gains: Default::default(),
            poses: cfg
                .poses
                .clone()
                .filter(|_| !cfg.baseline_ipm)
                .map(|c| PoseRefiner::new(m.frames.len(), m.cameras.len(), c)),
            prepare_report: prepared.report,
            level: prepared.grid.level.clone(),
            grid: prepared.grid,
            z_hat: s.z_hat,
            q: s.q,
            origin,
            initial,
            trainer,
            train_views,
            holdout_views,
            order,
            losses: Vec::new(),
            timings,
            stopped: None,
            cfg,
        })
    }

    pub fn total_steps(&self) -> usize {
        self.order.len()
    }

    pub fn steps_done(&self) -> usize {
        self.trainer.steps_done
    }

    pub fn is_done(&self) -> bool {
        self.stopped.is_some() || self.steps_done() >= self.total_steps()
    }

    /// The packed target of a view and its mask count.
    fn target(&self, b: &Bundle, v: &ViewRef) -> Result<(Vec<u32>, usize), Problem> {
        let view = &b.manifest.frames[v.frame].views[v.view];
        let rgb = b.read_rgb(&view.image)?;
        let label = b.read_view_label(v.frame, v.view)?;
        let l = &self.cfg.train.loss;
        Ok(targets::pack(
            &b.manifest,
            &rgb,
            &label,
            l.open_px,
            l.dilate_px,
        ))
    }

    /// A held-out view's log gain: the mean of its camera's nearest trained frames'
    /// before and after it (auto-exposure drifts slowly), 0 without any.
    pub fn holdout_gain(&self, v: &ViewRef) -> f32 {
        let g = &self.frame_gains;
        let before = g.range((v.camera, 0)..(v.camera, v.frame)).next_back();
        let after = g
            .range((v.camera, v.frame + 1)..(v.camera, usize::MAX))
            .next();
        match (before, after) {
            (Some((_, a)), Some((_, b))) => 0.5 * (a + b),
            (Some((_, a)), None) | (None, Some((_, a))) => *a,
            (None, None) => 0.0,
        }
    }

    /// One optimisation step; `Ok(None)` once every step is done. A non-finite loss
    /// ends the session (the last good model is kept) and is returned as the error.
    pub async fn step(&mut self, b: &Bundle) -> Result<Option<StepLoss>, ReconstructError> {
        if self.is_done() {
            return Ok(None);
        }
        let t = Instant::now();
        let v = self.train_views[self.order[self.steps_done()]];
        let (target, count) = self.target(b, &v)?;
        self.timings.target_ms += t.elapsed().as_secs_f64() * 1e3;
        let mut cam = view_camera(&b.manifest, v.frame, v.view, self.origin, [0.0, 0.0])
            .ok_or(ReconstructError::NoViews)?;
        // A view's own gain on top of its camera's exposure: measured in its first
        // step (rendered with gain 0) and kept for its later ones (`optim::gain`).
        let key = (v.camera, v.frame);
        let known = self.frame_gains.get(&key).copied();
        let measure_gain = self.cfg.train.frame_exposure && known.is_none();
        if self.cfg.train.frame_exposure {
            cam.exposure[0] = known.unwrap_or(0.0);
        }
        // With refinement: the view from the frame's corrected pose, and from the
        // start step on, the gradient about the corrected vehicle position.
        let mut pose_centre = None;
        let mut progress = 0.0;
        let x = &b.manifest.frames[v.frame].vehicle_to_world;
        if let Some(r) = &self.poses {
            let [rig, c] = r.view(v.frame, v.camera, x);
            let at = [0, 1, 2].map(|k| x[k][3] - self.origin[k]);
            cam = c.apply(&rig.apply(&cam, at), at);
            let start = (r.cfg.start * self.total_steps() as f64).floor() as usize;
            if self.steps_done() >= start {
                pose_centre = Some([0, 1, 2].map(|k| (at[k] + c.tau[k]) as f32));
                let left = self.total_steps().saturating_sub(start).max(1);
                progress = (self.steps_done() - start) as f64 / left as f64;
            }
        }
        let r = self
            .trainer
            .step_with(&cam, v.camera, &target, count, pose_centre, measure_gain)
            .await;
        self.timings.train_ms += t.elapsed().as_secs_f64() * 1e3;
        match r {
            Ok(out) => {
                if let (Some(r), Some(g)) = (&mut self.poses, out.pose) {
                    r.update(v.frame, g, progress);
                    r.update_rig(v.camera, g, x, progress);
                }
                if let Some(g) = out.gain {
                    self.frame_gains.insert(key, g.log_gain);
                }
                self.losses.push(out.loss);
                Ok(Some(out.loss))
            }
            Err(e) => {
                self.stopped = Some(e.to_string());
                Err(e.into())
            }
        }
    }

    /// The BEV geometry: the truth raster's when the bundle has one, else the grid's
    /// bounding box at the grid resolution.
    pub fn geometry(&self, truth: Option<&BevRaster>) -> BevGeometry {
        let corridor = BevGeometry::around(
            (0..self.grid.len()).map(|k| self.grid.xy(k)),
            self.grid.resolution,
            self.grid.resolution,
        );
        match truth {
            // The truth's grid, grown where the corridor leaves it (merged drives,
            // whose truth is the first drive's).
            Some(t) => BevGeometry::of_raster(t).covering(&corridor),
            None => corridor,
        }
    }

    /// Renders the current model's BEV image.
    pub async fn render_bev(
        &self,
        p: &Params<f32>,
        g: &BevGeometry,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<BevImage, GpuError> {
        let t = &self.trainer;
        bev::render(
            &t.ctx,
            &t.raster,
            &t.params,
            p,
            g,
            self.origin,
            progress,
            true,
        )
        .await
    }

    /// Renders per-surfel scalars (q and refinement level) as a two-channel BEV image
    /// through the same kernels: they ride in the colour channels of a copy of `p`.
    pub async fn render_scalars(
        &self,
        p: &Params<f32>,
        g: &BevGeometry,
    ) -> Result<BevImage, GpuError> {
        let mut s = p.clone();
        for (k, c) in s.rgb.iter_mut().enumerate() {
            *c = [self.q[k], self.level[k] as f32, 0.0];
        }
        let t = &self.trainer;
        let gp = GpuRasterizer::upload(&t.ctx, &s);
        bev::render(
            &t.ctx,
            &t.raster,
            &gp,
            &s,
            g,
            self.origin,
            &mut |_, _| {},
            true,
        )
        .await
    }

    /// Centres of the surfels some training view saw, in world coordinates.
    /// Σ (initial z − truth)² and count over surfels `seen`, where the truth is
    /// valid: the initial surface at the centres the metrics score.
    pub fn initial_error(&self, seen: &[usize], truth: &BevRaster) -> (f64, usize) {
        let (mut se, mut n) = (0.0, 0);
        for &k in seen {
            let q = self.initial.pos[k].map(|v| v as f64);
            let (x, y) = (q[0] + self.origin[0], q[1] + self.origin[1]);
            if let Some(z) = truth.elevation_xy(x, y) {
                se += (q[2] + self.origin[2] - z).powi(2);
                n += 1;
            }
        }
        (se, n)
    }

    pub fn centres(&self, p: &Params<f32>) -> Vec<[f64; 3]> {
        p.pos
            .iter()
            .zip(&p.opacity)
            .filter(|(_, &o)| o > UNSEEN_OPACITY_LOGIT + 1.0)
            .map(|(q, _)| {
                [
                    q[0] as f64 + self.origin[0],
                    q[1] as f64 + self.origin[1],
                    q[2] as f64 + self.origin[2],
                ]
            })
            .collect()
    }

    /// Road-pixel PSNR of the held-out views for the current model and for the IPM
    /// baseline model, over pixels inside the loss mask that both cover.
    pub async fn holdout(&self, b: &Bundle) -> Result<Option<Holdout>, ReconstructError> {
        let mut sums = HoldoutSums::default();
        self.holdout_sums(b, &mut sums).await?;
        Ok(sums.holdout(self.holdout_views.len()))
    }

    /// Adds the held-out views' squared errors (model and IPM baseline) to `sums`.
    pub async fn holdout_sums(
        &self,
        b: &Bundle,
        sums: &mut HoldoutSums,
    ) -> Result<(), ReconstructError> {
        if self.holdout_views.is_empty() {
            return Ok(());
        }
        let t = &self.trainer;
        let exposures = t.read_exposures().await?;
        let ipm = GpuRasterizer::upload(&t.ctx, &self.initial);
        let (mut se, mut se_ipm, mut n) = (0.0f64, 0.0f64, 0u64);
        let mut frames = Vec::new();
        for v in &self.holdout_views {
            let (target, _) = self.target(b, v)?;
            let mut e = exposures.get(v.camera).copied().unwrap_or([0.0, 0.0]);
            e[0] += self.holdout_gain(v);
            let Some(cam) = view_camera(&b.manifest, v.frame, v.view, self.origin, e) else {
                continue;
            };
            let cam0 = view_camera(&b.manifest, v.frame, v.view, self.origin, [0.0, 0.0])
                .ok_or(ReconstructError::NoViews)?;
            let cull = &self.cfg.train.cull;
            let f = t.raster.forward(&t.ctx, &t.params, &cam, cull).await?;
            let a = GpuRasterizer::read_image(&t.ctx, &f).await?;
            let f = t.raster.forward(&t.ctx, &ipm, &cam0, cull).await?;
            let bimg = GpuRasterizer::read_image(&t.ctx, &f).await?;
            let min_alpha = self.cfg.train.loss.min_alpha;
            for (i, &tp) in target.iter().enumerate() {
                if tp >> 24 == targets::MASKED
                    || a.alpha[i] < min_alpha
                    || bimg.alpha[i] < min_alpha
                {
                    continue;
                }
                for c in 0..3 {
                    let tc = ((tp >> (8 * c)) & 255) as f64 / 255.0;
                    se += (a.rgb[3 * i + c] as f64 - tc).powi(2);
                    se_ipm += (bimg.rgb[3 * i + c] as f64 - tc).powi(2);
                }
                n += 3;
            }
            frames.push(v.frame);
        }
        sums.se += se;
        sums.se_ipm += se_ipm;
        sums.n += n;
        sums.frames.extend(frames);
        Ok(())
    }
}

/// Squared errors of held-out views summed over one or more sessions (tiles).
#[derive(Clone, Debug, Default)]
pub struct HoldoutSums {
    pub se: f64,
    pub se_ipm: f64,
    pub n: u64,
    pub frames: std::collections::BTreeSet<usize>,
}

impl HoldoutSums {
    /// Adds another session's sums (a frame held out in two tiles counts once).
    pub fn merge(&mut self, o: &HoldoutSums) {
        self.se += o.se;
        self.se_ipm += o.se_ipm;
        self.n += o.n;
        self.frames.extend(o.frames.iter().copied());
    }

    pub fn holdout(&self, views: usize) -> Option<Holdout> {
        if self.n == 0 {
            return None;
        }
        let psnr = |se: f64| -10.0 * (se / self.n as f64).max(1e-12).log10();
        Some(Holdout {
            psnr_db: psnr(self.se),
            ipm_psnr_db: psnr(self.se_ipm),
            frames: self.frames.len(),
            views,
        })
    }
}

/// Everything a finished run produces.
pub struct Outcome {
    pub params: Params<f32>,
    pub geometry: BevGeometry,
    pub bev: BevImage,
    pub raster: BevRaster,
    /// q and refinement level per BEV pixel (NaN where nothing is rendered).
    pub confidence: Vec<f32>,
    pub density: Vec<f32>,
    pub truth: Option<BevRaster>,
    pub metrics: Option<Metrics>,
    pub holdout: Option<Holdout>,
}

impl Session {
    /// The model as it stands (after the last good step), read back from the GPU.
    /// Callers save it before `finish` so that a later failure cannot lose training.
    pub async fn model(&self) -> Result<Params<f32>, ReconstructError> {
        Ok(read_params(&self.trainer.ctx, &self.trainer.params).await?)
    }

    /// Renders the BEV layers of the model `p` (from `model`) and scores them.
    pub async fn finish(
        &mut self,
        b: &Bundle,
        p: Params<f32>,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Outcome, ReconstructError> {
        let t = Instant::now();
        let truth = BevRaster::from_bundle(b)?;
        let g = self.geometry(truth.as_ref());
        let layers = self.layers(&p, &g, progress).await?;
        self.timings.bev_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let centres = self.centres(&p);
        let seen: Vec<usize> = (0..p.len())
            .filter(|&k| p.opacity[k] > UNSEEN_OPACITY_LOGIT + 1.0)
            .collect();
        let initial = truth.as_ref().map(|t| self.initial_error(&seen, t));
        let holdout = self.holdout(b).await?;
        let mut o = Outcome::assemble(b, p, g, layers, truth, &centres, holdout, self.min_alpha())?;
        if let (Some(m), Some((se, n))) = (o.metrics.as_mut(), initial) {
            m.initial_elevation_rmse_m = (n > 0).then(|| (se / n as f64).sqrt());
        }
        self.timings.eval_ms = t.elapsed().as_secs_f64() * 1e3;
        Ok(o)
    }

    pub fn min_alpha(&self) -> f32 {
        self.cfg.train.loss.min_alpha
    }

    /// The BEV layers of the model `p` over `g`: colour, logits, elevation and
    /// alpha, and the confidence and density layers (NaN where nothing is rendered).
    pub async fn layers(
        &self,
        p: &Params<f32>,
        g: &BevGeometry,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Layers, GpuError> {
        let bev = self.render_bev(p, g, progress).await?;
        let min_alpha = self.min_alpha();
        let scalars = self.render_scalars(p, g).await?;
        let layer = |c: usize| -> Vec<f32> {
            (0..bev.alpha.len())
                .map(|i| {
                    if bev.alpha[i] >= min_alpha {
                        scalars.rgb[3 * i + c]
                    } else {
                        f32::NAN
                    }
                })
                .collect()
        };
        let (confidence, density) = (layer(0), layer(1));
        Ok(Layers {
            bev,
            confidence,
            density,
        })
    }
}

/// The rendered layers of a model over one geometry (a tile's or the map's).
#[derive(Clone, Debug, Default)]
pub struct Layers {
    pub bev: BevImage,
    pub confidence: Vec<f32>,
    pub density: Vec<f32>,
}

impl Outcome {
    /// The outcome of a block of a map (its layers over `g`), unscored: how a map
    /// too large for whole layers is written, one block at a time
    /// (`TiledRun::finish_streamed`). `truth`: the whole truth raster, cut to `g`.
    pub fn block(
        g: BevGeometry,
        layers: Layers,
        truth: Option<&BevRaster>,
        road_channels: &[(usize, u8)],
        min_alpha: f32,
    ) -> Self {
        let raster = bev::to_raster(&layers.bev, &g, road_channels, min_alpha);
        Outcome {
            params: Params::default(),
            geometry: g,
            bev: layers.bev,
            confidence: layers.confidence,
            density: layers.density,
            truth: truth.map(|t| t.crop_to(&raster)),
            raster,
            metrics: None,
            holdout: None,
        }
    }

    /// The outcome of layers over the map's geometry `g`: the raster and the metrics
    /// (`centres`: the surfel centres some view saw, world).
    #[allow(clippy::too_many_arguments)]
    pub fn assemble(
        b: &Bundle,
        params: Params<f32>,
        g: BevGeometry,
        layers: Layers,
        truth: Option<BevRaster>,
        centres: &[[f64; 3]],
        holdout: Option<Holdout>,
        min_alpha: f32,
    ) -> Result<Self, ReconstructError> {
        let raster = bev::to_raster(&layers.bev, &g, &road_channels(b), min_alpha);
        let mut metrics = crate::eval::score(b, truth.as_ref(), &raster, centres, g.resolution)?;
        if let (Some(m), Some(t)) = (metrics.as_mut(), &truth) {
            m.vs_reference = crate::eval::vs_reference(b, t, &raster)?;
        }
        Ok(Outcome {
            params,
            geometry: g,
            bev: layers.bev,
            raster,
            confidence: layers.confidence,
            density: layers.density,
            truth,
            metrics,
            holdout,
        })
    }
}

/// Views and the range and RMS of their gains as factors (e^a), when measured.
pub fn frame_gain_summary(
    g: &std::collections::BTreeMap<(usize, usize), f32>,
) -> serde_json::Value {
    if g.is_empty() {
        return serde_json::Value::Null;
    }
    let a: Vec<f64> = g.values().map(|&a| a as f64).collect();
    let lo = a.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = a.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let rms = (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt();
    serde_json::json!({
        "views": a.len(),
        "min": lo.exp(),
        "max": hi.exp(),
        "log_rms": rms,
    })
}

/// Several tiles' `frame_gain_summary` as one (null when none measured any).
pub fn merge_frame_gains<'a>(
    parts: impl Iterator<Item = &'a serde_json::Value>,
) -> serde_json::Value {
    let (mut views, mut sq, mut lo, mut hi) = (0u64, 0.0f64, f64::INFINITY, 0.0f64);
    for p in parts {
        let (Some(n), Some(r), Some(a), Some(b)) = (
            p["views"].as_u64(),
            p["log_rms"].as_f64(),
            p["min"].as_f64(),
            p["max"].as_f64(),
        ) else {
            continue;
        };
        views += n;
        sq += n as f64 * r * r;
        (lo, hi) = (lo.min(a), hi.max(b));
    }
    if views == 0 {
        return serde_json::Value::Null;
    }
    serde_json::json!({
        "views": views,
        "min": lo,
        "max": hi,
        "log_rms": (sq / views as f64).sqrt(),
    })
}

/// The report of a finished run (report.json).
pub fn report(s: &Session, o: &Outcome, bundle: &str) -> serde_json::Value {
    let last = s.losses.last().copied().unwrap_or_default();
    let first = s.losses.first().copied().unwrap_or_default();
    let mut r = base_report(&s.cfg, o, bundle);
    let more = serde_json::json!({
        "surfels": s.prepare_report,
        "gpu_bytes_per_surfel": s.bytes_per_surfel_gpu,
        "surfels_with_lidar": s.with_lidar,
        "pose_alignment": s.alignment,
        "smoothness_edges": s.edges,
        "z_change_rms_m": (o.params.pos.iter().zip(&s.initial.pos)
            .map(|(a, b)| ((a[2] - b[2]) as f64).powi(2)).sum::<f64>()
            / o.params.len().max(1) as f64).sqrt(),
        "steps": s.steps_done(),
        // Views that found a surfel their candidate list missed (positions re-read).
        "position_refreshes": s.trainer.position_refreshes,
        // Steps whose surfel-tile pairs overflowed the buffers sized for them (run again).
        "pair_overflows": s.trainer.pair_overflows,
        "training_views": s.train_views.len(),
        "holdout_views": s.holdout_views.len(),
        // The frames' own gains (`--no-frame-exposure` turns them off).
        "frame_gains": frame_gain_summary(&s.frame_gains),
        "loss_first": first,
        "loss_last": last,
        "stopped": s.stopped,
        "timings": s.timings,
        "seconds_per_step": (s.steps_done() > 0)
            .then(|| s.timings.train_ms / 1e3 / s.steps_done() as f64),
        // Measured per step × training views: exact for full epochs, an estimate
        // when --max-steps cut the run short.
        "seconds_per_epoch": (s.steps_done() > 0)
            .then(|| s.timings.train_ms / 1e3 / s.steps_done() as f64 * s.train_views.len() as f64),
    });
    if let (Some(r), serde_json::Value::Object(more)) = (r.as_object_mut(), more) {
        r.extend(more);
    }
    r
}

/// The part of report.json that needs no session: the bundle, the settings, the
/// map's geometry, its metrics and held-out scores.
pub fn base_report(c: &ReconstructConfig, o: &Outcome, bundle: &str) -> serde_json::Value {
    let t = &c.train;
    serde_json::json!({
        "bundle": bundle,
        "settings": {
            "resolution_m": c.prepare.grid.resolution,
            "half_width_m": c.prepare.grid.half_width,
            "adaptive": c.prepare.refine.enabled,
            "init": format!("{:?}", c.prepare.init.method).to_lowercase(),
            "lidar": t.use_lidar,
            "baseline": if c.baseline_ipm { Some("ipm") } else { None },
            "train": t,
        },
        "bev": o.geometry,
        "metrics": o.metrics,
        "holdout": o.holdout,
    })
}

/// RGBA pixels of an RGB float image (0..1), opaque where `alpha` ≥ `min_alpha`.
pub fn rgba(rgb: &[f32], alpha: &[f32], min_alpha: f32) -> Vec<u8> {
    rgb.chunks_exact(3)
        .zip(alpha)
        .flat_map(|(c, &a)| {
            let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            [
                q(c[0]),
                q(c[1]),
                q(c[2]),
                if a >= min_alpha { 255 } else { 0 },
            ]
        })
        .collect()
}

impl Session {
    /// The current model's BEV colour as RGBA over `g` (a live preview while training).
    pub async fn preview(&self, g: &BevGeometry) -> Result<Vec<u8>, GpuError> {
        let p = read_params(&self.trainer.ctx, &self.trainer.params).await?;
        let img = self.render_bev(&p, g, &mut |_, _| {}).await?;
        Ok(rgba(&img.rgb, &img.alpha, self.cfg.train.loss.min_alpha))
    }

    /// Vehicle positions of the bundle as BEV pixel coordinates (x, y pairs) of `g`.
    pub fn trajectory(b: &Bundle, g: &BevGeometry) -> Vec<f32> {
        b.manifest
            .frames
            .iter()
            .flat_map(|f| {
                let (x, y) = (f.vehicle_to_world[0][3], f.vehicle_to_world[1][3]);
                [
                    ((x - g.origin[0]) / g.resolution) as f32,
                    ((g.origin[1] - y) / g.resolution) as f32,
                ]
            })
            .collect()
    }

    /// The current model rendered into view `view` of frame `frame` (with its
    /// camera's learned exposure) beside the input image, both RGBA of the camera's
    /// size; `None` when the frame or view does not exist.
    pub async fn camera_view(
        &self,
        b: &Bundle,
        frame: usize,
        view: usize,
    ) -> Result<Option<(u32, u32, Vec<u8>, Vec<u8>)>, ReconstructError> {
        let m = &b.manifest;
        let Some(v) = m.frames.get(frame).and_then(|f| f.views.get(view)) else {
            return Ok(None);
        };
        let Some(camera) = m.cameras.iter().position(|c| c.name == v.camera) else {
            return Ok(None);
        };
        let t = &self.trainer;
        let e = t.read_exposures().await?;
        let e = e.get(camera).copied().unwrap_or([0.0, 0.0]);
        let Some(cam) = view_camera(m, frame, view, self.origin, e) else {
            return Ok(None);
        };
        let f = t
            .raster
            .forward(&t.ctx, &t.params, &cam, &self.cfg.train.cull)
            .await?;
        let img = GpuRasterizer::read_image(&t.ctx, &f).await?;
        let rendered = rgba(&img.rgb, &img.alpha, self.cfg.train.loss.min_alpha);
        let input = b.read_rgb(&v.image)?;
        let input = input
            .pixels()
            .flat_map(|p| [p.0[0], p.0[1], p.0[2], 255])
            .collect();
        Ok(Some((cam.width, cam.height, rendered, input)))
    }
}
