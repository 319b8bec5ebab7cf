//! Stitching: each finished tile renders its layers over its rect; the map blends
//! them with weights that fall linearly to zero over the last `2·overlap_m` of each
//! rect's edges, so that at every pixel of an overlap two (or four) tiles' weights
//! sum to one and the colour, classes and elevation pass from one tile to the next
//! without a step.
//!
//! The blend is held in blocks of `BLOCK` pixels, aligned with the map file's tiles
//! and allocated where a tile renders, so the host holds the area the drive covers,
//! not its bounding box (a drive that curves or turns round covers a few per cent of
//! its box). A finished block reads out as the layers of its own small window
//! (`block`), which is how a map too large for whole-image layers is written
//! (`TiledRun::finish_streamed`); `finish` assembles them whole.

use super::Rect;
use crate::bev::{BevGeometry, BevImage};
use crate::reconstruct::Layers;
use std::collections::BTreeMap;

/// Side of a block, pixels: the map file's tile (`map_file::TILE`).
pub const BLOCK: u32 = crate::export::map_file::TILE;

/// A tile's window of the map raster: its top-left pixel and its geometry.
#[derive(Clone, Copy, Debug)]
pub struct Window {
    pub col: u32,
    pub row: u32,
    pub geometry: BevGeometry,
}

/// The weighted sums of one block.
struct Block {
    weight: Vec<f32>,
    rgb: Vec<f32>,
    logits: Vec<f32>,
    elevation: Vec<f32>,
    alpha: Vec<f32>,
    confidence: Vec<f32>,
    density: Vec<f32>,
    /// Largest alpha below the floor where no tile was valid.
    faint: Vec<f32>,
}

impl Block {
    fn new(n: usize, channels: usize) -> Self {
        Self {
            weight: vec![0.0; n],
            rgb: vec![0.0; 3 * n],
            logits: vec![0.0; channels * n],
            elevation: vec![0.0; n],
            alpha: vec![0.0; n],
            confidence: vec![0.0; n],
            density: vec![0.0; n],
            faint: vec![0.0; n],
        }
    }
}

/// Host bytes per pixel of a block: weight, RGB, logits, elevation, alpha,
/// confidence, density, faint alpha.
fn block_px_bytes(channels: usize) -> u64 {
    (10 + channels as u64) * 4
}

/// Blends tiles' layers into the map's.
pub struct Stitcher {
    pub geometry: BevGeometry,
    channels: usize,
    min_alpha: f32,
    blocks: BTreeMap<(u32, u32), Block>,
}

impl Stitcher {
    /// Host bytes of the map's whole layers (the blend and the layers it gives,
    /// `finish`), for a map of geometry `g`.
    pub fn bytes(g: &BevGeometry, channels: usize) -> u64 {
        g.width as u64 * g.height as u64 * (11 + channels as u64) * 4
    }

    /// Host bytes of the blocks that windows `w` cover (what the blend holds when
    /// every tile has rendered).
    pub fn block_bytes<'a>(
        g: &BevGeometry,
        channels: usize,
        windows: impl Iterator<Item = &'a Window>,
    ) -> u64 {
        let mut seen = std::collections::BTreeSet::new();
        for w in windows {
            seen.extend(blocks_of(w));
        }
        seen.iter()
            .map(|&(bx, by)| {
                let (bw, bh) = block_size(g, bx, by);
                bw as u64 * bh as u64 * block_px_bytes(channels)
            })
            .sum()
    }

    pub fn new(geometry: BevGeometry, channels: usize, min_alpha: f32) -> Self {
        Self {
            geometry,
            channels,
            min_alpha,
            blocks: BTreeMap::new(),
        }
    }

    /// Host bytes the blocks hold now.
    pub fn held_bytes(&self) -> u64 {
        self.blocks
            .keys()
            .map(|&(bx, by)| {
                let (bw, bh) = block_size(&self.geometry, bx, by);
                bw as u64 * bh as u64 * block_px_bytes(self.channels)
            })
            .sum()
    }

    /// The window of the map's raster that covers `r` (`None` when they are apart).
    pub fn window(&self, r: &Rect) -> Option<Window> {
        let g = &self.geometry;
        let res = g.resolution;
        let c0 = ((r.min[0] - g.origin[0]) / res).floor().max(0.0) as u32;
        let c1 = (((r.max[0] - g.origin[0]) / res).ceil().max(0.0) as u32).min(g.width);
        let r0 = ((g.origin[1] - r.max[1]) / res).floor().max(0.0) as u32;
        let r1 = (((g.origin[1] - r.min[1]) / res).ceil().max(0.0) as u32).min(g.height);
        (c1 > c0 && r1 > r0).then(|| window_at(g, c0, r0, c1 - c0, r1 - r0))
    }

    /// Adds a tile's layers over `w`. `blend`: the tile's rect and the width over
    /// which its weight falls to zero at the rect's edges (`None`: weight 1).
    pub fn add(&mut self, w: &Window, l: &Layers, blend: Option<(Rect, f64)>) {
        let g = self.geometry;
        let ch = self.channels;
        let (tw, th) = (w.geometry.width, w.geometry.height);
        for (bx, by) in blocks_of(w) {
            let (bw, bh) = block_size(&g, bx, by);
            let b = self
                .blocks
                .entry((bx, by))
                .or_insert_with(|| Block::new((bw * bh) as usize, ch));
            let (x0, y0) = (bx * BLOCK, by * BLOCK);
            for gy in y0.max(w.row)..(y0 + bh).min(w.row + th) {
                for gx in x0.max(w.col)..(x0 + bw).min(w.col + tw) {
                    let li = ((gy - w.row) * tw + gx - w.col) as usize;
                    let bi = ((gy - y0) * bw + gx - x0) as usize;
                    let a = l.bev.alpha[li];
                    if a.is_nan() || a < self.min_alpha {
                        b.faint[bi] = b.faint[bi].max(if a.is_finite() { a } else { 0.0 });
                        continue;
                    }
                    let wt = match blend {
                        Some((r, width)) if width > 0.0 => {
                            let px = g.origin[0] + (gx as f64 + 0.5) * g.resolution;
                            let py = g.origin[1] - (gy as f64 + 0.5) * g.resolution;
                            let dx = (px - r.min[0]).min(r.max[0] - px);
                            let dy = (py - r.min[1]).min(r.max[1] - py);
                            ((dx / width).clamp(1e-3, 1.0) * (dy / width).clamp(1e-3, 1.0)) as f32
                        }
                        _ => 1.0,
                    };
                    b.weight[bi] += wt;
                    for c in 0..3 {
                        b.rgb[3 * bi + c] += wt * l.bev.rgb[3 * li + c];
                    }
                    for c in 0..ch {
                        b.logits[ch * bi + c] += wt * l.bev.logits[ch * li + c];
                    }
                    b.elevation[bi] += wt * l.bev.elevation[li];
                    b.alpha[bi] += wt * a;
                    b.confidence[bi] += wt * l.confidence[li];
                    b.density[bi] += wt * l.density[li];
                }
            }
        }
    }

    /// The blocks held, (column, row) of `BLOCK`-pixel blocks, in row-major order.
    pub fn blocks(&self) -> Vec<(u32, u32)> {
        let mut k: Vec<_> = self.blocks.keys().copied().collect();
        k.sort_by_key(|&(bx, by)| (by, bx));
        k
    }

    /// The blended layers of block (bx, by) over its window (`None` when no tile
    /// rendered there): NaN confidence, density and elevation where no tile was valid.
    pub fn block(&self, bx: u32, by: u32) -> Option<(Window, Layers)> {
        let b = self.blocks.get(&(bx, by))?;
        let (bw, bh) = block_size(&self.geometry, bx, by);
        let ch = self.channels;
        let mut out = Layers {
            bev: BevImage {
                width: bw,
                height: bh,
                channels: ch,
                rgb: b.rgb.clone(),
                logits: b.logits.clone(),
                elevation: b.elevation.clone(),
                alpha: b.alpha.clone(),
            },
            confidence: b.confidence.clone(),
            density: b.density.clone(),
        };
        for i in 0..(bw * bh) as usize {
            let w = b.weight[i];
            if w > 0.0 {
                for c in 0..3 {
                    out.bev.rgb[3 * i + c] /= w;
                }
                for c in 0..ch {
                    out.bev.logits[ch * i + c] /= w;
                }
                out.bev.elevation[i] /= w;
                out.bev.alpha[i] /= w;
                out.confidence[i] /= w;
                out.density[i] /= w;
            } else {
                out.bev.alpha[i] = b.faint[i];
                out.bev.elevation[i] = f32::NAN;
                out.confidence[i] = f32::NAN;
                out.density[i] = f32::NAN;
            }
        }
        let w = window_at(&self.geometry, bx * BLOCK, by * BLOCK, bw, bh);
        Some((w, out))
    }

    /// The blended layers of the whole map (NaN confidence, density and elevation
    /// where no tile rendered anything).
    pub fn finish(mut self) -> Layers {
        let g = self.geometry;
        let n = (g.width * g.height) as usize;
        let ch = self.channels;
        let mut out = Layers {
            bev: BevImage::blank(g.width, g.height, ch),
            confidence: vec![f32::NAN; n],
            density: vec![f32::NAN; n],
        };
        for (bx, by) in self.blocks() {
            let Some((w, l)) = self.block(bx, by) else {
                continue;
            };
            // Each block's sums go as its layers are copied: the later layers of
            // the map (its images) reuse that memory.
            self.blocks.remove(&(bx, by));
            let bw = w.geometry.width as usize;
            for y in 0..w.geometry.height as usize {
                let (li, gi) = (
                    y * bw,
                    (w.row as usize + y) * g.width as usize + w.col as usize,
                );
                let o = &mut out;
                o.bev.rgb[3 * gi..3 * (gi + bw)].copy_from_slice(&l.bev.rgb[3 * li..3 * (li + bw)]);
                o.bev.logits[ch * gi..ch * (gi + bw)]
                    .copy_from_slice(&l.bev.logits[ch * li..ch * (li + bw)]);
                o.bev.elevation[gi..gi + bw].copy_from_slice(&l.bev.elevation[li..li + bw]);
                o.bev.alpha[gi..gi + bw].copy_from_slice(&l.bev.alpha[li..li + bw]);
                o.confidence[gi..gi + bw].copy_from_slice(&l.confidence[li..li + bw]);
                o.density[gi..gi + bw].copy_from_slice(&l.density[li..li + bw]);
            }
        }
        out
    }

    /// The blend's colour as RGBA over the whole map (transparent where no tile
    /// rendered), for previews while training.
    pub fn preview(&self) -> Vec<u8> {
        let g = self.geometry;
        let mut out = vec![0u8; (g.width * g.height * 4) as usize];
        for (&(bx, by), b) in &self.blocks {
            let (bw, bh) = block_size(&g, bx, by);
            for y in 0..bh {
                for x in 0..bw {
                    let bi = (y * bw + x) as usize;
                    let wt = b.weight[bi];
                    if wt <= 0.0 {
                        continue;
                    }
                    let gi = ((by * BLOCK + y) * g.width + bx * BLOCK + x) as usize;
                    let c =
                        |k: usize| ((b.rgb[3 * bi + k] / wt).clamp(0.0, 1.0) * 255.0).round() as u8;
                    out[4 * gi..4 * gi + 4].copy_from_slice(&[c(0), c(1), c(2), 255]);
                }
            }
        }
        out
    }
}

/// The window of `g` at pixel (c0, r0), w × h pixels.
fn window_at(g: &BevGeometry, c0: u32, r0: u32, w: u32, h: u32) -> Window {
    Window {
        col: c0,
        row: r0,
        geometry: BevGeometry {
            origin: [
                g.origin[0] + c0 as f64 * g.resolution,
                g.origin[1] - r0 as f64 * g.resolution,
            ],
            resolution: g.resolution,
            width: w,
            height: h,
        },
    }
}

/// Pixel size of block (bx, by) of a map of geometry `g` (the last column and row
/// of blocks may be smaller).
fn block_size(g: &BevGeometry, bx: u32, by: u32) -> (u32, u32) {
    (
        (g.width - bx * BLOCK).min(BLOCK),
        (g.height - by * BLOCK).min(BLOCK),
    )
}

/// The blocks a window touches.
fn blocks_of(w: &Window) -> impl Iterator<Item = (u32, u32)> {
    let (bx0, by0) = (w.col / BLOCK, w.row / BLOCK);
    let bx1 = (w.col + w.geometry.width).div_ceil(BLOCK);
    let by1 = (w.row + w.geometry.height).div_ceil(BLOCK);
    (by0..by1).flat_map(move |by| (bx0..bx1).map(move |bx| (bx, by)))
}
