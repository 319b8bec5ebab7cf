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
//!
//! A block that no unfinished tile renders into is sealed (`seal_except`): its sums
//! are deflated, and it is inflated only to be read. Most of a block lies outside the
//! corridor (weight 0) and compresses to nothing, so along a drive the blend holds
//! the few open blocks around the tile being trained plus a few per cent of the rest,
//! instead of growing by a tile's window (76 bytes per pixel with 9 classes) with
//! every tile.

use super::Rect;
use crate::bev::{BevGeometry, BevImage};
use crate::reconstruct::Layers;
use std::borrow::Cow;
use std::collections::{BTreeMap, BTreeSet};
use std::io::{Read, Write};

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
#[derive(Clone)]
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

    /// The sums' fields in a fixed order (sealing writes and reads them so).
    fn fields(&self) -> [&Vec<f32>; 8] {
        [
            &self.weight,
            &self.rgb,
            &self.logits,
            &self.elevation,
            &self.alpha,
            &self.confidence,
            &self.density,
            &self.faint,
        ]
    }

    fn fields_mut(&mut self) -> [&mut Vec<f32>; 8] {
        [
            &mut self.weight,
            &mut self.rgb,
            &mut self.logits,
            &mut self.elevation,
            &mut self.alpha,
            &mut self.confidence,
            &mut self.density,
            &mut self.faint,
        ]
    }

    /// The sums deflated.
    fn seal(&self) -> Vec<u8> {
        let mut z = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::fast());
        for f in self.fields() {
            // Writing into a Vec cannot fail.
            let _ = z.write_all(bytemuck::cast_slice(f));
        }
        z.finish().unwrap_or_default()
    }

    /// A block of `n` pixels from `seal`'s bytes (written by this process, so a
    /// short read means a bug: its sums are left zero rather than panicking).
    fn unseal(bytes: &[u8], n: usize, channels: usize) -> Self {
        let mut b = Self::new(n, channels);
        let mut z = flate2::read::DeflateDecoder::new(bytes);
        for f in b.fields_mut() {
            let _ = z.read_exact(bytemuck::cast_slice_mut(f));
        }
        b
    }
}

/// A block being blended, or sealed: no tile left renders into it.
enum Held {
    Open(Block),
    Sealed(Vec<u8>),
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
    blocks: BTreeMap<(u32, u32), Held>,
    /// The most bytes the blocks have held at once.
    pub peak_held_bytes: u64,
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
            peak_held_bytes: 0,
        }
    }

    /// Host bytes the blocks hold now (open blocks' sums, sealed blocks' bytes).
    pub fn held_bytes(&self) -> u64 {
        self.blocks
            .iter()
            .map(|(&(bx, by), h)| match h {
                Held::Open(_) => {
                    let (bw, bh) = block_size(&self.geometry, bx, by);
                    bw as u64 * bh as u64 * block_px_bytes(self.channels)
                }
                Held::Sealed(z) => z.len() as u64,
            })
            .sum()
    }

    /// Blocks held open and sealed.
    pub fn counts(&self) -> (usize, usize) {
        let open = self
            .blocks
            .values()
            .filter(|h| matches!(h, Held::Open(_)))
            .count();
        (open, self.blocks.len() - open)
    }

    /// The blocks window `w` touches (a tile that is still to render there keeps
    /// them open).
    pub fn blocks_of(w: &Window) -> impl Iterator<Item = (u32, u32)> {
        blocks_of(w)
    }

    /// Seals every open block not in `open`: no tile will render into it again.
    pub fn seal_except(&mut self, open: &BTreeSet<(u32, u32)>) {
        for (k, h) in self.blocks.iter_mut() {
            if let Held::Open(b) = h {
                if !open.contains(k) {
                    *h = Held::Sealed(b.seal());
                }
            }
        }
    }

    /// Block (bx, by)'s sums, inflated if it is sealed.
    fn sums(&self, bx: u32, by: u32) -> Option<Cow<'_, Block>> {
        Some(match self.blocks.get(&(bx, by))? {
            Held::Open(b) => Cow::Borrowed(b),
            Held::Sealed(z) => {
                let (bw, bh) = block_size(&self.geometry, bx, by);
                Cow::Owned(Block::unseal(z, (bw * bh) as usize, self.channels))
            }
        })
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
            let held = self
                .blocks
                .entry((bx, by))
                .or_insert_with(|| Held::Open(Block::new((bw * bh) as usize, ch)));
            // A tile may render into a sealed block only if the caller's plan of who
            // renders where was wrong; it is reopened rather than lost.
            if let Held::Sealed(z) = held {
                *held = Held::Open(Block::unseal(z, (bw * bh) as usize, ch));
            }
            let Held::Open(b) = held else {
                continue;
            };
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

    /// Records the blocks' bytes now in `peak_held_bytes`.
    pub fn note_peak(&mut self) {
        self.peak_held_bytes = self.peak_held_bytes.max(self.held_bytes());
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
        let b = self.sums(bx, by)?.into_owned();
        let (bw, bh) = block_size(&self.geometry, bx, by);
        let ch = self.channels;
        let mut out = Layers {
            bev: BevImage {
                width: bw,
                height: bh,
                channels: ch,
                rgb: b.rgb,
                logits: b.logits,
                elevation: b.elevation,
                alpha: b.alpha,
            },
            confidence: b.confidence,
            density: b.density,
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
        for &(bx, by) in self.blocks.keys() {
            let Some(b) = self.sums(bx, by) else {
                continue;
            };
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Layers of `w`×`h` px whose values vary with the pixel and the tile (`seed`):
    /// a corridor along the diagonal, transparent outside it and faint in places.
    fn layers(w: u32, h: u32, ch: usize, seed: f32) -> Layers {
        let n = (w * h) as usize;
        let mut bev = BevImage::blank(w, h, ch);
        let mut confidence = vec![0.0; n];
        let mut density = vec![0.0; n];
        for i in 0..n {
            let v = (i as f32 * 0.37 + seed).sin();
            let (x, y) = ((i as u32 % w) as i64, (i as u32 / w) as i64);
            bev.alpha[i] = if (x - y).abs() > w as i64 / 6 {
                0.0
            } else if i % 7 == 0 {
                0.01
            } else {
                0.5 + 0.4 * v
            };
            bev.elevation[i] = 0.1 * v + seed;
            for c in 0..3 {
                bev.rgb[3 * i + c] = 0.5 + 0.3 * (v * (c + 1) as f32).cos();
            }
            for c in 0..ch {
                bev.logits[ch * i + c] = v * c as f32;
            }
            confidence[i] = v.abs();
            density[i] = 1.0 + v;
        }
        Layers {
            bev,
            confidence,
            density,
        }
    }

    #[test]
    fn sealing_blocks_changes_no_pixel_of_the_blend() {
        let g = BevGeometry {
            origin: [0.0, 80.0],
            resolution: 0.1,
            width: 800,
            height: 700,
        };
        let ch = 4;
        // Three tiles along a diagonal, overlapping by 2 m.
        let rects: Vec<Rect> = (0..3)
            .map(|k| {
                let x = 20.0 * k as f64;
                Rect {
                    min: [x, 80.0 - 24.0 - 20.0 * k as f64],
                    max: [x + 24.0, 80.0 - 20.0 * k as f64],
                }
            })
            .collect();
        let mut plain = Stitcher::new(g, ch, 0.05);
        let mut sealed = Stitcher::new(g, ch, 0.05);
        let windows: Vec<Window> = rects.iter().filter_map(|r| plain.window(r)).collect();
        assert_eq!(windows.len(), 3);
        for (k, (w, r)) in windows.iter().zip(&rects).enumerate() {
            let l = layers(w.geometry.width, w.geometry.height, ch, k as f32);
            plain.add(w, &l, Some((*r, 4.0)));
            sealed.add(w, &l, Some((*r, 4.0)));
            // What the tiles still to come render into stays open.
            let open: BTreeSet<_> = windows[k + 1..].iter().flat_map(blocks_of).collect();
            sealed.seal_except(&open);
            sealed.note_peak();
        }
        let (open, shut) = sealed.counts();
        assert_eq!(open, 0, "every tile finished");
        assert!(shut > 4, "{shut} blocks sealed");
        // Blocks half outside the corridor compress well below their sums' size.
        assert!(
            sealed.held_bytes() < plain.held_bytes() / 2,
            "sealed {} B, open {} B",
            sealed.held_bytes(),
            plain.held_bytes()
        );
        assert!(sealed.peak_held_bytes < plain.held_bytes());
        for (bx, by) in plain.blocks() {
            let (a, b) = (plain.block(bx, by), sealed.block(bx, by));
            let ((_, a), (_, b)) = (a.expect("plain block"), b.expect("sealed block"));
            let same = |x: &[f32], y: &[f32]| {
                x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits())
            };
            assert!(same(&a.bev.rgb, &b.bev.rgb), "rgb of block ({bx}, {by})");
            assert!(same(&a.bev.logits, &b.bev.logits));
            assert!(same(&a.bev.elevation, &b.bev.elevation));
            assert!(same(&a.bev.alpha, &b.bev.alpha));
            assert!(same(&a.confidence, &b.confidence));
            assert!(same(&a.density, &b.density));
        }
        assert_eq!(plain.preview(), sealed.preview());
        // A tile that renders into a sealed block after all reopens it: nothing is lost.
        let extra = layers(
            windows[0].geometry.width,
            windows[0].geometry.height,
            ch,
            9.0,
        );
        plain.add(&windows[0], &extra, None);
        sealed.add(&windows[0], &extra, None);
        let (a, b) = (plain.finish(), sealed.finish());
        assert!(a
            .bev
            .rgb
            .iter()
            .zip(&b.bev.rgb)
            .all(|(p, q)| p.to_bits() == q.to_bits()));
    }
}
