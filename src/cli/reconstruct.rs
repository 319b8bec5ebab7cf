//! `rogs reconstruct BUNDLE… --out DIR`: the whole job headless, with progress and
//! ETA on stderr, the map layers, the surfel PLY and report.json in DIR. Several
//! bundles (drives of the same place, one world frame) make one map; large drives
//! are trained tile by tile (`--tile-m`).

use super::progress::Progress;
use super::{EXIT_INVALID_INPUT, EXIT_MACHINE};
use crate::bundle::{Bundle, Limits};
use crate::gpu::GpuContext;
use crate::settings::Settings;
use crate::tiles::{TiledRun, DEFAULT_OVERLAP_M};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Init {
    /// Each surfel takes the height of the nearest pose's ground plane.
    Nearest,
    /// Weighted consensus of the K nearest poses' planes (the default).
    Consensus,
}

/// Which surfels an optimisation step updates (`Settings::adam`).
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum AdamMode {
    /// Every parameter of every surfel every step (the paper's Adam; the default).
    Dense,
    /// Only the surfels the step's view may see: up to 2× faster steps on large
    /// models, but a surfel's height then moves only in its views, so maps whose
    /// height must travel far from the trajectory's plane come out worse.
    Selective,
}

impl AdamMode {
    pub fn scope(self) -> crate::optim::AdamScope {
        use crate::optim::AdamScope;
        match self {
            Self::Selective => AdamScope::Selective,
            Self::Dense => AdamScope::Dense,
        }
    }

    pub fn name(self) -> &'static str {
        self.scope().name()
    }
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Baseline {
    /// Best-view colours draped on the initial surface, no optimisation.
    Ipm,
}

#[derive(clap::Args)]
pub struct Args {
    /// The scene bundle (.zip or folder); several bundles (drives of the same
    /// streets in one world frame) are merged into one map.
    #[arg(num_args = 1.., required_unless_present = "plan", conflicts_with = "plan")]
    bundles: Vec<PathBuf>,
    /// Output folder (created if missing; files in it are overwritten).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    settings: SettingsArgs,
    /// Up axis of surfels.ply and surfels_semantic.ply: z keeps the map's world frame
    /// (x east, y north, z up); y rotates them for splat viewers that expect y up.
    #[arg(long, default_value = "z")]
    ply_up: crate::export::ply::Up,
    /// Go on from where an earlier run into the same --out stopped: the tiles it
    /// finished (checkpoints in OUT/tiles/) are kept, the rest are trained. Needs the
    /// same bundles and options; a checkpoint of other settings is refused by name.
    #[arg(long)]
    resume: bool,
    /// Run one tile job of a plan made by `rogs plan` (with --tile), with the plan's
    /// bundles and settings: --out receives the tile's checkpoint NAME.tile and
    /// job.json. A valid checkpoint already there is kept (the job is done); a
    /// damaged one is trained again.
    #[arg(long, requires = "tile", conflicts_with = "SettingsArgs")]
    plan: Option<PathBuf>,
    /// The tile of --plan to run, by name (`x3_y-2`; plan.json lists them).
    #[arg(long, requires = "plan")]
    tile: Option<String>,
    /// Fault injection for tests: the GPU device is destroyed (a real device loss)
    /// as the tile of this plan index (0-based) starts.
    #[arg(long, hide = true)]
    fault_tile: Option<usize>,
}

/// The settings that change the map, shared by `rogs reconstruct` and `rogs plan`.
#[derive(clap::Args)]
pub struct SettingsArgs {
    /// Passes over the training images; the paper's one-epoch schedule is the default.
    #[arg(long, default_value_t = 1)]
    epochs: usize,
    /// Grid spacing in metres (the paper: 0.05). Coarser is faster and lighter.
    #[arg(long, default_value_t = 0.05)]
    resolution: f64,
    /// Corridor half-width around the trajectory, metres. Default: the bundle's
    /// `corridor_half_width_m` (the importers write 8 for nuScenes, 4 for KITTI), else 8.
    #[arg(long)]
    half_width: Option<f64>,
    /// Ignore the bundle's LiDAR (no LiDAR elevation loss, no LiDAR refinement cue).
    #[arg(long)]
    no_lidar: bool,
    /// Uniform grid: no road-structure-aware refinement.
    #[arg(long)]
    no_adaptive: bool,
    /// How surfel heights start.
    #[arg(long, value_enum, default_value = "consensus")]
    init: Init,
    /// Drop the trajectory-prior loss L_traj. By default it is on only where the
    /// LiDAR term is off (a bundle without LiDAR, or --no-lidar): with aligned LiDAR
    /// the prior pulls heights toward the poses' plane, the less accurate of the two.
    #[arg(long, conflicts_with = "traj_loss")]
    no_traj_loss: bool,
    /// Keep the trajectory-prior loss L_traj with LiDAR too (the paper's setting).
    #[arg(long)]
    traj_loss: bool,
    /// Which surfels a step updates: every parameter of every surfel (dense, the
    /// paper's Adam), or only those the step's view may see (selective: a step's
    /// cost follows the view, not the model; docs/PERFORMANCE.md says what it costs
    /// the map).
    #[arg(long, value_enum, default_value = "dense")]
    adam: AdamMode,
    /// Down-weight pixels whose colour residual is large (cars, people, moving
    /// shadows in a drive without labels): weight 1 / (1 + (r/C)²) for a mean
    /// residual r on a 0–1 scale, e.g. 0.1; 0 (the default) turns it off. It pays
    /// where traffic moves; on parked cars it costs 0.2–0.3 dB (docs/QUALITY.md).
    #[arg(long, value_name = "C")]
    robust_c: Option<f32>,
    /// Start the colours and classes from the pose plane's pixels, as the IPM
    /// baseline does, instead of where each surfel's LiDAR elevation puts it (an
    /// ablation: the LiDAR's start is 3 dB better on `demo`, docs/QUALITY.md).
    #[arg(long)]
    no_lidar_colours: bool,
    /// One exposure per camera only, without each frame's own gain on top (by
    /// default a view's gain is measured at its first step, against the map so
    /// far, because auto-exposure changes a real camera's brightness from frame to
    /// frame; held-out views take their neighbours').
    #[arg(long)]
    no_frame_exposure: bool,
    /// Set a learning rate by name, e.g. `--lr rgb=4e-3` (repeatable): z_start,
    /// z_end, rotation, scale, opacity, rgb, rgb_on_lidar, logits, exposure.
    #[arg(long, value_name = "NAME=RATE", value_parser = parse_rate)]
    lr: Vec<(String, f32)>,
    /// Leave every K-th frame out of training and report road PSNR on those views,
    /// for the result and for the IPM baseline.
    #[arg(long)]
    holdout_every: Option<usize>,
    /// Write a baseline instead of optimising.
    #[arg(long, value_enum)]
    baseline: Option<Baseline>,
    /// Starting z learning rate as a ratio of the scene extent (default 1.6e-3; the paper: 1.6e-4).
    #[arg(long)]
    lr_z_start: Option<f32>,
    /// Final z learning rate as a ratio of the scene extent (default 1.6e-5; the paper: 1.6e-6).
    #[arg(long)]
    lr_z_end: Option<f32>,
    /// LiDAR points farther than this (metres) from a surfel's trajectory-plane
    /// height are taken for walls or roofs and ignored by the LiDAR elevation loss
    /// (default 0.5). Raise it where the ground departs further from the road's
    /// plane (embankments).
    #[arg(long, value_parser = positive_metres)]
    lidar_gate: Option<f32>,
    /// Of the points within the gate, those farther than this (metres) from the
    /// lowest layer around the surfel are taken for the sides of cars (default 0.2).
    /// Widen it when poses are noisy and --no-pose-align is set.
    #[arg(long, value_parser = positive_metres)]
    lidar_band: Option<f32>,
    /// Keep the bundle's poses as they are. By default each frame's height, roll
    /// and pitch are corrected so that its LiDAR sweep's ground agrees with the
    /// other sweeps' (needs LiDAR; x, y and yaw are never changed).
    #[arg(long)]
    no_pose_align: bool,
    /// Stop after this many steps (for timing part of an epoch on a large bundle;
    /// report.json then estimates seconds per epoch from the steps done).
    #[arg(long)]
    max_steps: Option<usize>,
    /// Seed of the training image order.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Train the map in square tiles of this side (metres, world-aligned), one
    /// after the other, so the GPU holds one tile at a time. Default: untiled, unless
    /// the corridor would hold over 4 M surfels, then 96 m tiles (`rogs plan`: 96 m).
    #[arg(long, value_parser = positive_m64)]
    tile_m: Option<f64>,
    /// Each tile also trains this far beyond its square (metres); neighbouring
    /// tiles' layers are blended over twice this width.
    #[arg(long, default_value_t = DEFAULT_OVERLAP_M, value_parser = non_negative_m64)]
    tile_overlap_m: f64,
    /// Photometric pose refinement: learn a correction of every frame's vehicle pose
    /// (x, y, z, roll, pitch, yaw) with the map, from the images. Worth it when the
    /// poses are noisy by more than a BEV pixel; give it a few epochs (--epochs 3),
    /// since each frame is corrected once per view it has per epoch. Writes
    /// poses_refined.json.
    #[arg(long)]
    refine_poses: bool,
    /// Its learning rate of translation, metres per step (default 0.02).
    #[arg(long, requires = "refine_poses")]
    pose_lr_m: Option<f64>,
    /// Its learning rate of rotation, degrees per step (default 0.2).
    #[arg(long, requires = "refine_poses")]
    pose_lr_deg: Option<f64>,
    /// Fraction of the steps before the poses start to move, so that the map has
    /// formed first (default 0.1).
    #[arg(long, requires = "refine_poses")]
    pose_start: Option<f64>,
    /// Refine x, y and yaw only, and leave height, roll and pitch to the LiDAR
    /// alignment (the default when the poses are aligned to the LiDAR).
    #[arg(long, requires = "refine_poses", conflicts_with = "pose_all")]
    pose_planar: bool,
    /// Refine all six degrees of freedom even where the LiDAR alignment ran.
    #[arg(long, requires = "refine_poses")]
    pose_all: bool,
    /// Also refine each camera's mounting on the vehicle (its camera_to_vehicle),
    /// one correction per camera shared by every frame: for a rig whose calibration
    /// is off. poses_refined.json then lists the corrected mountings.
    #[arg(long, requires = "refine_poses")]
    pose_rig: bool,
    /// Host memory the map's whole layers may take, MiB (default 8192). A tiled map
    /// whose whole layers would need more is finished block by block (see
    /// --finish), holding only the blocks of the map the drive covers.
    #[arg(long)]
    map_memory_mib: Option<u64>,
    /// How a tiled map is finished: block by block (map.rogsmap, the tiled
    /// GeoTIFFs a block at a time, the PNG layers and elevation arrays a row of
    /// 256-px blocks at a time: the same files, holding a row of blocks) or with its
    /// whole layers held.
    #[arg(long, value_enum, default_value = "auto")]
    finish: Finish,
}

/// How a tiled map is finished (`Settings::map_finish`).
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum Finish {
    /// Block by block when the whole layers would take over 1 GiB or
    /// --map-memory-mib.
    Auto,
    /// Always block by block.
    Blocks,
    /// Whole layers, unless over --map-memory-mib.
    Whole,
}

impl SettingsArgs {
    /// The run's settings, as the page would send them.
    pub fn settings(&self) -> Settings {
        let a = self;
        Settings {
            resolution: Some(a.resolution),
            half_width: a.half_width,
            epochs: Some(a.epochs),
            lidar: Some(!a.no_lidar),
            align: Some(!a.no_pose_align),
            adaptive: Some(!a.no_adaptive),
            init: Some(
                match a.init {
                    Init::Nearest => "nearest",
                    Init::Consensus => "consensus",
                }
                .into(),
            ),
            traj_loss: match (a.traj_loss, a.no_traj_loss) {
                (true, _) => Some(true),
                (_, true) => Some(false),
                _ => None,
            },
            holdout_every: a.holdout_every,
            baseline: a.baseline.map(|_| "ipm".into()),
            lr_z_start: a.lr_z_start,
            lr_z_end: a.lr_z_end,
            lidar_gate: a.lidar_gate,
            lidar_band: a.lidar_band,
            max_steps: a.max_steps,
            seed: Some(a.seed),
            tile_m: a.tile_m,
            tile_overlap_m: Some(a.tile_overlap_m),
            ply_up: None,
            fault_tile: None,
            refine_poses: Some(a.refine_poses),
            pose_lr_m: a.pose_lr_m,
            pose_lr_deg: a.pose_lr_deg,
            pose_start: a.pose_start,
            pose_planar: a
                .pose_planar
                .then_some(true)
                .or(a.pose_all.then_some(false)),
            map_memory_mib: a.map_memory_mib,
            map_finish: match a.finish {
                Finish::Auto => None,
                Finish::Blocks => Some("blocks".into()),
                Finish::Whole => Some("whole".into()),
            },
            pose_rig: Some(a.pose_rig),
            adam: Some(a.adam.name().into()),
            robust_c: a.robust_c,
            lidar_colours: a.no_lidar_colours.then_some(false),
            frame_exposure: a.no_frame_exposure.then_some(false),
            lr: a.lr.clone(),
        }
    }
}

/// `NAME=RATE` of `--lr`.
fn parse_rate(s: &str) -> Result<(String, f32), String> {
    let (name, v) = s
        .split_once('=')
        .ok_or_else(|| format!("{s:?}: expected NAME=RATE, such as rgb=4e-3"))?;
    let v: f32 = v
        .parse()
        .map_err(|_| format!("{v:?} is not a number (in {s:?})"))?;
    Ok((name.to_string(), v))
}

/// Opens the bundles and merges them into one; on bad input, the exit code (the
/// problem is printed).
pub(super) fn open_bundles(paths: &[PathBuf]) -> Result<Bundle, ExitCode> {
    let mut bundles = Vec::new();
    for path in paths {
        let mut bar = Progress::new("open");
        match Bundle::open(path, Limits::default(), &mut |d, t| bar.update(d, t)) {
            Ok(b) => bundles.push(b),
            Err(e) => {
                bar.finish();
                eprintln!("{}: invalid bundle: {e}", path.display());
                return Err(ExitCode::from(EXIT_INVALID_INPUT));
            }
        }
        bar.finish();
    }
    let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    Bundle::merge(bundles, &names).map_err(|e| {
        eprintln!("cannot merge the drives into one map: {e}");
        ExitCode::from(EXIT_INVALID_INPUT)
    })
}

/// Aligns, plans and prepares the run of settings `s` on `b`; `tiled`: always in
/// tiles (96 m when `s` names no size), as a plan is. Bad input is printed and
/// answered with its exit code.
pub(super) fn start(b: &mut Bundle, s: &Settings, tiled: bool) -> Result<TiledRun, ExitCode> {
    let (mut cfg, asked) = match s
        .config(&b.manifest, crate::settings::CLI)
        .and_then(|c| Ok((c, s.tiling()?)))
    {
        Ok(v) => v,
        Err(e) => {
            eprintln!("invalid settings: {e}");
            return Err(ExitCode::from(EXIT_INVALID_INPUT));
        }
    };
    // Files are written here: a map too large for whole layers streams into them.
    cfg.map.stream = true;
    let tiling = match tiled {
        true => Some(asked.unwrap_or_default()),
        false => crate::tiles::choose(&b.manifest, &cfg, asked),
    };
    let ctx = match GpuContext::new_blocking() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            return Err(ExitCode::from(EXIT_MACHINE));
        }
    };
    eprintln!("preparing surfels…");
    match pollster::block_on(TiledRun::new(b, cfg, tiling, ctx)) {
        Ok(r) => Ok(r),
        Err(e) if e.is_input() => {
            eprintln!("cannot map this bundle with these settings: {e}");
            Err(ExitCode::from(EXIT_INVALID_INPUT))
        }
        Err(e) => {
            eprintln!("error: {e}");
            Err(ExitCode::from(EXIT_MACHINE))
        }
    }
}

/// The tile job `--plan P --tile NAME` asks for, if any: (plan, tile, out).
pub fn tile_job(a: &Args) -> Option<(&std::path::Path, &str, &std::path::Path)> {
    Some((a.plan.as_deref()?, a.tile.as_deref()?, &a.out))
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let names: Vec<String> = a.bundles.iter().map(|p| p.display().to_string()).collect();
    let mut b = match open_bundles(&a.bundles) {
        Ok(b) => b,
        Err(code) => return Ok(code),
    };
    std::fs::create_dir_all(&a.out)
        .map_err(|e| format!("cannot create {}: {e}", a.out.display()))?;
    let s = a.settings.settings();
    let mut run = match start(&mut b, &s, false) {
        Ok(r) => r,
        Err(code) => return Ok(code),
    };
    run.fault_tile = a.fault_tile;
    let tiles_dir = a.out.join("tiles");
    if run.tiling.is_some() {
        run.checkpoints = true;
        // The finished tiles' surfels are in their checkpoints: not held twice.
        run.spill_models(tiles_dir.clone());
        run.write_checkpoints_into(tiles_dir.clone());
        if a.resume {
            match resume(&mut run, &tiles_dir) {
                Ok(n) => eprintln!(
                    "resumed: {n} finished tiles restored from {}",
                    tiles_dir.display()
                ),
                Err(e) => {
                    eprintln!("cannot resume: {e}");
                    return Ok(ExitCode::from(EXIT_INVALID_INPUT));
                }
            }
        }
    } else if a.resume {
        eprintln!("nothing to resume: this run is not tiled (only tiled runs keep checkpoints; see --tile-m)");
    }
    match &run.tiling {
        Some(t) => eprintln!(
            "{} tiles of {} m (overlap {} m), {} steps planned, {} drive(s)",
            run.tiles.len(),
            t.size_m,
            t.overlap_m,
            run.total_steps(),
            b.drives.len()
        ),
        None => {
            if let Some(s) = &run.session {
                eprintln!(
                    "{} surfels ({} added by refinement), {} training views, {} held out",
                    s.prepare_report.surfels,
                    s.prepare_report.added_surfels,
                    s.train_views.len(),
                    s.holdout_views.len()
                );
            }
        }
    }
    let stopped = train(&mut run, &b, &tiles_dir)?;
    if stopped && run.tiling.is_some() {
        eprintln!(
            "{} finished tiles are kept in {}: run the same command with --resume to go on",
            run.tiles_done(),
            tiles_dir.display()
        );
    }
    write_map(&a.out, &mut run, &b, &names.join(" + "), a.ply_up)?;
    if !stopped && tiles_dir.is_dir() {
        // The map is written: its tiles' checkpoints are no longer needed.
        let _ = std::fs::remove_dir_all(&tiles_dir);
    }
    Ok(if stopped {
        ExitCode::from(EXIT_MACHINE)
    } else {
        ExitCode::SUCCESS
    })
}

/// Steps the run to its end with a progress bar, writing each finished tile's
/// checkpoint into `tiles_dir`; true when a failure stopped it (it is printed).
pub(super) fn train(
    run: &mut TiledRun,
    b: &Bundle,
    tiles_dir: &std::path::Path,
) -> Result<bool, String> {
    let mut bar = Progress::new("optimise");
    let mut stopped = false;
    loop {
        let r = pollster::block_on(run.step(b));
        write_checkpoints(run, tiles_dir)?;
        match r {
            Ok(Some(l)) => {
                let tile = match run.current_tile() {
                    Some((k, name)) => format!("tile {}/{} {name}, ", k + 1, run.tile_count()),
                    None => String::new(),
                };
                bar.set_message(&format!("{tile}loss {:.4}", l.total()));
                bar.update(run.steps_done(), run.total_steps());
            }
            Ok(None) => break,
            Err(e) => {
                eprintln!("\nerror: {e}");
                stopped = true;
                break;
            }
        }
    }
    bar.finish();
    Ok(stopped)
}

/// Stitches and scores the run's map and writes every output into `out`: the
/// model first (training is never lost, whatever happens to the BEV), then the
/// layers, report.json and map.rogsmap.
pub(super) fn write_map(
    out: &std::path::Path,
    run: &mut TiledRun,
    b: &Bundle,
    name: &str,
    ply_up: crate::export::ply::Up,
) -> Result<(), String> {
    if run.streamed {
        return write_streamed(out, run, b, name, ply_up);
    }
    let mut bar = Progress::new("BEV");
    let outcome = pollster::block_on(run.finish(b, &mut |d, t| bar.update(d, t)));
    bar.finish();
    let model = write_model(out, run, b, ply_up)?;
    let o = outcome.map_err(|e| {
        format!(
            "{e} (the trained model was written to {})",
            out.join("surfels.ply").display()
        )
    })?;
    let mut files = crate::export::files(&o, &b.manifest)?;
    let mut report = run.report(b, &o, name);
    let embedded = serde_json::to_vec_pretty(&report).map_err(|e| e.to_string())?;
    let map = crate::export::map_file::write(&o, b, &embedded)?;
    final_peak(&mut report);
    let report = serde_json::to_vec_pretty(&report).map_err(|e| e.to_string())?;
    files.push(("report.json".into(), report));
    if let Some(p) = run.pose_refiner() {
        let json = serde_json::to_vec_pretty(&p.file(&b.manifest)).map_err(|e| e.to_string())?;
        files.push(("poses_refined.json".into(), json));
    }
    files.push(("map.rogsmap".into(), map));
    write_files(out, &files)?;
    if let Some(m) = &o.metrics {
        eprintln!("metrics: {}", serde_json::to_string(m).unwrap_or_default());
    }
    if let Some(h) = &o.holdout {
        eprintln!(
            "held-out road PSNR {:.2} dB (IPM baseline {:.2} dB) over {} frames",
            h.psnr_db, h.ipm_psnr_db, h.frames
        );
    }
    eprintln!("wrote {} files to {}", model + files.len(), out.display());
    Ok(())
}

/// report.json's `peak_host_bytes` read again once every output but the small files
/// is made: the run's peak includes encoding map.rogsmap and the layers, which come
/// after the report is first built (map.rogsmap embeds that first reading).
fn final_peak(report: &mut serde_json::Value) {
    if let Some(p) = crate::mem::peak_host_bytes() {
        report["peak_host_bytes"] = p.into();
    }
}

/// As `write_map`, for a map too large for whole layers (`TiledRun::streamed`): the
/// model, map.rogsmap written block by block, report.json, bev.json.
fn write_streamed(
    out: &std::path::Path,
    run: &mut TiledRun,
    b: &Bundle,
    name: &str,
    ply_up: crate::export::ply::Up,
) -> Result<(), String> {
    let model = write_model(out, run, b, ply_up)?;
    let g = run.geometry;
    let channels = run.model().0.channels();
    let dense = crate::export::layers::dense(&g);
    eprintln!(
        "the map is {}×{} px: its whole layers would take {} MiB, over the budget (--map-memory-mib), \
         so every layer is written block by block: map.rogsmap, the tiled GeoTIFFs{}",
        g.width,
        g.height,
        crate::tiles::Stitcher::bytes(&g, channels) >> 20,
        if dense {
            ", and the PNG layers and elevation arrays a row of blocks at a time"
        } else {
            " (no PNG layers or elevation arrays: the map has over 2^28 pixels)"
        }
    );
    let create = |n: &str| {
        let p = out.join(n);
        std::fs::File::create(&p)
            .map(std::io::BufWriter::new)
            .map_err(|e| format!("cannot create {}: {e}", p.display()))
    };
    let mut bar = Progress::new("map");
    let done = pollster::block_on(run.finish_streamed(
        b,
        name,
        create("map.rogsmap")?,
        &mut |d, t| bar.update(d, t),
    ));
    bar.finish();
    let done = done.map_err(|e| {
        format!(
            "{e} (the trained model was written to {})",
            out.join("surfels.ply").display()
        )
    })?;
    // The raster layers straight into their files.
    let names = crate::export::layers::names(&g, &b.manifest, run.has_truth());
    let mut sinks = Vec::new();
    for n in &names {
        sinks.push((n.to_string(), create(n)?));
    }
    let mut bar = Progress::new("layers");
    run.write_layers(b, done.range, &mut sinks, &mut |d, t| bar.update(d, t))?;
    bar.finish();
    for (n, mut w) in sinks {
        std::io::Write::flush(&mut w).map_err(|e| format!("{}: {e}", out.join(n).display()))?;
    }
    let json = |v: &serde_json::Value| serde_json::to_vec_pretty(v).map_err(|e| e.to_string());
    let mut files = crate::export::side_files(&g, &b.manifest, done.range, run.has_truth());
    let mut report = done.report;
    final_peak(&mut report);
    files.push(("report.json".to_string(), json(&report)?));
    let mut map = done.map;
    std::io::Write::flush(&mut map)
        .map_err(|e| format!("{}: {e}", out.join("map.rogsmap").display()))?;
    drop(map);
    if let Some(p) = run.pose_refiner() {
        files.push(("poses_refined.json".into(), json(&p.file(&b.manifest))?));
    }
    write_files(out, &files)?;
    if let Some(m) = &done.outcome.metrics {
        eprintln!("metrics: {}", serde_json::to_string(m).unwrap_or_default());
    }
    eprintln!(
        "wrote {} files to {}",
        model + 1 + names.len() + files.len(),
        out.display()
    );
    Ok(())
}

/// Writes the checkpoints of the tiles finished since the last call
/// (`name.tile.part`, then renamed: a run killed while writing leaves no half
/// checkpoint).
pub(super) fn write_checkpoints(run: &mut TiledRun, dir: &std::path::Path) -> Result<(), String> {
    while let Some((name, bytes)) = run.take_checkpoint() {
        crate::tiles::checkpoint::write_whole(dir, &name, |w| {
            std::io::Write::write_all(w, &bytes).map_err(|e| e.to_string())
        })?;
    }
    Ok(())
}

/// Restores every checkpoint in `dir`; the count, or which file was refused and why.
fn resume(run: &mut TiledRun, dir: &std::path::Path) -> Result<usize, String> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(0);
    };
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "tile"))
        .collect();
    paths.sort();
    for p in &paths {
        let bytes = std::fs::read(p).map_err(|e| format!("cannot read {}: {e}", p.display()))?;
        run.restore_file(&bytes, Some(p)).map_err(|e| {
            format!(
                "{}: {e} (delete the file to train its tile again)",
                p.display()
            )
        })?;
    }
    Ok(paths.len())
}

fn positive_m64(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!(
            "{s:?}: expected a positive number of metres, such as 64"
        )),
    }
}

fn non_negative_m64(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!(
            "{s:?}: expected a number of metres, 0 or more, such as 4"
        )),
    }
}

/// A distance in metres that must be positive and finite.
fn positive_metres(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!(
            "{s:?}: expected a positive number of metres, such as 0.3"
        )),
    }
}

/// Writes the model's files into `out` a tile at a time (tiles spilled to their
/// checkpoints read back one by one); how many files.
fn write_model(
    out: &std::path::Path,
    run: &TiledRun,
    b: &Bundle,
    up: crate::export::ply::Up,
) -> Result<usize, String> {
    let (m, origin) = run.model();
    let open = |name: &str| {
        let p = out.join(name);
        std::fs::File::create(&p)
            .map(std::io::BufWriter::new)
            .map_err(|e| format!("cannot write {}: {e}", p.display()))
    };
    let mut w = crate::export::ModelWriter::start(open, m.len(), origin, &b.manifest, up)?;
    m.write(&mut w)?;
    Ok(w.finish()?.len())
}

fn write_files(dir: &std::path::Path, files: &[(String, Vec<u8>)]) -> Result<(), String> {
    for (name, bytes) in files {
        let p = dir.join(name);
        std::fs::write(&p, bytes).map_err(|e| format!("cannot write {}: {e}", p.display()))?;
    }
    Ok(())
}
