//! Tile jobs: a tiled reconstruction written out as independent jobs, so that a
//! scheduler (a Ray cluster, a batch queue, a shell loop) can run its tiles on other
//! processes or machines and one merge stitches their outputs into the map.
//!
//! `rogs plan` writes `PLAN/plan.json` (this module's `PlanFile`) and one
//! `PLAN/jobs/NAME.json` per tile (`JobFile`); `rogs reconstruct --plan PLAN --tile
//! NAME --out TILES/NAME` runs one job and leaves the tile's checkpoint
//! (`TILES/NAME/NAME.tile`, the format `--resume` restores); `rogs merge PLAN TILES
//! --out MAP` restores every tile's checkpoint in the plan's order and writes the map.
//! Tiles are independent (no tile's training reads another's) and the merge adds
//! them in the order the single-process run does, so the merged map is that run's,
//! bit for bit (tests/jobs.rs).
//!
//! Every process of a plan opens the same bundles with the same settings and checks
//! that it arrives at the plan's fingerprint (a hash of the manifest after pose
//! alignment, the settings and the tile plan): a job on a machine that read other
//! bundles or runs another rogs refuses to run instead of making a tile that does not
//! fit. docs/DISTRIBUTED.md documents the files.

use super::{TileConfig, TiledRun};
use crate::bev::BevGeometry;
use crate::grid::Rect;
use crate::settings::Settings;
use serde::{Deserialize, Serialize};

pub const PLAN_FORMAT: &str = "rogs-plan";
pub const JOB_FORMAT: &str = "rogs-tile-job";
pub const VERSION: u32 = 1;

/// `plan.json`: the run every job belongs to.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PlanFile {
    pub format: String,
    pub version: u32,
    /// The bundles, in order (absolute paths, or relative to the plan's folder).
    pub bundles: Vec<String>,
    /// The settings every job runs with (`rogs reconstruct`'s, as the page sends them).
    pub settings: Settings,
    /// The run's fingerprint (hex): every job and the merge must arrive at it.
    pub fingerprint: String,
    pub tiling: TileConfig,
    /// The map's raster: west and north edges, metres per pixel, size.
    pub geometry: GeometryFile,
    /// Training steps over all tiles.
    pub steps: usize,
    /// The tiles in the order the merge adds them.
    pub jobs: Vec<JobRef>,
}

/// A tile of `plan.json`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JobRef {
    /// The tile's name (`x3_y-2`): its job file is `jobs/NAME.json`, its output folder
    /// `TILES/NAME`, its checkpoint `TILES/NAME/NAME.tile`.
    pub tile: String,
    pub index: usize,
    /// Views that see the tile (its training images, once per epoch).
    pub views: usize,
    /// Training steps the schedule gives it (a scheduler's cost estimate).
    pub steps: usize,
}

/// `jobs/NAME.json`: one tile job, complete enough to schedule without the plan.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JobFile {
    pub format: String,
    pub version: u32,
    pub tile: String,
    pub index: usize,
    pub fingerprint: String,
    /// The square the tile owns and the rect it trains (core and overlap), metres.
    pub core: Rect,
    pub rect: Rect,
    /// (frame, view) of every view that sees the tile, in the merged bundle's order.
    pub views: Vec<[usize; 2]>,
    pub steps: usize,
    /// The seed of the tile's training image order (the plan's `settings.seed`).
    pub seed: u64,
    /// The run's settings (the plan's): what the job trains with.
    pub settings: Settings,
    /// The command that runs the job, `{plan}` and `{tiles}` standing for the plan's
    /// folder and the tile outputs' folder.
    pub command: Vec<String>,
}

/// `BevGeometry` as a plan records it.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct GeometryFile {
    pub origin: [f64; 2],
    pub resolution: f64,
    pub width: u32,
    pub height: u32,
}

impl From<BevGeometry> for GeometryFile {
    fn from(g: BevGeometry) -> Self {
        Self {
            origin: g.origin,
            resolution: g.resolution,
            width: g.width,
            height: g.height,
        }
    }
}

/// The output folder of tile `name` and its checkpoint file, under `tiles`.
pub fn checkpoint_path(tiles: &std::path::Path, name: &str) -> std::path::PathBuf {
    tiles
        .join(name)
        .join(format!("{name}{}", super::checkpoint::SUFFIX))
}

impl PlanFile {
    /// The plan of a tiled run (`run.tiling` must be set) over `bundles`.
    pub fn of(run: &TiledRun, bundles: Vec<String>, settings: Settings) -> Result<Self, String> {
        let tiling = run
            .tiling
            .ok_or("a plan needs a tiled run (--tile-m)".to_string())?;
        let jobs = run
            .tiles
            .iter()
            .enumerate()
            .map(|(index, t)| JobRef {
                tile: t.name(),
                index,
                views: t.views.len(),
                steps: run.planned_steps_of(t),
            })
            .collect();
        Ok(Self {
            format: PLAN_FORMAT.into(),
            version: VERSION,
            bundles,
            settings,
            fingerprint: format!("{:016x}", run.fingerprint),
            tiling,
            geometry: run.geometry.into(),
            steps: run.total_steps(),
            jobs,
        })
    }

    /// The job file of tile `index` of the run this plan was made from.
    pub fn job(&self, run: &TiledRun, index: usize) -> Option<JobFile> {
        let t = run.tiles.get(index)?;
        let r = self.jobs.get(index)?;
        Some(JobFile {
            format: JOB_FORMAT.into(),
            version: VERSION,
            tile: r.tile.clone(),
            index,
            fingerprint: self.fingerprint.clone(),
            core: t.core,
            rect: t.rect,
            views: t.views.iter().map(|&(f, v)| [f, v]).collect(),
            steps: r.steps,
            seed: self.settings.seed.unwrap_or(0),
            settings: self.settings.clone(),
            command: [
                "rogs",
                "reconstruct",
                "--plan",
                "{plan}",
                "--tile",
                &r.tile,
                "--out",
                &format!("{{tiles}}/{}", r.tile),
            ]
            .map(String::from)
            .to_vec(),
        })
    }

    /// Reads `plan.json`; the error names what is wrong.
    pub fn parse(bytes: &[u8]) -> Result<Self, String> {
        let de = &mut serde_json::Deserializer::from_slice(bytes);
        let p: Self = serde_path_to_error::deserialize(de).map_err(|e| {
            let path = e.path().to_string();
            format!(
                "{}: {}",
                if path == "." { "plan" } else { &path },
                e.inner()
            )
        })?;
        if p.format != PLAN_FORMAT || p.version != VERSION {
            return Err(format!(
                "format {:?} version {}, expected {PLAN_FORMAT:?} version {VERSION} (made by `rogs plan`)",
                p.format, p.version
            ));
        }
        if p.bundles.is_empty() || p.jobs.is_empty() {
            return Err("a plan names at least one bundle and one tile job".into());
        }
        Ok(p)
    }

    /// The plan's index of tile `name`.
    pub fn index_of(&self, name: &str) -> Result<usize, String> {
        self.jobs
            .iter()
            .position(|j| j.tile == name)
            .ok_or_else(|| {
                let names: Vec<&str> = self.jobs.iter().map(|j| j.tile.as_str()).collect();
                let shown = names
                    .iter()
                    .take(12)
                    .copied()
                    .collect::<Vec<_>>()
                    .join(", ");
                format!(
                    "tile {name:?} is not in the plan; its {} tiles are {shown}{}",
                    names.len(),
                    if names.len() > 12 { ", …" } else { "" }
                )
            })
    }

    /// Whether `run` (made from this plan's bundles and settings) is the plan's run.
    pub fn check(&self, run: &TiledRun) -> Result<(), String> {
        let fp = format!("{:016x}", run.fingerprint);
        if fp != self.fingerprint || run.tiles.len() != self.jobs.len() {
            return Err(format!(
                "the bundles and settings read here give fingerprint {fp} and {} tiles, the plan's \
                 are {} and {} tiles: a bundle changed since the plan was made, or another rogs \
                 version made it; make the plan again with `rogs plan`",
                run.tiles.len(),
                self.fingerprint,
                self.jobs.len()
            ));
        }
        Ok(())
    }
}
