//! The map file, `map.rogsmap` (docs/MAP.md): one zip holding every layer of a
//! finished map as an image pyramid of 256-pixel tiles (so a viewer reads the tiles
//! it shows, never a whole 70 000-pixel image), the elevation as float tiles, the
//! georeference, the class table, the trajectory and report.json.
//!
//! `write` makes one; `read_index` / `validate` check one completely (every tile
//! present, decoding at its size), naming the entry or field at fault.

use crate::bundle::{BundleErrors, Limits, Manifest, Problem, SemanticClass, Source, ZipSource};
use crate::reconstruct::Outcome;
use serde::{Deserialize, Serialize};

pub const FORMAT: &str = "rogs-map";
pub const VERSION: u32 = 1;
/// Side of a tile, pixels (the last row and column of tiles may be smaller).
pub const TILE: u32 = 256;
/// The index entry at the archive's root.
pub const INDEX: &str = "map.json";

/// `map.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapIndex {
    pub format: String,
    pub version: u32,
    pub name: String,
    /// Level 0's georeference: world x of the west edge, world y of the north edge,
    /// metres per pixel, size (row 0 north), as bev.json.
    pub origin: [f64; 2],
    pub resolution: f64,
    pub width: u32,
    pub height: u32,
    pub tile: u32,
    /// Level k has `ceil(width / 2^k) × ceil(height / 2^k)` pixels; the last level
    /// fits one tile.
    pub levels: u32,
    /// RGBA layers: `layers/{name}/{level}/{col}_{row}.png`.
    pub layers: Vec<String>,
    /// Float layers (little-endian f32, row-major, NaN where empty):
    /// `values/{name}/{level}/{col}_{row}.f32`.
    pub values: Vec<String>,
    pub classes: Vec<SemanticClass>,
    /// Vehicle positions (world x, y) of every frame.
    pub trajectory: Vec<[f64; 2]>,
    /// The run's report (an entry of the archive).
    pub report: String,
}

impl MapIndex {
    /// Pixel size of level `k`.
    pub fn level_size(&self, k: u32) -> (u32, u32) {
        let d = 1u32 << k.min(31);
        (self.width.div_ceil(d), self.height.div_ceil(d))
    }

    /// Tiles across and down at level `k`.
    pub fn tiles(&self, k: u32) -> (u32, u32) {
        let (w, h) = self.level_size(k);
        (w.div_ceil(self.tile), h.div_ceil(self.tile))
    }

    /// Pixel size of tile (c, r) of level `k`.
    pub fn tile_size(&self, k: u32, c: u32, r: u32) -> (u32, u32) {
        let (w, h) = self.level_size(k);
        (
            (w - c * self.tile).min(self.tile),
            (h - r * self.tile).min(self.tile),
        )
    }

    pub fn layer_path(name: &str, k: u32, c: u32, r: u32) -> String {
        format!("layers/{name}/{k}/{c}_{r}.png")
    }

    pub fn values_path(name: &str, k: u32, c: u32, r: u32) -> String {
        format!("values/{name}/{k}/{c}_{r}.f32")
    }
}

/// Levels for a map of w × h pixels: halve until the map fits one tile.
fn level_count(w: u32, h: u32) -> u32 {
    let mut k = 1;
    while w.max(h).div_ceil(1 << (k - 1)) > TILE {
        k += 1;
    }
    k
}

/// Halves an RGBA image: each pixel the mean of the non-transparent pixels of its
/// 2 × 2 block (transparent where none is).
fn half_rgba(px: &[u8], w: u32, h: u32) -> (Vec<u8>, u32, u32) {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0u8; (nw * nh * 4) as usize];
    for y in 0..nh {
        for x in 0..nw {
            let (mut s, mut n) = ([0u32; 4], 0u32);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (sx, sy) = (2 * x + dx, 2 * y + dy);
                if sx < w && sy < h {
                    let i = ((sy * w + sx) * 4) as usize;
                    if px[i + 3] > 0 {
                        for c in 0..4 {
                            s[c] += px[i + c] as u32;
                        }
                        n += 1;
                    }
                }
            }
            let o = ((y * nw + x) * 4) as usize;
            for c in 0..4 {
                if let Some(m) = (s[c] + n / 2).checked_div(n) {
                    out[o + c] = m as u8;
                }
            }
        }
    }
    (out, nw, nh)
}

/// Halves a float image: the mean of each 2 × 2 block's finite values.
fn half_f32(v: &[f32], w: u32, h: u32) -> (Vec<f32>, u32, u32) {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![f32::NAN; (nw * nh) as usize];
    for y in 0..nh {
        for x in 0..nw {
            let (mut s, mut n) = (0.0f64, 0u32);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (sx, sy) = (2 * x + dx, 2 * y + dy);
                if sx < w && sy < h {
                    let z = v[(sy * w + sx) as usize];
                    if z.is_finite() {
                        s += z as f64;
                        n += 1;
                    }
                }
            }
            if n > 0 {
                out[(y * nw + x) as usize] = (s / n as f64) as f32;
            }
        }
    }
    (out, nw, nh)
}

/// Pixels (c0.., r0..) of size tw × th out of a w-wide image of `n` values per pixel.
fn crop<T: Copy>(px: &[T], w: u32, n: usize, c0: u32, r0: u32, tw: u32, th: u32) -> Vec<T> {
    let mut out = Vec::with_capacity((tw * th) as usize * n);
    for y in r0..r0 + th {
        let i = (y * w + c0) as usize * n;
        out.extend_from_slice(&px[i..i + tw as usize * n]);
    }
    out
}

fn png_rgba(px: Vec<u8>, w: u32, h: u32) -> Vec<u8> {
    match image::RgbaImage::from_raw(w, h, px) {
        Some(img) => super::png(&img.into()),
        None => Vec::new(),
    }
}

/// The map file of a finished run.
pub fn write(o: &Outcome, m: &Manifest, report: &[u8]) -> Result<Vec<u8>, String> {
    let g = &o.geometry;
    let index = MapIndex {
        format: FORMAT.into(),
        version: VERSION,
        name: m.name.clone(),
        origin: g.origin,
        resolution: g.resolution,
        width: g.width,
        height: g.height,
        tile: TILE,
        levels: level_count(g.width, g.height),
        layers: super::LAYERS
            .iter()
            .filter(|l| **l != "error" || o.truth.is_some())
            .map(|l| l.to_string())
            .collect(),
        values: vec!["elevation".into()],
        classes: m.semantic_classes.clone(),
        trajectory: m
            .frames
            .iter()
            .map(|f| [f.vehicle_to_world[0][3], f.vehicle_to_world[1][3]])
            .collect(),
        report: "report.json".into(),
    };
    let mut zip = crate::bundle::ZipBundleWriter::new(std::io::Cursor::new(Vec::new()));
    let json = serde_json::to_vec_pretty(&index).map_err(|e| e.to_string())?;
    zip.add(INDEX, &json)?;
    zip.add(&index.report, report)?;
    for name in &index.layers {
        let Some(mut px) = super::layer_rgba(o, m, name) else {
            continue;
        };
        let (mut w, mut h) = (g.width, g.height);
        for k in 0..index.levels {
            let (tx, ty) = index.tiles(k);
            for r in 0..ty {
                for c in 0..tx {
                    let (tw, th) = index.tile_size(k, c, r);
                    let t = crop(&px, w, 4, c * TILE, r * TILE, tw, th);
                    zip.add(&MapIndex::layer_path(name, k, c, r), &png_rgba(t, tw, th))?;
                }
            }
            (px, w, h) = half_rgba(&px, w, h);
        }
    }
    let mut z = super::elevation(o);
    let (mut w, mut h) = (g.width, g.height);
    for k in 0..index.levels {
        let (tx, ty) = index.tiles(k);
        for r in 0..ty {
            for c in 0..tx {
                let (tw, th) = index.tile_size(k, c, r);
                let t = crop(&z, w, 1, c * TILE, r * TILE, tw, th);
                let bytes: Vec<u8> = t.iter().flat_map(|v| v.to_le_bytes()).collect();
                zip.add(&MapIndex::values_path("elevation", k, c, r), &bytes)?;
            }
        }
        (z, w, h) = half_f32(&z, w, h);
    }
    Ok(zip.finish_raw()?.into_inner())
}

fn invalid(field: &str, what: impl Into<String>) -> Problem {
    Problem::Invalid {
        field: format!("{INDEX}: {field}"),
        what: what.into(),
    }
}

/// What `validate` found in a valid map file.
#[derive(Clone, Debug, Serialize)]
pub struct MapSummary {
    pub index: MapIndex,
    pub tiles: usize,
    pub bytes: u64,
}

/// Checks a map file completely: the index, the report, and every tile of every
/// level (present, decoding, of its size). Every problem is listed.
pub fn validate(bytes: Vec<u8>, limits: &Limits) -> Result<MapSummary, BundleErrors> {
    let size = bytes.len() as u64;
    let src = ZipSource::new(bytes, limits).map_err(BundleErrors)?;
    let text = src.read(INDEX, limits).map_err(|_| {
        BundleErrors(vec![Problem::Invalid {
            field: INDEX.into(),
            what: "missing at the archive's root; a .rogsmap holds map.json (docs/MAP.md)".into(),
        }])
    })?;
    let de = &mut serde_json::Deserializer::from_slice(&text);
    let index: MapIndex = serde_path_to_error::deserialize(de)
        .map_err(|e| BundleErrors(vec![invalid(&e.path().to_string(), e.inner().to_string())]))?;
    let mut problems = Vec::new();
    if index.format != FORMAT {
        problems.push(invalid(
            "format",
            format!("found {:?}, expected \"{FORMAT}\"", index.format),
        ));
    }
    if index.version != VERSION {
        problems.push(invalid(
            "version",
            format!(
                "found {}, this build reads version {VERSION}",
                index.version
            ),
        ));
    }
    if !(index.resolution.is_finite() && index.resolution > 0.0) {
        problems.push(invalid(
            "resolution",
            "expected a positive number of metres per pixel",
        ));
    }
    if !index.origin.iter().all(|v| v.is_finite()) {
        problems.push(invalid("origin", "expected finite world coordinates"));
    }
    if index.width == 0 || index.height == 0 || index.width > 1 << 22 || index.height > 1 << 22 {
        problems.push(invalid("width/height", "expected 1 to 4194304 pixels"));
    }
    if index.tile != TILE {
        problems.push(invalid(
            "tile",
            format!("found {}, expected {TILE}", index.tile),
        ));
    }
    if !problems.is_empty() {
        return Err(BundleErrors(problems));
    }
    if index.levels != level_count(index.width, index.height) {
        problems.push(invalid(
            "levels",
            format!(
                "found {}, expected {} (halve until one tile holds the map)",
                index.levels,
                level_count(index.width, index.height)
            ),
        ));
    }
    if index.trajectory.iter().flatten().any(|v| !v.is_finite()) {
        problems.push(invalid("trajectory", "contains a non-finite coordinate"));
    }
    match src.read(&index.report, limits) {
        Ok(r) if serde_json::from_slice::<serde_json::Value>(&r).is_ok() => {}
        Ok(_) => problems.push(invalid(
            "report",
            format!("{} is not valid JSON", index.report),
        )),
        Err(p) => problems.push(p),
    }
    let mut tiles = 0;
    let levels = index.levels.min(level_count(index.width, index.height));
    for k in 0..levels {
        let (tx, ty) = index.tiles(k);
        for r in 0..ty {
            for c in 0..tx {
                let (tw, th) = index.tile_size(k, c, r);
                for name in &index.layers {
                    let path = MapIndex::layer_path(name, k, c, r);
                    tiles += 1;
                    let b = match src.read(&path, limits) {
                        Ok(b) => b,
                        Err(_) => {
                            problems.push(Problem::MissingFile {
                                field: format!("{INDEX}: layers[{name:?}]"),
                                path,
                            });
                            continue;
                        }
                    };
                    match image::load_from_memory_with_format(&b, image::ImageFormat::Png) {
                        Ok(img) if (img.width(), img.height()) == (tw, th) => {}
                        Ok(img) => problems.push(Problem::Invalid {
                            field: path,
                            what: format!(
                                "tile is {}×{}, expected {tw}×{th}",
                                img.width(),
                                img.height()
                            ),
                        }),
                        Err(e) => problems.push(Problem::ImageDecode {
                            path,
                            reason: e.to_string(),
                        }),
                    }
                }
                for name in &index.values {
                    let path = MapIndex::values_path(name, k, c, r);
                    tiles += 1;
                    match src.read(&path, limits) {
                        Ok(b) if b.len() == (4 * tw * th) as usize => {}
                        Ok(b) => problems.push(Problem::Invalid {
                            field: path,
                            what: format!(
                                "{} bytes, expected {} ({tw}×{th} float32)",
                                b.len(),
                                4 * tw * th
                            ),
                        }),
                        Err(_) => problems.push(Problem::MissingFile {
                            field: format!("{INDEX}: values[{name:?}]"),
                            path,
                        }),
                    }
                }
            }
        }
    }
    if problems.is_empty() {
        Ok(MapSummary {
            index,
            tiles,
            bytes: size,
        })
    } else {
        Err(BundleErrors(problems))
    }
}
