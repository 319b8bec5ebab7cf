//! A map too large for whole-image layers (`TiledRun::streamed`), finished block by
//! block: each `BLOCK`-pixel block of the blend becomes the outcome of its own small
//! window (`Outcome::block`), whose pixels go straight into map.rogsmap's level-0
//! tile of the same place, and whose sums (PSNR, IoU, seams, the elevation range)
//! add up to the whole map's. Nothing the size of the map's bounding box is ever
//! allocated; the blend holds the blocks the drive covers.

use super::stitch::{Stitcher, Window, BLOCK};
use super::{SeamSums, TiledRun};
use crate::bev::BevImage;
use crate::bundle::{Bundle, Manifest};
use crate::eval::{elevation_vs_raster, BevRaster, Tally};
use crate::export::layers::LayerFiles;
use crate::export::map_file::{self, MapIndex, MapSource, Region};
use crate::reconstruct::{road_channels, Outcome, ReconstructError};
use crate::render::Params;
use std::io::{Seek, Write};
use web_time::Instant;

/// A streamed map: the map file (written into the sink given) and the report it
/// holds.
pub struct StreamedMap<W> {
    pub map: W,
    pub report: serde_json::Value,
    pub outcome: Outcome,
    /// The elevation's range over the whole map (the elevation layer's colours).
    pub range: (f32, f32),
}

/// The blend's blocks as a map source: block (bx, by) is level-0 tile (bx, by).
struct BlockSource<'a> {
    stitch: &'a Stitcher,
    truth: Option<&'a BevRaster>,
    road: &'a [(usize, u8)],
    min_alpha: f32,
    manifest: &'a Manifest,
    index: &'a MapIndex,
    range: (f32, f32),
}

impl BlockSource<'_> {
    fn outcome(&self, bx: u32, by: u32) -> Option<Outcome> {
        self.window(bx, by).map(|w| w.1)
    }

    /// Block (bx, by)'s window and outcome.
    fn window(&self, bx: u32, by: u32) -> Option<(Window, Outcome)> {
        let (w, layers) = self.stitch.block(bx, by)?;
        let o = Outcome::block(w.geometry, layers, self.truth, self.road, self.min_alpha);
        Some((w, o))
    }
}

impl MapSource for BlockSource<'_> {
    fn region(&self, x0: u32, y0: u32, w: u32, h: u32) -> Result<Option<Region>, String> {
        if !x0.is_multiple_of(BLOCK) || !y0.is_multiple_of(BLOCK) || w > BLOCK || h > BLOCK {
            return Err(format!(
                "map tiles of {w}×{h} px at ({x0}, {y0}) do not fall on the blend's {BLOCK}-px blocks"
            ));
        }
        Ok(self
            .outcome(x0 / BLOCK, y0 / BLOCK)
            .map(|o| map_file::region_of(&o, self.manifest, self.index, self.range)))
    }
}

impl TiledRun {
    /// The map of a run whose whole layers would not fit (`streamed`), written block
    /// by block: map.rogsmap (into `map`) with every layer, and report.json (metrics against the
    /// truth summed over the blocks; seams over neighbouring pixels of one block).
    /// `progress(done, total)` counts blocks twice: scoring, then writing.
    pub async fn finish_streamed<W: Write + Seek>(
        &mut self,
        b: &Bundle,
        bundle: &str,
        map: W,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<StreamedMap<W>, ReconstructError> {
        if self.session.is_some() && !self.recorded && self.failed.is_none() {
            self.record(b).await?;
        }
        let t = Instant::now();
        let road = road_channels(b);
        let m = &b.manifest;
        let mut src = BlockSource {
            stitch: &self.stitch,
            truth: self.truth.as_ref(),
            road: &road,
            min_alpha: self.cfg.train.loss.min_alpha,
            manifest: m,
            index: &map_file::run_index(m, &self.geometry, false, (0.0, 1.0)),
            range: (0.0, 1.0),
        };
        // Pass 1: the sums, and the elevation's range the layer's colours span.
        let blocks = self.stitch.blocks();
        let mut tally = Tally::default();
        let mut seams = SeamSums::default();
        let (mut lo, mut hi) = (f32::MAX, f32::MIN);
        for (k, &(bx, by)) in blocks.iter().enumerate() {
            progress(k, 2 * blocks.len());
            let Some(o) = src.outcome(bx, by) else {
                continue;
            };
            for z in crate::export::elevation(&o)
                .into_iter()
                .filter(|z| z.is_finite())
            {
                (lo, hi) = (lo.min(z), hi.max(z));
            }
            if let Some(t) = &o.truth {
                tally.add(&o.raster, t);
            }
            if let Some(c) = self.tiling {
                seams.add(&o.raster, &c);
            }
        }
        let range = if lo > hi { (0.0, 1.0) } else { (lo, hi) };
        let road_ids = crate::eval::road_classes(m);
        let centres = self.model.centres().map_err(ReconstructError::Checkpoint)?;
        let metrics = self.truth.as_ref().map(|t| {
            let mut m = tally.metrics(&road_ids, elevation_vs_raster(&centres, t));
            m.initial_elevation_rmse_m = self.initial_rmse();
            // Of the whole truth: blocks where no tile rendered hold truth cells too.
            let cells = t.valid.pixels().filter(|v| v.0[0] != 0).count();
            m.coverage = (cells > 0).then(|| tally.covered() as f64 / cells as f64);
            m
        });
        // The report reads the map's geometry, metrics and held-out scores.
        let g = self.geometry;
        let outcome = Outcome {
            params: Params::default(),
            geometry: g,
            bev: BevImage::blank(0, 0, self.model.channels()),
            raster: BevRaster::empty(g.origin, g.resolution, 0, 0),
            confidence: Vec::new(),
            density: Vec::new(),
            truth: None,
            metrics,
            holdout: self.holdout.holdout(self.holdout_views),
        };
        let mut report = self.report(b, &outcome, bundle);
        report["seams"] = serde_json::to_value(seams.seams()).unwrap_or_default();
        report["map_layers"] = serde_json::json!({
            "streamed": true,
            "blocks": blocks.len(),
            "block_px": BLOCK,
            "held_bytes": self.stitch.held_bytes(),
            "whole_layers_bytes": Stitcher::bytes(&g, self.model.channels()),
        });
        // Pass 2: the map file, each level-0 tile from its block.
        let index = map_file::run_index(m, &g, self.truth.is_some(), range);
        src.index = &index;
        src.range = range;
        let bytes = serde_json::to_vec_pretty(&report)
            .map_err(|e| ReconstructError::Write(e.to_string()))?;
        let n = blocks.len();
        let map = map_file::write_into(
            map,
            index.clone(),
            &src,
            &bytes,
            &map_file::thumbnails(b),
            &mut |d, total| progress(n + d * n / total.max(1), 2 * n),
        )
        .map_err(ReconstructError::Write)?;
        self.eval_ms = t.elapsed().as_secs_f64() * 1e3;
        report["timings"]["eval_ms"] = self.eval_ms.into();
        Ok(StreamedMap {
            map,
            report,
            outcome,
            range,
        })
    }

    /// The map's raster files (`export::layers::names`, in that order in `sinks`)
    /// of a streamed map, block by block, after `finish_streamed` (whose `range`
    /// it takes); `progress(done, total)` counts blocks.
    pub fn write_layers<W: Write + Seek>(
        &self,
        b: &Bundle,
        range: (f32, f32),
        sinks: &mut [(String, W)],
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<(), String> {
        let road = road_channels(b);
        let m = &b.manifest;
        let index = map_file::run_index(m, &self.geometry, false, (0.0, 1.0));
        let src = BlockSource {
            stitch: &self.stitch,
            truth: self.truth.as_ref(),
            road: &road,
            min_alpha: self.cfg.train.loss.min_alpha,
            manifest: m,
            index: &index,
            range,
        };
        let mut files = LayerFiles::start(sinks, self.geometry, m, range, self.truth.is_some())?;
        let blocks = self.stitch.blocks();
        for (k, &(bx, by)) in blocks.iter().enumerate() {
            progress(k, blocks.len());
            if let Some((w, o)) = src.window(bx, by) {
                files.add(w.col, w.row, &o)?;
            }
        }
        files.finish()?;
        progress(blocks.len(), blocks.len());
        Ok(())
    }
}
