//! What a run reads, before it reads it: the page opens a long drive lazily (its zip's
//! directory only) and hands the engine the files of one tile at a time, so the wasm
//! heap holds one tile's images, labels and sweeps, never the drive
//! (docs/ARCHITECTURE.md, "Lazy reading").
//!
//! A tile reads the images and labels of every view of its near frames (colour
//! candidates, held-out views) and of the views that see it (training), and the
//! sweeps of its near frames when the LiDAR is in use. An untiled run reads every
//! file. The start reads the truth's files (and, when it aligns, every sweep: the
//! page streams those a batch at a time through `align::gather_ground_returns`).

use super::{Tile, TileConfig, TiledRun};
use crate::bundle::{Bundle, LazyFiles, Problem};
use crate::gpu::GpuContext;
use crate::init::align::{gather_ground_returns, GroundReturns};
use crate::optim::train::StepLoss;
use crate::reconstruct::{aligns, Outcome, ReconstructConfig, ReconstructError};
use std::collections::BTreeSet;

/// The files tile `t` reads while it is built, trained and recorded.
pub fn tile_files(b: &Bundle, cfg: &ReconstructConfig, t: &Tile) -> Vec<String> {
    let m = &b.manifest;
    let mut out = BTreeSet::new();
    let lidar = cfg.train.use_lidar || cfg.prepare.use_lidar;
    for (f, frame) in m.frames.iter().enumerate() {
        if !t.near_frames.get(f).copied().unwrap_or(false) {
            continue;
        }
        for k in 0..frame.views.len() {
            out.extend(b.view_files(f, k).into_iter().map(String::from));
        }
        if let (true, Some(l)) = (lidar, &frame.lidar) {
            out.insert(l.clone());
        }
    }
    for &(f, k) in &t.views {
        out.extend(b.view_files(f, k).into_iter().map(String::from));
    }
    out.into_iter().collect()
}

/// Every file an untiled run reads.
fn all_files(b: &Bundle, cfg: &ReconstructConfig) -> Vec<String> {
    let lidar = cfg.train.use_lidar || cfg.prepare.use_lidar;
    let m = &b.manifest;
    let mut out = BTreeSet::new();
    for (f, frame) in m.frames.iter().enumerate() {
        for k in 0..frame.views.len() {
            out.extend(b.view_files(f, k).into_iter().map(String::from));
        }
        if let (true, Some(l)) = (lidar, &frame.lidar) {
            out.insert(l.clone());
        }
    }
    out.into_iter().collect()
}

/// The files `TiledRun::new` reads besides the sweeps its alignment gathers: the
/// truth's, and for an untiled run every file (it builds its one session at once).
pub fn start_files(b: &Bundle, cfg: &ReconstructConfig, tiled: bool) -> Vec<String> {
    let mut out: Vec<String> = b
        .manifest
        .ground_truth
        .iter()
        .flat_map(|gt| [&gt.rgb, &gt.class_ids, &gt.elevation, &gt.valid])
        .cloned()
        .collect();
    if !tiled {
        out.extend(all_files(b, cfg));
    }
    out
}

impl TiledRun {
    /// The files the next `step` reads: the current tile's until it is recorded,
    /// and the next tile's once the current one's steps are done (a step records one
    /// tile and starts the next). Hold these, drop the rest, and `step`; a step that
    /// still lacks a file (the tile after an empty one) returns an error whose
    /// `not_loaded()` names it, changes nothing, and can be stepped again.
    pub fn wanted(&self, b: &Bundle) -> Vec<String> {
        if self.tiling.is_none() {
            return all_files(b, &self.cfg);
        }
        let mut out = BTreeSet::new();
        let current = self.started.checked_sub(1).and_then(|k| self.tiles.get(k));
        let live = self.session.is_some() && !self.recorded;
        if let (Some(t), true) = (current, live) {
            out.extend(tile_files(b, &self.cfg, t));
        }
        let done = self.session.as_ref().is_none_or(|s| s.is_done()) || self.recorded;
        if let (Some(t), true, None) = (self.tiles.get(self.started), done, &self.failed) {
            out.extend(tile_files(b, &self.cfg, t));
        }
        out.into_iter().collect()
    }
}

/// Reads the files a lazily read run asks for: given (drive, path within the
/// drive), resolves to their bytes in the same order, or to a sentence.
pub type Fetch<'a> = dyn FnMut(Vec<(usize, String)>) -> Fetched<'a> + 'a;

/// What a `Fetch` resolves to.
pub type Fetched<'a> =
    std::pin::Pin<Box<dyn std::future::Future<Output = Result<Vec<Vec<u8>>, String>> + 'a>>;

/// Makes `files` hold exactly `wanted`: drops the rest, fetches what is missing and
/// checks what arrived as opening the bundle eagerly would have (a bad image fails
/// here, by name, before any work reads it).
pub async fn hold(
    b: &Bundle,
    files: &LazyFiles,
    wanted: &[String],
    fetch: &mut Fetch<'_>,
) -> Result<(), ReconstructError> {
    files.retain(wanted);
    let missing = files.missing(wanted);
    if missing.is_empty() {
        return Ok(());
    }
    let first = missing[0].1.clone();
    let bytes = fetch(missing.clone())
        .await
        .map_err(|reason| Problem::Unreadable {
            path: first.clone(),
            reason,
        })?;
    if bytes.len() != missing.len() {
        return Err(Problem::Unreadable {
            path: first,
            reason: format!("{} files asked for, {} read", missing.len(), bytes.len()),
        }
        .into());
    }
    for ((k, p), data) in missing.iter().zip(bytes) {
        files.provide(*k, p, data)?;
    }
    match files.check(b, &missing).into_iter().next() {
        Some(p) => Err(p.into()),
        None => Ok(()),
    }
}

/// Sweeps gathered per batch while aligning a lazily read drive.
const SWEEP_BATCH_BYTES: u64 = 64 << 20;

/// `TiledRun::new` over a lazily read bundle: when it aligns and is tiled, the
/// sweeps a batch at a time, keeping only their ground returns; then the truth's
/// files (an untiled run is given every file at once).
pub async fn start_lazy(
    b: &mut Bundle,
    files: &LazyFiles,
    cfg: ReconstructConfig,
    tiling: Option<TileConfig>,
    ctx: GpuContext,
    fetch: &mut Fetch<'_>,
) -> Result<TiledRun, ReconstructError> {
    let start = start_files(b, &cfg, tiling.is_some());
    // The sweeps first, a batch at a time and nothing else held (the truth's files of
    // a long drive are hundreds of MB), then the start's files.
    let returns = match (aligns(&cfg), tiling) {
        (Some(a), Some(_)) => {
            let a = a.clone();
            let m = &b.manifest;
            let sweeps: Vec<(usize, String)> = m
                .frames
                .iter()
                .enumerate()
                .filter_map(|(f, fr)| fr.lidar.clone().map(|l| (f, l)))
                .collect();
            let mut returns = GroundReturns::new(m.frames.len());
            let mut k = 0;
            while k < sweeps.len() {
                let (mut batch, mut bytes) = (Vec::new(), 0u64);
                while k < sweeps.len() && (batch.is_empty() || bytes < SWEEP_BATCH_BYTES) {
                    bytes += b.source().size(&sweeps[k].1).unwrap_or(0);
                    batch.push(sweeps[k].clone());
                    k += 1;
                }
                let want: Vec<String> = batch.iter().map(|s| s.1.clone()).collect();
                hold(b, files, &want, fetch).await?;
                let mut mask = vec![false; b.manifest.frames.len()];
                for (f, _) in &batch {
                    mask[*f] = true;
                }
                gather_ground_returns(b, &a, Some(&mask), &mut returns)?;
            }
            Some(returns)
        }
        _ => None,
    };
    hold(b, files, &start, fetch).await?;
    let run = TiledRun::new_with(b, cfg, tiling, ctx, returns).await;
    files.retain(&[]);
    run
}

/// `TiledRun::step` over a lazily read bundle: holds what the step will read first.
pub async fn step_lazy(
    run: &mut TiledRun,
    b: &Bundle,
    files: &LazyFiles,
    fetch: &mut Fetch<'_>,
) -> Result<Option<StepLoss>, ReconstructError> {
    // A step can find a file missing only where the plan could not foresee it
    // (after an empty tile): a few rounds always suffice.
    let mut last = None;
    for _ in 0..8 {
        let wanted = run.wanted(b);
        hold(b, files, &wanted, fetch).await?;
        match run.step(b).await {
            Err(e) if e.not_loaded().is_some() => last = Some(e),
            r => return r,
        }
    }
    Err(last.unwrap_or(ReconstructError::NoViews))
}

/// `TiledRun::finish` over a lazily read bundle: the last tile's files (it may not
/// be recorded yet) and the thumbnails' images. Without truth, the LiDAR
/// pseudo-ground-truth would need every file: a lazily read map has no metrics then.
pub async fn finish_lazy(
    run: &mut TiledRun,
    b: &Bundle,
    files: &LazyFiles,
    fetch: &mut Fetch<'_>,
) -> Result<Outcome, ReconstructError> {
    let mut wanted = run.wanted(b);
    for f in crate::export::map_file::thumbnail_frames(&b.manifest) {
        if let Some(v) = b.manifest.frames[f].views.first() {
            wanted.push(v.image.clone());
        }
    }
    hold(b, files, &wanted, fetch).await?;
    run.finish(b, &mut |_, _| {}).await
}
