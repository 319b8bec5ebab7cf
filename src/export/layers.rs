//! The map's raster files written a piece at a time: PNG layers, the elevation as
//! `.npy` and `.f32`, and the tiled GeoTIFFs, from rectangles of the map handed over
//! in row-major order of the map's `BLOCK`-pixel blocks (a whole map is one
//! rectangle; a streamed map hands each block of its blend, `TiledRun::write_layers`).
//!
//! Each rectangle's pixels are computed once per layer and written to every file that
//! shows that layer. The GeoTIFFs are tiled on the blocks, so each tile is written
//! as its block comes and the files hold nothing back. PNG and the arrays are
//! row-major: a row of blocks is held until the next row of blocks starts (rows no
//! block covers are written empty), so they hold one row of blocks of the map's
//! width, never the map. Maps over `DENSE_MAX_PX` pixels (a drive whose bounding
//! box is mostly empty) get only the GeoTIFFs and map.rogsmap: a dense image that
//! size would be mostly padding.

use super::colour::mapped;
use super::geotiff::{self, Kind, TifWriter, TILE};
use super::{elevation, elevation_error, grey, layer_rgba_in, semantic_colours};
use crate::bev::BevGeometry;
use crate::bundle::Manifest;
use crate::reconstruct::Outcome;
use std::cell::RefCell;
use std::io::{Seek, Write};
use std::rc::Rc;

/// The most pixels a map may have for its dense raster files (PNG, `.npy`, `.f32`):
/// 2²⁸ (1 GiB of float32 elevation).
pub const DENSE_MAX_PX: u64 = 1 << 28;

/// A layer's pixels over a rectangle, computed once for every file that shows it.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Source {
    Rgb,
    Valid,
    Semantic,
    Ids,
    ElevationColour,
    /// World z, float32 little endian, NaN where empty.
    Elevation,
    Confidence,
    Density,
    Error,
    /// RGB with alpha 0 where empty.
    Rgba,
    /// Class ids, `SEMANTIC_NODATA` where empty.
    IdsNoData,
    /// Elevation in the dataset's frame (the frame's z offset added).
    ElevationFrame,
}

impl Source {
    fn bytes(self) -> usize {
        match self {
            Source::Valid | Source::Ids | Source::Confidence | Source::Density => 1,
            Source::IdsNoData => 1,
            Source::Rgb | Source::Semantic | Source::ElevationColour | Source::Error => 3,
            Source::Elevation | Source::ElevationFrame | Source::Rgba => 4,
        }
    }

    /// One empty pixel: what a map shows where no tile rendered.
    fn empty(self) -> Vec<u8> {
        match self {
            Source::Elevation | Source::ElevationFrame => f32::NAN.to_le_bytes().to_vec(),
            Source::IdsNoData => vec![geotiff::SEMANTIC_NODATA],
            s => vec![0; s.bytes()],
        }
    }
}

/// How a file is written.
#[derive(Clone, Copy, Debug)]
enum Format {
    Png(png::ColorType),
    Npy,
    F32,
    Tif(Kind),
}

/// Every raster file of a map: name, layer, format.
fn specs(m: &Manifest, truth: bool, dense: bool) -> Vec<(&'static str, Source, Format)> {
    use png::ColorType::{Grayscale, Rgb};
    let labelled = m.labelled();
    let all = [
        ("rgb.png", Source::Rgb, Format::Png(Rgb), true),
        ("valid.png", Source::Valid, Format::Png(Grayscale), true),
        ("semantic.png", Source::Semantic, Format::Png(Rgb), labelled),
        (
            "semantic_ids.png",
            Source::Ids,
            Format::Png(Grayscale),
            labelled,
        ),
        (
            "elevation.png",
            Source::ElevationColour,
            Format::Png(Rgb),
            true,
        ),
        ("elevation.npy", Source::Elevation, Format::Npy, true),
        ("elevation.f32", Source::Elevation, Format::F32, true),
        (
            "confidence.png",
            Source::Confidence,
            Format::Png(Grayscale),
            true,
        ),
        ("density.png", Source::Density, Format::Png(Grayscale), true),
        ("error.png", Source::Error, Format::Png(Rgb), truth),
        (
            "elevation.tif",
            Source::ElevationFrame,
            Format::Tif(Kind::Float32),
            true,
        ),
        ("rgb.tif", Source::Rgba, Format::Tif(Kind::Rgba8), true),
        (
            "semantic.tif",
            Source::IdsNoData,
            Format::Tif(Kind::Gray8),
            labelled,
        ),
    ];
    all.into_iter()
        .filter(|(_, _, f, on)| *on && (dense || matches!(f, Format::Tif(_))))
        .map(|(n, s, f, _)| (n, s, f))
        .collect()
}

/// Whether a map of geometry `g` gets dense raster files.
pub fn dense(g: &BevGeometry) -> bool {
    g.width as u64 * g.height as u64 <= DENSE_MAX_PX
}

/// The names of the raster files of a map of geometry `g` (`truth`: the map is
/// scored, so it has an error layer), in the order `LayerFiles::start` expects.
pub fn names(g: &BevGeometry, m: &Manifest, truth: bool) -> Vec<&'static str> {
    specs(m, truth, dense(g)).into_iter().map(|s| s.0).collect()
}

/// The bytes an encoder writes, moved on to the file by the encoder's owner (png's
/// stream writer keeps the writer it is given for good).
#[derive(Clone, Default)]
struct Spool(Rc<RefCell<Vec<u8>>>);

impl Write for Spool {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.borrow_mut().extend_from_slice(b);
        Ok(b.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Spool {
    /// Moves the bytes spooled so far into `w`.
    fn drain_into(&self, w: &mut impl Write) -> std::io::Result<()> {
        let mut b = self.0.borrow_mut();
        w.write_all(&b)?;
        b.clear();
        Ok(())
    }
}

/// A dense file's writer.
enum Dense<'a, W: Write> {
    Png(Box<png::StreamWriter<'static, Spool>>, Spool, &'a mut W),
    Raw(&'a mut W),
}

/// A rectangle of the map whose rows are not all written to the dense files yet.
struct Pending {
    col: u32,
    row: u32,
    width: u32,
    height: u32,
    /// The dense files' layers, in `sources` order.
    px: Vec<Vec<u8>>,
}

/// The map's raster files, written as rectangles of it come (see the module's
/// header).
pub struct LayerFiles<'a, W: Write + Seek> {
    g: BevGeometry,
    manifest: &'a Manifest,
    /// The elevation's colours span this (the whole map's).
    range: (f32, f32),
    /// The dataset frame's z offset.
    z_offset: f32,
    /// The layers the dense files show, each once.
    sources: Vec<Source>,
    /// Dense files: name, index into `sources`, writer.
    dense: Vec<(&'static str, usize, Dense<'a, W>)>,
    tifs: Vec<(Source, TifWriter<'a, W>)>,
    pending: Vec<Pending>,
    /// Rows written to the dense files.
    written: u32,
}

impl<'a, W: Write + Seek> LayerFiles<'a, W> {
    /// Starts the files into `sinks`, named as `names` gives them, for a map of
    /// geometry `g` (bundle world) whose elevation spans `range`.
    pub fn start(
        sinks: &'a mut [(String, W)],
        g: BevGeometry,
        m: &'a Manifest,
        range: (f32, f32),
        truth: bool,
    ) -> Result<Self, String> {
        let specs = specs(m, truth, dense(&g));
        // The GeoTIFFs' tie point in the dataset's frame, so that they line up with
        // its maps.
        let off = m.frame_offset();
        let tif_g = BevGeometry {
            origin: [g.origin[0] + off[0], g.origin[1] + off[1]],
            ..g
        };
        let frame = m.frame_description();
        let mut out = Self {
            g,
            manifest: m,
            range,
            z_offset: off[2] as f32,
            sources: Vec::new(),
            dense: Vec::new(),
            tifs: Vec::new(),
            pending: Vec::new(),
            written: 0,
        };
        for (name, w) in sinks.iter_mut() {
            let Some(&(n, s, f)) = specs.iter().find(|s| s.0 == name.as_str()) else {
                return Err(format!("{name} is not one of the map's raster files"));
            };
            let err = |e: &dyn std::fmt::Display| format!("{n}: {e}");
            let d = match f {
                Format::Tif(k) => {
                    out.tifs
                        .push((s, TifWriter::start(n, w, k, tif_g, &frame)?));
                    continue;
                }
                Format::Png(c) => {
                    let spool = Spool::default();
                    let mut e = png::Encoder::new(spool.clone(), g.width, g.height);
                    e.set_color(c);
                    e.set_depth(png::BitDepth::Eight);
                    let s = e
                        .write_header()
                        .and_then(|h| h.into_stream_writer())
                        .map_err(|e| err(&e))?;
                    Dense::Png(Box::new(s), spool, w)
                }
                Format::Npy => {
                    w.write_all(&super::npy_header(g.width, g.height))
                        .map_err(|e| err(&e))?;
                    Dense::Raw(w)
                }
                Format::F32 => Dense::Raw(w),
            };
            let k = match out.sources.iter().position(|&x| x == s) {
                Some(k) => k,
                None => {
                    out.sources.push(s);
                    out.sources.len() - 1
                }
            };
            out.dense.push((n, k, d));
        }
        Ok(out)
    }

    /// The pixels of layer `s` of `o` (a rectangle of the map).
    fn pixels(&self, s: Source, o: &Outcome) -> Vec<u8> {
        let (w, h) = (o.geometry.width, o.geometry.height);
        let r = &o.raster;
        let f32s = |v: Vec<f32>| -> Vec<u8> { v.into_iter().flat_map(f32::to_le_bytes).collect() };
        match s {
            Source::Rgb => r.rgb.as_raw().clone(),
            Source::Valid => r.valid.as_raw().clone(),
            Source::Semantic => semantic_colours(self.manifest, &r.class_ids, &r.valid).into_raw(),
            Source::Ids => r.class_ids.as_raw().clone(),
            Source::ElevationColour => {
                mapped(&elevation(o), w, h, self.range.0, self.range.1).into_raw()
            }
            Source::Elevation => f32s(elevation(o)),
            Source::ElevationFrame => f32s(
                elevation(o)
                    .into_iter()
                    .map(|z| z + self.z_offset)
                    .collect(),
            ),
            Source::Confidence => grey(&o.confidence, w, h).into_raw(),
            Source::Density => grey(&o.density, w, h).into_raw(),
            Source::Error => elevation_error(o)
                .map(|e| mapped(&e, w, h, 0.0, 0.1).into_raw())
                .unwrap_or_else(|| vec![0; (w * h * 3) as usize]),
            Source::Rgba => layer_rgba_in(o, self.manifest, "rgb", self.range).unwrap_or_default(),
            Source::IdsNoData => r
                .class_ids
                .as_raw()
                .iter()
                .zip(r.valid.as_raw())
                .map(|(&c, &v)| if v != 0 { c } else { geotiff::SEMANTIC_NODATA })
                .collect(),
        }
    }

    /// Adds the rectangle `o` whose top-left pixel is (`col`, `row`) of the map: on
    /// the blocks' grid, after every rectangle of the rows of blocks above it and
    /// right of the others of its own.
    pub fn add(&mut self, col: u32, row: u32, o: &Outcome) -> Result<(), String> {
        let (w, h) = (o.geometry.width, o.geometry.height);
        if !col.is_multiple_of(TILE)
            || !row.is_multiple_of(TILE)
            || row < self.written
            || col + w > self.g.width
            || row + h > self.g.height
        {
            return Err(format!(
                "a {w}×{h} px part of the map at ({col}, {row}) is off the {TILE}-px blocks, \
                 outside the {}×{} px map, or above rows already written ({})",
                self.g.width, self.g.height, self.written
            ));
        }
        self.write_rows(row)?;
        for k in 0..self.tifs.len() {
            let s = self.tifs[k].0;
            let px = self.pixels(s, o);
            let b = s.bytes();
            for ty in 0..h.div_ceil(TILE) {
                for tx in 0..w.div_ceil(TILE) {
                    let (x0, y0) = (tx * TILE, ty * TILE);
                    let (tw, th) = ((w - x0).min(TILE), (h - y0).min(TILE));
                    let mut tile = Vec::with_capacity((tw * th) as usize * b);
                    for y in y0..y0 + th {
                        let i = (y * w + x0) as usize * b;
                        tile.extend_from_slice(&px[i..i + tw as usize * b]);
                    }
                    let (gx, gy) = ((col + x0) / TILE, (row + y0) / TILE);
                    self.tifs[k].1.tile(gx, gy, &tile, tw, th)?;
                }
            }
        }
        if !self.dense.is_empty() {
            let px = self.sources.iter().map(|&s| self.pixels(s, o)).collect();
            self.pending.push(Pending {
                col,
                row,
                width: w,
                height: h,
                px,
            });
        }
        Ok(())
    }

    /// Writes the dense files' rows up to `until` from the pending rectangles (empty
    /// where none covers a pixel), and drops the rectangles written in full.
    fn write_rows(&mut self, until: u32) -> Result<(), String> {
        if self.dense.is_empty() {
            self.written = until.max(self.written);
            return Ok(());
        }
        let width = self.g.width as usize;
        self.pending.sort_by_key(|p| (p.row, p.col));
        // Each layer's empty row, copied under every row before the rectangles.
        let empty: Vec<Vec<u8>> = self
            .sources
            .iter()
            .map(|s| s.empty().repeat(width))
            .collect();
        let mut rows = empty.clone();
        for y in self.written..until {
            for (k, s) in self.sources.iter().enumerate() {
                let b = s.bytes();
                let row = &mut rows[k];
                row.copy_from_slice(&empty[k]);
                for p in self
                    .pending
                    .iter()
                    .filter(|p| (p.row..p.row + p.height).contains(&y))
                {
                    let src = (y - p.row) as usize * p.width as usize * b;
                    let n = p.width as usize * b;
                    let dst = p.col as usize * b;
                    row[dst..dst + n].copy_from_slice(&p.px[k][src..src + n]);
                }
            }
            for (name, k, d) in &mut self.dense {
                let r = match d {
                    Dense::Png(s, ..) => s.write_all(&rows[*k]),
                    Dense::Raw(w) => w.write_all(&rows[*k]),
                };
                r.map_err(|e| format!("{name}: {e}"))?;
            }
        }
        for (name, _, d) in &mut self.dense {
            if let Dense::Png(_, spool, w) = d {
                spool.drain_into(w).map_err(|e| format!("{name}: {e}"))?;
            }
        }
        self.written = until.max(self.written);
        self.pending.retain(|p| p.row + p.height > until);
        Ok(())
    }

    /// Writes the rows left (empty below the last rectangle) and closes every file.
    pub fn finish(mut self) -> Result<(), String> {
        self.write_rows(self.g.height)?;
        for (name, _, d) in self.dense {
            match d {
                Dense::Png(s, spool, w) => {
                    s.finish().map_err(|e| format!("{name}: {e}"))?;
                    spool
                        .drain_into(w)
                        .and_then(|_| w.flush())
                        .map_err(|e| format!("{name}: {e}"))?;
                }
                Dense::Raw(w) => w.flush().map_err(|e| format!("{name}: {e}"))?,
            }
        }
        for (_, t) in self.tifs {
            t.finish()?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bev::BevImage;
    use crate::reconstruct::Layers;
    use std::io::Cursor;

    /// A `w`×`h` rectangle of map at `origin` whose every pixel is rendered at
    /// elevation `z`.
    fn part(origin: [f64; 2], w: u32, h: u32, z: f32) -> Outcome {
        let mut bev = BevImage::blank(w, h, 1);
        bev.alpha.fill(1.0);
        bev.elevation.fill(z);
        bev.rgb.fill(0.5);
        let n = (w * h) as usize;
        let layers = Layers {
            bev,
            confidence: vec![1.0; n],
            density: vec![0.5; n],
        };
        let g = BevGeometry {
            origin,
            resolution: 0.1,
            width: w,
            height: h,
        };
        Outcome::block(g, layers, None, &[(0, 1)], 0.5)
    }

    fn files(
        g: BevGeometry,
        parts: &[(u32, u32, &Outcome)],
    ) -> Result<Vec<(String, Vec<u8>)>, String> {
        let (m, _) = crate::bundle::example::tiny();
        let mut sinks: Vec<_> = names(&g, &m, false)
            .into_iter()
            .map(|n| (n.to_string(), Cursor::new(Vec::new())))
            .collect();
        let mut w = LayerFiles::start(&mut sinks, g, &m, (0.0, 4.0), false)?;
        for (c, r, o) in parts {
            w.add(*c, *r, o)?;
        }
        w.finish()?;
        Ok(sinks
            .into_iter()
            .map(|(n, c)| (n, c.into_inner()))
            .collect())
    }

    #[test]
    fn blocks_land_where_they_belong_and_the_rest_is_empty() {
        // 600 × 300 px: blocks (1, 0) and (0, 1) rendered, the rest never.
        let g = BevGeometry {
            origin: [0.0, 0.0],
            resolution: 0.1,
            width: 600,
            height: 300,
        };
        let a = part([25.6, 0.0], 256, 256, 2.0);
        let b = part([0.0, -25.6], 256, 44, 3.0);
        let out = files(g, &[(256, 0, &a), (0, 256, &b)]).expect("files");
        let get = |n: &str| &out.iter().find(|f| f.0 == n).expect(n).1;
        let z: Vec<f32> = get("elevation.f32")
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        assert_eq!(z.len(), 600 * 300);
        let at = |x: usize, y: usize| z[y * 600 + x];
        assert_eq!(
            (at(256, 0), at(511, 255), at(0, 256), at(255, 299)),
            (2.0, 2.0, 3.0, 3.0)
        );
        for (x, y) in [
            (0, 0),
            (255, 255),
            (512, 0),
            (599, 255),
            (256, 256),
            (599, 299),
        ] {
            assert!(at(x, y).is_nan(), "({x}, {y}) = {}", at(x, y));
        }
        let npy = get("elevation.npy");
        assert!(
            npy.ends_with(get("elevation.f32")),
            "the .npy holds the .f32's values"
        );
        let valid = image::load_from_memory(get("valid.png"))
            .expect("png")
            .to_luma8();
        assert_eq!((valid.width(), valid.height()), (600, 300));
        assert_eq!(valid.get_pixel(300, 10).0[0], 255);
        assert_eq!(valid.get_pixel(10, 10).0[0], 0);
        assert_eq!(valid.get_pixel(10, 290).0[0], 255);
        assert_eq!(valid.get_pixel(300, 290).0[0], 0);
        // The GeoTIFFs: one tile per block, then one shared empty tile and the
        // directory (GDAL reads them in the suites).
        let tif = get("elevation.tif");
        assert_eq!(&tif[..4], b"II*\0");
        // A part above rows already written, or off the blocks, is refused.
        let e = files(g, &[(0, 256, &b), (256, 0, &a)]).expect_err("out of order");
        assert!(e.contains("above rows already written"), "{e}");
        let e = files(g, &[(100, 0, &a)]).expect_err("off the blocks");
        assert!(e.contains("off the 256-px blocks"), "{e}");
    }
}
