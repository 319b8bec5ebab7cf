//! GeoTIFF layers for GIS tools (QGIS, GDAL): `elevation.tif` (float32 metres, NaN
//! no-data where the map is empty), `rgb.tif` (RGBA, alpha 0 where empty) and
//! `semantic.tif` (class ids, 255 no-data), each exactly the map's size, with the
//! georeference as GeoTIFF tags: the upper-left corner of pixel (0, 0) tied to the
//! map's origin (west edge, north edge), square pixels of the map's resolution, and a
//! user-defined (local engineering) model, named in the citation, because a bundle's
//! world frame has no CRS.
//!
//! The files are *tiled* (`TILE`-pixel tiles, deflated, as cloud-optimised GeoTIFFs
//! are), not stripped: a tile is the map's own block (`map_file::TILE`), so a map is
//! written one block at a time in any order, and a tile no block covers points at
//! one shared empty tile. A map of any length is written holding one tile.

use crate::bev::BevGeometry;
use std::io::{Seek, SeekFrom, Write};

/// Side of a GeoTIFF tile, pixels: the map's block.
pub const TILE: u32 = crate::export::map_file::TILE;

/// Class id written where the map is empty.
pub const SEMANTIC_NODATA: u8 = 255;

/// The sample layouts the map's GeoTIFFs use.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// One float32 sample (elevation), NaN no-data.
    Float32,
    /// RGB with unassociated alpha, 8 bits each.
    Rgba8,
    /// One byte (class ids), `SEMANTIC_NODATA` no-data.
    Gray8,
}

impl Kind {
    /// Bytes per pixel.
    pub fn bytes(self) -> usize {
        match self {
            Kind::Float32 | Kind::Rgba8 => 4,
            Kind::Gray8 => 1,
        }
    }

    fn samples(self) -> u16 {
        if self == Kind::Rgba8 {
            4
        } else {
            1
        }
    }
}

/// TIFF field types.
const SHORT: u16 = 3;
const LONG: u16 = 4;
const ASCII: u16 = 2;
const DOUBLE: u16 = 12;

/// One IFD entry: tag, type, count and the value's little-endian bytes.
struct Entry(u16, u16, u32, Vec<u8>);

/// An entry of `ty` holding `v`'s values, each as its little-endian bytes.
fn entry<const N: usize>(tag: u16, ty: u16, v: impl ExactSizeIterator<Item = [u8; N]>) -> Entry {
    let count = v.len() as u32;
    Entry(tag, ty, count, v.flatten().collect())
}

fn shorts(tag: u16, v: &[u16]) -> Entry {
    entry(tag, SHORT, v.iter().map(|x| x.to_le_bytes()))
}

fn longs(tag: u16, v: &[u32]) -> Entry {
    entry(tag, LONG, v.iter().map(|x| x.to_le_bytes()))
}

fn doubles(tag: u16, v: &[f64]) -> Entry {
    entry(tag, DOUBLE, v.iter().map(|x| x.to_le_bytes()))
}

fn ascii(tag: u16, s: &str) -> Entry {
    let mut b = s.as_bytes().to_vec();
    b.push(0);
    Entry(tag, ASCII, b.len() as u32, b)
}

/// A tiled, deflated, georeferenced GeoTIFF written tile by tile into `w`.
pub struct TifWriter<'a, W: Write + Seek> {
    name: String,
    w: &'a mut W,
    kind: Kind,
    /// The map's geometry, its origin in the dataset's frame.
    g: BevGeometry,
    frame: String,
    tiles_x: u32,
    /// Each tile's (offset, byte count); (0, 0) until written.
    tiles: Vec<(u32, u32)>,
    /// Where the file's bytes end.
    end: u64,
}

impl<'a, W: Write + Seek> TifWriter<'a, W> {
    /// Starts `name` (for errors) in `w` (at its start) for a map of geometry `g`
    /// (origin in the dataset's frame named `frame`).
    pub fn start(
        name: &str,
        w: &'a mut W,
        kind: Kind,
        g: BevGeometry,
        frame: &str,
    ) -> Result<Self, String> {
        // Little-endian TIFF; the first IFD's offset is written at the finish.
        w.write_all(b"II*\0\0\0\0\0")
            .map_err(|e| format!("{name}: {e}"))?;
        let (tiles_x, tiles_y) = (g.width.div_ceil(TILE), g.height.div_ceil(TILE));
        Ok(Self {
            name: name.into(),
            w,
            kind,
            g,
            frame: frame.into(),
            tiles_x,
            tiles: vec![(0, 0); (tiles_x * tiles_y) as usize],
            end: 8,
        })
    }

    fn err(&self, e: impl std::fmt::Display) -> String {
        format!("{}: {e}", self.name)
    }

    /// Appends `bytes` at the end (on a word boundary); their offset.
    fn append(&mut self, bytes: &[u8]) -> Result<u32, String> {
        if self.end % 2 == 1 {
            self.w.write_all(&[0]).map_err(|e| self.err(e))?;
            self.end += 1;
        }
        let at = u32::try_from(self.end).map_err(|_| {
            self.err(
                "over 4 GiB, more than a TIFF holds: use map.rogsmap, or a coarser --resolution",
            )
        })?;
        self.w.write_all(bytes).map_err(|e| self.err(e))?;
        self.end += bytes.len() as u64;
        Ok(at)
    }

    /// Writes tile (tx, ty) from `px`: `width` × `height` pixels of `kind.bytes()`
    /// each, row-major, the tile's top-left part (the map's edge tiles are smaller);
    /// the rest of the tile is padding.
    pub fn tile(
        &mut self,
        tx: u32,
        ty: u32,
        px: &[u8],
        width: u32,
        height: u32,
    ) -> Result<(), String> {
        let bpp = self.kind.bytes();
        if width > TILE || height > TILE || px.len() != (width * height) as usize * bpp {
            return Err(self.err(format!(
                "tile ({tx}, {ty}) of {width}×{height} px in {} bytes",
                px.len()
            )));
        }
        let row = TILE as usize * bpp;
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        let mut pad = vec![0u8; row];
        for y in 0..TILE as usize {
            let src = if y < height as usize {
                let r = &px[y * width as usize * bpp..(y + 1) * width as usize * bpp];
                pad[..r.len()].copy_from_slice(r);
                &pad[..]
            } else {
                pad.fill(0);
                &pad[..]
            };
            z.write_all(src).map_err(|e| self.err(e))?;
        }
        let bytes = z.finish().map_err(|e| self.err(e))?;
        let at = self.append(&bytes)?;
        let i = (ty * self.tiles_x + tx) as usize;
        match self.tiles.get_mut(i) {
            Some(t) => *t = (at, bytes.len() as u32),
            None => return Err(self.err(format!("tile ({tx}, {ty}) is outside the map"))),
        }
        Ok(())
    }

    /// Writes the empty tile for the tiles no block covered, then the directory.
    pub fn finish(mut self) -> Result<(), String> {
        if self.tiles.iter().any(|t| t.1 == 0) {
            // No data: NaN elevation, transparent colour, no-data class.
            let empty: Vec<u8> = match self.kind {
                Kind::Float32 => f32::NAN.to_le_bytes().repeat((TILE * TILE) as usize),
                Kind::Rgba8 => vec![0; (TILE * TILE * 4) as usize],
                Kind::Gray8 => vec![SEMANTIC_NODATA; (TILE * TILE) as usize],
            };
            let (w, h) = (TILE, TILE);
            let i = self.tiles.iter().position(|t| t.1 == 0).unwrap_or(0) as u32;
            self.tile(i % self.tiles_x, i / self.tiles_x, &empty, w, h)?;
            let e = self.tiles[i as usize];
            for t in self.tiles.iter_mut().filter(|t| t.1 == 0) {
                *t = e;
            }
        }
        let entries = self.entries();
        // The directory: entries sorted by tag, values over 4 bytes after it.
        let n = entries.len();
        if self.end % 2 == 1 {
            self.append(&[])?;
        }
        let ifd = self.end;
        let mut values = ifd + 2 + 12 * n as u64 + 4;
        let mut dir = Vec::with_capacity(2 + 12 * n + 4);
        let mut extra = Vec::new();
        dir.extend_from_slice(&(n as u16).to_le_bytes());
        for Entry(tag, ty, count, v) in &entries {
            dir.extend_from_slice(&tag.to_le_bytes());
            dir.extend_from_slice(&ty.to_le_bytes());
            dir.extend_from_slice(&count.to_le_bytes());
            if v.len() <= 4 {
                let mut inline = [0u8; 4];
                inline[..v.len()].copy_from_slice(v);
                dir.extend_from_slice(&inline);
            } else {
                let at = u32::try_from(values).map_err(|_| self.err("over 4 GiB"))?;
                dir.extend_from_slice(&at.to_le_bytes());
                extra.extend_from_slice(v);
                values += v.len() as u64;
                if values % 2 == 1 {
                    extra.push(0);
                    values += 1;
                }
            }
        }
        dir.extend_from_slice(&0u32.to_le_bytes());
        dir.extend_from_slice(&extra);
        let at = self.append(&dir)?;
        self.w
            .seek(SeekFrom::Start(4))
            .and_then(|_| self.w.write_all(&at.to_le_bytes()))
            .and_then(|_| self.w.seek(SeekFrom::Start(self.end)))
            .map_err(|e| self.err(e))?;
        self.w.flush().map_err(|e| self.err(e))
    }

    /// The image's tags, sorted: layout, tiles, and the georeference (GeoTIFF 1.1).
    fn entries(&self) -> Vec<Entry> {
        let (g, k) = (&self.g, self.kind);
        let spp = k.samples() as usize;
        let bits = if k == Kind::Float32 { 32 } else { 8 };
        let citation = format!("rogs local frame: {}|", self.frame);
        let mut e = vec![
            longs(256, &[g.width]),
            longs(257, &[g.height]),
            shorts(258, &vec![bits; spp]),
            // Deflate (zlib).
            shorts(259, &[8]),
            // BlackIsZero, or RGB.
            shorts(262, &[if k == Kind::Rgba8 { 2 } else { 1 }]),
            shorts(277, &[k.samples()]),
            // Chunky.
            shorts(284, &[1]),
            longs(322, &[TILE]),
            longs(323, &[TILE]),
            longs(324, &self.tiles.iter().map(|t| t.0).collect::<Vec<_>>()),
            longs(325, &self.tiles.iter().map(|t| t.1).collect::<Vec<_>>()),
        ];
        if k == Kind::Rgba8 {
            // ExtraSamples: the fourth is unassociated alpha.
            e.push(shorts(338, &[2]));
        }
        // SampleFormat: IEEE float, or unsigned.
        e.push(shorts(339, &vec![if bits == 32 { 3 } else { 1 }; spp]));
        // ModelPixelScale, ModelTiepoint.
        e.push(doubles(33550, &[g.resolution, g.resolution, 0.0]));
        e.push(doubles(
            33922,
            &[0.0, 0.0, 0.0, g.origin[0], g.origin[1], 0.0],
        ));
        // GeoKeyDirectory, version 1.1.0, 3 keys: GTModelType user-defined,
        // GTRasterType PixelIsArea, GTCitation (from the ASCII parameters).
        e.push(shorts(
            34735,
            &[
                1,
                1,
                0,
                3,
                1024,
                0,
                1,
                32767,
                1025,
                0,
                1,
                1,
                1026,
                34737,
                citation.len() as u16,
                0,
            ],
        ));
        e.push(ascii(34737, &citation));
        // GDAL's no-data value, as text.
        match k {
            Kind::Float32 => e.push(ascii(42113, "nan")),
            Kind::Gray8 => e.push(ascii(42113, &SEMANTIC_NODATA.to_string())),
            Kind::Rgba8 => {}
        }
        e
    }
}
