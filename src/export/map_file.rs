//! The map file, `map.rogsmap` (docs/MAP.md): one zip holding every layer of a
//! finished map as an image pyramid of 256-pixel tiles (so a viewer reads the tiles
//! it shows, never a whole 70 000-pixel image), the elevation as float tiles, the
//! georeference, the class table, the trajectory and report.json.
//!
//! `write` makes one; `read_index` / `validate` check one completely (every tile
//! present, decoding at its size), naming the entry or field at fault.

use crate::bundle::{
    Bundle, BundleErrors, Limits, Manifest, Problem, SemanticClass, Source, ZipSource,
};
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
    /// Elevation the `elevation` layer's colour ramp spans, metres (low, high).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elevation_range: Option<[f32; 2]>,
    /// Per level, one character per tile in row-major order: `1` where the tile is
    /// in the archive, `0` where it was left out because nothing is mapped there.
    /// Absent: every tile is present.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub present: Option<Vec<String>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stats: Option<MapStats>,
    /// Frames with a stored thumbnail of their first view's input image:
    /// `thumbs/{frame:06}.jpg` (optional).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub thumbnails: Vec<usize>,
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

    /// Whether tile (c, r) of level k is in the archive (see `present`).
    pub fn is_present(&self, k: u32, c: u32, r: u32) -> bool {
        let Some(p) = &self.present else { return true };
        let tx = self.tiles(k).0;
        p.get(k as usize)
            .and_then(|l| l.as_bytes().get((r * tx + c) as usize))
            .is_none_or(|&b| b == b'1')
    }

    pub fn layer_path(name: &str, k: u32, c: u32, r: u32) -> String {
        format!("layers/{name}/{k}/{c}_{r}.png")
    }

    pub fn values_path(name: &str, k: u32, c: u32, r: u32) -> String {
        format!("values/{name}/{k}/{c}_{r}.f32")
    }

    pub fn thumbnail_path(frame: usize) -> String {
        format!("thumbs/{frame:06}.jpg")
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
fn half_rgba(px: &[u8], w: u32, h: u32) -> Vec<u8> {
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
    out
}

/// Halves a float image: the mean of each 2 × 2 block's finite values.
fn half_f32(v: &[f32], w: u32, h: u32) -> Vec<f32> {
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
    out
}

/// Pixels (c0.., r0..) of size tw × th out of a w-wide image of `n` values per pixel.
pub fn crop<T: Copy>(px: &[T], w: u32, n: usize, c0: u32, r0: u32, tw: u32, th: u32) -> Vec<T> {
    let mut out = Vec::with_capacity((tw * th) as usize * n);
    for y in r0..r0 + th {
        let i = (y * w + c0) as usize * n;
        out.extend_from_slice(&px[i..i + tw as usize * n]);
    }
    out
}

/// Copies a tw-wide block of `n` values per pixel into a w-wide image at (x0, y0).
fn paste<T: Copy>(dst: &mut [T], w: u32, n: usize, x0: u32, y0: u32, src: &[T], tw: u32) {
    let row = tw as usize * n;
    for (y, line) in src.chunks_exact(row).enumerate() {
        let i = ((y0 as usize + y) * w as usize + x0 as usize) * n;
        dst[i..i + row].copy_from_slice(line);
    }
}

fn png_rgba(px: Vec<u8>, w: u32, h: u32) -> Vec<u8> {
    match image::RgbaImage::from_raw(w, h, px) {
        Some(img) => super::png(&img.into()),
        None => Vec::new(),
    }
}

/// A block of level-0 (or any level's) pixels, every layer: RGBA per entry of
/// `MapIndex::layers` and floats per entry of `MapIndex::values`, row-major.
#[derive(Clone, Debug)]
pub struct Region {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<Vec<u8>>,
    pub values: Vec<Vec<f32>>,
}

impl Region {
    /// Transparent and NaN everywhere.
    pub fn empty(layers: usize, values: usize, width: u32, height: u32) -> Self {
        let n = (width * height) as usize;
        Self {
            width,
            height,
            rgba: vec![vec![0; 4 * n]; layers],
            values: vec![vec![f32::NAN; n]; values],
        }
    }

    /// Whether any pixel of any layer holds something.
    pub fn is_empty(&self) -> bool {
        self.rgba
            .iter()
            .all(|l| l.chunks_exact(4).all(|p| p[3] == 0))
            && self.values.iter().all(|v| v.iter().all(|x| x.is_nan()))
    }

    fn paste(&mut self, x0: u32, y0: u32, r: &Region) {
        for (d, s) in self.rgba.iter_mut().zip(&r.rgba) {
            paste(d, self.width, 4, x0, y0, s, r.width);
        }
        for (d, s) in self.values.iter_mut().zip(&r.values) {
            paste(d, self.width, 1, x0, y0, s, r.width);
        }
    }

    fn half(&self) -> Region {
        let (w, h) = (self.width, self.height);
        Region {
            width: w.div_ceil(2),
            height: h.div_ceil(2),
            rgba: self.rgba.iter().map(|l| half_rgba(l, w, h)).collect(),
            values: self.values.iter().map(|v| half_f32(v, w, h)).collect(),
        }
    }
}

/// Where a map's level-0 pixels come from, one tile at a time: the writer holds a
/// few tiles per level, never the whole map, so a map's size is bounded by disk, not
/// memory (the synthetic truth of a long drive is written this way).
pub trait MapSource: Sync {
    /// Pixels `[x0, x0 + w) × [y0, y0 + h)` of level 0 in the index's layer and value
    /// order; `None` (or an empty region) where nothing is mapped.
    fn region(&self, x0: u32, y0: u32, w: u32, h: u32) -> Result<Option<Region>, String>;
}

/// Error histogram bins: 5 mm wide up to 10 cm, the last one holds the rest.
pub const ERROR_BIN_M: f64 = 0.005;
const ERROR_BINS: usize = 21;

/// `map.json`'s `stats`: what a reviewer reads without opening a tile.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapStats {
    /// Area with a mapped elevation, m².
    pub mapped_m2: f64,
    /// Area per class of the table (ids without pixels are left out), m².
    pub classes: Vec<ClassArea>,
    /// Counts of |elevation − truth| in bins of `bin_m` (the last bin holds the
    /// rest), when the map has an error layer.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error_histogram: Option<Histogram>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassArea {
    pub id: u8,
    pub name: String,
    pub area_m2: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Histogram {
    pub bin_m: f64,
    pub counts: Vec<u64>,
}

/// The index and statistics of a map being written.
struct Writer<'a, W: std::io::Write + std::io::Seek> {
    index: &'a MapIndex,
    src: &'a dyn MapSource,
    zip: crate::bundle::ZipBundleWriter<W>,
    present: Vec<Vec<bool>>,
    class_px: [u64; 256],
    mapped_px: u64,
    errors: Option<Vec<u64>>,
    done: usize,
    progress: &'a mut dyn FnMut(usize, usize),
}

impl<W: std::io::Write + std::io::Seek> Writer<'_, W> {
    /// Tile (c, r) of level k, built from its four children at level k − 1 (level 0
    /// from the source) and written; `None` when it is empty.
    fn build(&mut self, k: u32, c: u32, r: u32) -> Result<Option<Region>, String> {
        let i = self.index;
        let (tw, th) = i.tile_size(k, c, r);
        let region = if k == 0 {
            let reg = self.src.region(c * i.tile, r * i.tile, tw, th)?;
            self.done += 1;
            let (tx, ty) = i.tiles(0);
            (self.progress)(self.done, (tx * ty) as usize);
            match reg {
                Some(reg) if (reg.width, reg.height) != (tw, th) => {
                    return Err(format!(
                        "map source gave {}×{} pixels for tile ({c}, {r}), expected {tw}×{th}",
                        reg.width, reg.height
                    ))
                }
                Some(reg) if !reg.is_empty() => {
                    self.count(&reg);
                    Some(reg)
                }
                _ => None,
            }
        } else {
            let (lw, lh) = i.level_size(k - 1);
            let (mw, mh) = (
                (lw - 2 * c * i.tile).min(2 * i.tile),
                (lh - 2 * r * i.tile).min(2 * i.tile),
            );
            let (ntx, nty) = i.tiles(k - 1);
            let mut mosaic: Option<Region> = None;
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (cc, rr) = (2 * c + dx, 2 * r + dy);
                if cc >= ntx || rr >= nty {
                    continue;
                }
                if let Some(child) = self.build(k - 1, cc, rr)? {
                    mosaic
                        .get_or_insert_with(|| {
                            Region::empty(i.layers.len(), i.values.len(), mw, mh)
                        })
                        .paste(dx * i.tile, dy * i.tile, &child);
                }
            }
            mosaic.map(|m| m.half())
        };
        if let Some(reg) = &region {
            for (name, px) in i.layers.iter().zip(&reg.rgba) {
                let png = png_rgba(px.clone(), tw, th);
                self.zip.add(&MapIndex::layer_path(name, k, c, r), &png)?;
            }
            for (name, v) in i.values.iter().zip(&reg.values) {
                let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
                self.zip
                    .add(&MapIndex::values_path(name, k, c, r), &bytes)?;
            }
            let tx = i.tiles(k).0;
            self.present[k as usize][(r * tx + c) as usize] = true;
        }
        Ok(region)
    }

    /// Level-0 statistics: mapped area, class areas, the error histogram.
    fn count(&mut self, reg: &Region) {
        let value = |name: &str| {
            self.index
                .values
                .iter()
                .position(|v| v == name)
                .map(|k| &reg.values[k])
        };
        if let Some(z) = value("elevation") {
            self.mapped_px += z.iter().filter(|v| v.is_finite()).count() as u64;
        }
        if let Some(ids) = value("class") {
            for v in ids.iter().filter(|v| v.is_finite()) {
                self.class_px[(*v as usize).min(255)] += 1;
            }
        }
        if let (Some(e), Some(h)) = (value("error"), self.errors.as_mut()) {
            for v in e.iter().filter(|v| v.is_finite()) {
                h[((*v as f64 / ERROR_BIN_M) as usize).min(ERROR_BINS - 1)] += 1;
            }
        }
    }
}

/// Writes a map file: `index` (its `present` and `stats` are filled in here) with
/// level-0 pixels from `src`, built into the pyramid tile by tile. Empty tiles are
/// left out and marked so in `present`. `progress(done, total)` counts level-0 tiles.
pub fn write_from(
    index: MapIndex,
    src: &dyn MapSource,
    report: &[u8],
    thumbnails: &[(usize, Vec<u8>)],
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<u8>, String> {
    let out = std::io::Cursor::new(Vec::new());
    write_into(out, index, src, report, thumbnails, progress).map(|c| c.into_inner())
}

/// As `write_from`, into `out` (a file: the map is never held whole).
pub fn write_into<W: std::io::Write + std::io::Seek>(
    out: W,
    mut index: MapIndex,
    src: &dyn MapSource,
    report: &[u8],
    thumbnails: &[(usize, Vec<u8>)],
    progress: &mut dyn FnMut(usize, usize),
) -> Result<W, String> {
    index.levels = level_count(index.width, index.height);
    let mut w = Writer {
        index: &index,
        src,
        zip: crate::bundle::ZipBundleWriter::new(out),
        present: (0..index.levels)
            .map(|k| {
                let (tx, ty) = index.tiles(k);
                vec![false; (tx * ty) as usize]
            })
            .collect(),
        class_px: [0; 256],
        mapped_px: 0,
        errors: index
            .values
            .iter()
            .any(|v| v == "error")
            .then(|| vec![0; ERROR_BINS]),
        done: 0,
        progress,
    };
    w.build(index.levels - 1, 0, 0)?;
    w.zip.add(&index.report, report)?;
    for (f, jpg) in thumbnails {
        w.zip.add(&MapIndex::thumbnail_path(*f), jpg)?;
    }
    let px_m2 = index.resolution * index.resolution;
    let stats = MapStats {
        mapped_m2: w.mapped_px as f64 * px_m2,
        classes: index
            .classes
            .iter()
            .filter(|c| w.class_px[c.id as usize] > 0)
            .map(|c| ClassArea {
                id: c.id,
                name: c.name.clone(),
                area_m2: w.class_px[c.id as usize] as f64 * px_m2,
            })
            .collect(),
        error_histogram: w.errors.take().map(|counts| Histogram {
            bin_m: ERROR_BIN_M,
            counts,
        }),
    };
    let present = w
        .present
        .iter()
        .map(|p| p.iter().map(|&b| if b { '1' } else { '0' }).collect())
        .collect();
    let mut zip = w.zip;
    index.present = Some(present);
    index.stats = Some(stats);
    index.thumbnails = thumbnails.iter().map(|t| t.0).collect();
    let json = serde_json::to_vec_pretty(&index).map_err(|e| e.to_string())?;
    zip.add(INDEX, &json)?;
    zip.finish_raw()
}

/// A finished run's layers, held in memory, as a map source.
struct OutcomeSource {
    whole: Region,
}

impl MapSource for OutcomeSource {
    fn region(&self, x0: u32, y0: u32, w: u32, h: u32) -> Result<Option<Region>, String> {
        let r = &self.whole;
        let reg = Region {
            width: w,
            height: h,
            rgba: r
                .rgba
                .iter()
                .map(|l| crop(l, r.width, 4, x0, y0, w, h))
                .collect(),
            values: r
                .values
                .iter()
                .map(|v| crop(v, r.width, 1, x0, y0, w, h))
                .collect(),
        };
        Ok(Some(reg))
    }
}

/// The index of a map before it is written: georeference, layers and values named,
/// `levels`, `present` and `stats` to be filled in by `write_from`.
pub fn new_index(
    name: &str,
    classes: &[SemanticClass],
    trajectory: Vec<[f64; 2]>,
    g: &crate::bev::BevGeometry,
    layers: &[&str],
    values: &[&str],
) -> MapIndex {
    MapIndex {
        format: FORMAT.into(),
        version: VERSION,
        name: name.into(),
        origin: g.origin,
        resolution: g.resolution,
        width: g.width,
        height: g.height,
        tile: TILE,
        levels: level_count(g.width, g.height),
        layers: layers.iter().map(|l| l.to_string()).collect(),
        values: values.iter().map(|l| l.to_string()).collect(),
        classes: classes.to_vec(),
        trajectory,
        report: "report.json".into(),
        elevation_range: None,
        present: None,
        stats: None,
        thumbnails: Vec::new(),
    }
}

/// Vehicle positions (world x, y) of a manifest's frames.
pub fn trajectory(m: &Manifest) -> Vec<[f64; 2]> {
    m.frames
        .iter()
        .map(|f| [f.vehicle_to_world[0][3], f.vehicle_to_world[1][3]])
        .collect()
}

/// At most this many frames get a thumbnail, evenly spaced along the drive.
pub const THUMBNAILS: usize = 120;
/// Thumbnail width, pixels.
pub const THUMB_WIDTH: u32 = 320;

/// The frames that get a thumbnail: up to `THUMBNAILS`, evenly spaced.
pub fn thumbnail_frames(m: &Manifest) -> Vec<usize> {
    let n = m.frames.len();
    let every = n.div_ceil(THUMBNAILS).max(1);
    (0..n.div_ceil(every)).map(|i| i * every).collect()
}

/// JPEG thumbnails of the first view of up to `THUMBNAILS` frames, for a reviewer
/// who clicks the trajectory without the bundle. Images that cannot be read are
/// skipped (the bundle was validated; a thumbnail is not worth failing a map for).
pub fn thumbnails(b: &Bundle) -> Vec<(usize, Vec<u8>)> {
    let frames = &b.manifest.frames;
    let chosen = thumbnail_frames(&b.manifest);
    crate::par::par_map(chosen.len(), |i| {
        let f = chosen[i];
        let view = frames[f].views.first()?;
        let img = image::load_from_memory(&b.read(&view.image).ok()?).ok()?;
        let h = (img.height() as u64 * THUMB_WIDTH as u64 / img.width().max(1) as u64).max(1);
        let small = img
            .resize_exact(THUMB_WIDTH, h as u32, image::imageops::FilterType::Triangle)
            .to_rgb8();
        let mut jpg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 80)
            .encode_image(&small)
            .ok()?;
        Some((f, jpg))
    })
    .into_iter()
    .flatten()
    .collect()
}

/// The map file of a finished run: every layer, and as values the elevation, the
/// class id, confidence, density and (with truth) the elevation error; thumbnails of
/// the input images.
pub fn write(o: &Outcome, b: &Bundle, report: &[u8]) -> Result<Vec<u8>, String> {
    let range = super::range(&super::elevation(o));
    let index = run_index(&b.manifest, &o.geometry, o.truth.is_some(), range);
    let src = OutcomeSource {
        whole: region_of(o, &b.manifest, &index, range),
    };
    write_from(index, &src, report, &thumbnails(b), &mut |_, _| {})
}

/// The index of a run's map file over geometry `g`: every layer (the error with
/// truth), the values `region_of` gives, the elevation ramp's `range`.
pub fn run_index(
    m: &Manifest,
    g: &crate::bev::BevGeometry,
    truth: bool,
    range: (f32, f32),
) -> MapIndex {
    // A drive without labels has no semantic layer and no class values.
    let layers: Vec<&str> = super::LAYERS
        .iter()
        .copied()
        .filter(|l| (*l != "error" || truth) && (*l != "semantic" || m.labelled()))
        .collect();
    let all = ["elevation", "class", "confidence", "density", "error"];
    let values: Vec<&str> = all
        .into_iter()
        .filter(|v| (*v != "error" || truth) && (*v != "class" || m.labelled()))
        .collect();
    let mut index = new_index(
        &m.name,
        &m.semantic_classes,
        trajectory(m),
        g,
        &layers,
        &values,
    );
    index.elevation_range = Some([range.0, range.1]);
    index
}

/// The pixels of `o` (its whole geometry: a map, or a block of one) in the layers
/// and values of `index` (`run_index`), the elevation's colours over `range`.
pub fn region_of(o: &Outcome, m: &Manifest, index: &MapIndex, range: (f32, f32)) -> Region {
    let g = &o.geometry;
    let n = (g.width * g.height) as usize;
    let value = |name: &str| -> Vec<f32> {
        let r = &o.raster;
        match name {
            "elevation" => super::elevation(o),
            "class" => r
                .class_ids
                .as_raw()
                .iter()
                .zip(r.valid.as_raw())
                .map(|(&c, &v)| if v != 0 { c as f32 } else { f32::NAN })
                .collect(),
            "confidence" => o.confidence.clone(),
            "density" => o.density.clone(),
            "error" => super::elevation_error(o).unwrap_or_else(|| vec![f32::NAN; n]),
            _ => vec![f32::NAN; n],
        }
    };
    Region {
        width: g.width,
        height: g.height,
        rgba: index
            .layers
            .iter()
            .map(|l| super::layer_rgba_in(o, m, l, range).unwrap_or_else(|| vec![0; 4 * n]))
            .collect(),
        values: index.values.iter().map(|v| value(v)).collect(),
    }
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
    if let Some(p) = &index.present {
        if p.len() != levels as usize {
            problems.push(invalid(
                "present",
                format!("{} levels listed, expected {levels}", p.len()),
            ));
        }
        for (k, l) in p.iter().enumerate().take(levels as usize) {
            let (tx, ty) = index.tiles(k as u32);
            if l.len() != (tx * ty) as usize || l.bytes().any(|b| b != b'0' && b != b'1') {
                problems.push(invalid(
                    &format!("present[{k}]"),
                    format!("expected {} characters 0 or 1 ({tx}×{ty} tiles)", tx * ty),
                ));
            }
        }
    }
    for k in 0..levels {
        let (tx, ty) = index.tiles(k);
        for r in 0..ty {
            for c in 0..tx {
                if !index.is_present(k, c, r) {
                    continue;
                }
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
    for &f in &index.thumbnails {
        let path = MapIndex::thumbnail_path(f);
        match src.read(&path, limits) {
            Ok(b) => {
                if let Err(e) = image::load_from_memory_with_format(&b, image::ImageFormat::Jpeg) {
                    problems.push(Problem::ImageDecode {
                        path,
                        reason: e.to_string(),
                    });
                }
            }
            Err(_) => problems.push(Problem::MissingFile {
                field: format!("{INDEX}: thumbnails"),
                path,
            }),
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
