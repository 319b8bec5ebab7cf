//! Stage 8: export. Every file of a finished run as (name, bytes), so that the CLI
//! writes them to a folder and the page offers them as downloads, identically.

pub mod colour;
pub mod geotiff;
pub mod layers;
pub mod map_file;
pub mod ply;

use crate::bev::BevGeometry;
use crate::bundle::Manifest;
use crate::reconstruct::Outcome;
use crate::render::Params;
use colour::legend;
use image::{GrayImage, RgbImage};

fn png(img: &image::DynamicImage) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    // Encoding an in-memory image into a Vec cannot fail for RGB8/L8.
    let _ = img.write_to(&mut out, image::ImageFormat::Png);
    out.into_inner()
}

/// The header of a float32 array of `height` rows of `width` as NumPy `.npy`
/// (version 1.0, little endian, C order); the values follow.
pub fn npy_header(width: u32, height: u32) -> Vec<u8> {
    let mut head =
        format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({height}, {width}), }}");
    // Magic (6) + version (2) + length (2) + header, padded with spaces to 64 bytes.
    while (10 + head.len() + 1) % 64 != 0 {
        head.push(' ');
    }
    head.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(head.len() as u16).to_le_bytes());
    out.extend_from_slice(head.as_bytes());
    out
}

/// Finite minimum and maximum (0, 1 when there is none).
pub(crate) fn range(v: &[f32]) -> (f32, f32) {
    let (lo, hi) = v
        .iter()
        .filter(|x| x.is_finite())
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    if lo > hi {
        (0.0, 1.0)
    } else {
        (lo, hi)
    }
}

/// The semantic layer coloured with the manifest's class colours.
pub fn semantic_colours(m: &Manifest, ids: &GrayImage, valid: &GrayImage) -> RgbImage {
    let mut lut = [[0u8; 3]; 256];
    for c in &m.semantic_classes {
        lut[c.id as usize] = c.color;
    }
    RgbImage::from_fn(ids.width(), ids.height(), |x, y| {
        if valid.get_pixel(x, y).0[0] == 0 {
            image::Rgb([0, 0, 0])
        } else {
            image::Rgb(lut[ids.get_pixel(x, y).0[0] as usize])
        }
    })
}

/// A 0..1 scalar layer as greyscale (NaN black).
fn grey(v: &[f32], w: u32, h: u32) -> GrayImage {
    GrayImage::from_fn(w, h, |x, y| {
        let s = v[(y * w + x) as usize];
        image::Luma([if s.is_finite() {
            (s.clamp(0.0, 1.0) * 255.0).round() as u8
        } else {
            0
        }])
    })
}

/// The elevation layer (world metres, NaN where invalid).
pub fn elevation(o: &Outcome) -> Vec<f32> {
    o.raster
        .elevation
        .iter()
        .zip(o.raster.valid.pixels())
        .map(|(&z, v)| if v.0[0] != 0 { z } else { f32::NAN })
        .collect()
}

/// |elevation − truth| where both are valid, metres.
pub fn elevation_error(o: &Outcome) -> Option<Vec<f32>> {
    let t = o.truth.as_ref()?;
    let g = &o.geometry;
    let z = elevation(o);
    Some(
        (0..(g.width * g.height))
            .map(|i| {
                let (x, y) = (i % g.width, i / g.width);
                let (wx, wy) = (
                    g.origin[0] + (x as f64 + 0.5) * g.resolution,
                    g.origin[1] - (y as f64 + 0.5) * g.resolution,
                );
                match t.pixel_of(wx, wy) {
                    Some((c, r)) if t.is_valid(c, r) => {
                        (z[i as usize] - t.elevation_at(c, r)).abs()
                    }
                    _ => f32::NAN,
                }
            })
            .collect(),
    )
}

/// The model's own files (`surfels.ply`, `surfels_semantic.ply` for a labelled drive,
/// and `surfel_centres.f32`: world x, y, z as f32 per surfel), which need no BEV: the
/// CLI writes them as soon as training ends.
pub fn model_files(
    p: &Params<f32>,
    origin: [f64; 3],
    m: &Manifest,
    up: ply::Up,
) -> Vec<(String, Vec<u8>)> {
    // Writing to memory with the count given cannot fail.
    ModelWriter::start(|_| Ok(Vec::new()), p.len(), origin, m, up)
        .and_then(|mut w| {
            w.add(p)?;
            w.finish()
        })
        .unwrap_or_default()
}

/// `model_files` written a part at a time (a tiled run's finished tiles, read back
/// one by one from their checkpoints): headers for `count` surfels in all, then each
/// part's rows in order. The files are the same as `model_files` of the parts joined.
pub struct ModelWriter<'a, W: std::io::Write> {
    sinks: Vec<(String, W)>,
    origin: [f64; 3],
    up: ply::Up,
    manifest: &'a Manifest,
    count: usize,
    written: usize,
}

impl<'a, W: std::io::Write> ModelWriter<'a, W> {
    /// Opens each file with `open(name)` and writes the headers.
    pub fn start(
        mut open: impl FnMut(&str) -> Result<W, String>,
        count: usize,
        origin: [f64; 3],
        m: &'a Manifest,
        up: ply::Up,
    ) -> Result<Self, String> {
        let frame = m.frame_description();
        let mut names = vec!["surfel_centres.f32", "surfels.ply"];
        if m.labelled() {
            names.push("surfels_semantic.ply");
        }
        let mut sinks = Vec::new();
        for name in names {
            let mut w = open(name)?;
            if name.ends_with(".ply") {
                w.write_all(ply::header(count, origin, up, &frame).as_bytes())
                    .map_err(|e| format!("{name}: {e}"))?;
            }
            sinks.push((name.to_string(), w));
        }
        Ok(Self {
            sinks,
            origin,
            up,
            manifest: m,
            count,
            written: 0,
        })
    }

    /// Appends the surfels of `p`.
    pub fn add(&mut self, p: &Params<f32>) -> Result<(), String> {
        self.written += p.len();
        if self.written > self.count {
            return Err(format!(
                "the model has more surfels than the {} its files were started for",
                self.count
            ));
        }
        for (name, w) in &mut self.sinks {
            let mut out = Vec::new();
            match name.as_str() {
                "surfel_centres.f32" => {
                    for q in &p.pos {
                        for (v, o) in q.iter().zip(self.origin) {
                            out.extend_from_slice(&((*v as f64 + o) as f32).to_le_bytes());
                        }
                    }
                }
                "surfels.ply" => ply::push_rows(&mut out, p, self.up, None),
                _ => {
                    let classes = class_colours(p, self.manifest);
                    ply::push_rows(&mut out, p, self.up, Some(&classes));
                }
            }
            w.write_all(&out).map_err(|e| format!("{name}: {e}"))?;
        }
        Ok(())
    }

    /// The files, every surfel written.
    pub fn finish(self) -> Result<Vec<(String, W)>, String> {
        if self.written != self.count {
            return Err(format!(
                "the model's files were started for {} surfels, {} were written",
                self.count, self.written
            ));
        }
        let mut out = Vec::new();
        for (name, mut w) in self.sinks {
            w.flush().map_err(|e| format!("{name}: {e}"))?;
            out.push((name, w));
        }
        Ok(out)
    }
}

/// Each surfel in the colour of its most likely class (channel k is class k of the
/// table).
fn class_colours(p: &Params<f32>, m: &Manifest) -> Vec<[u8; 3]> {
    (0..p.len())
        .map(|i| {
            let l = &p.logits[i * p.channels..(i + 1) * p.channels];
            let k = (0..l.len())
                .max_by(|&a, &b| l[a].total_cmp(&l[b]))
                .unwrap_or(0);
            m.semantic_classes.get(k).map_or([0, 0, 0], |c| c.color)
        })
        .collect()
}

/// The map's files (BEV layers and their geometry); with `model_files` and the report,
/// every output of a run.
pub fn files(o: &Outcome, m: &Manifest) -> Result<Vec<(String, Vec<u8>)>, String> {
    let g = o.geometry;
    let range = range(&elevation(o));
    let truth = o.truth.is_some();
    let mut sinks: Vec<(String, std::io::Cursor<Vec<u8>>)> = layers::names(&g, m, truth)
        .into_iter()
        .map(|n| (n.to_string(), std::io::Cursor::new(Vec::new())))
        .collect();
    let mut w = layers::LayerFiles::start(&mut sinks, g, m, range, truth)?;
    w.add(0, 0, o)?;
    w.finish()?;
    let mut out: Vec<_> = sinks
        .into_iter()
        .map(|(n, c)| (n, c.into_inner()))
        .collect();
    out.extend(side_files(&g, m, range, truth));
    Ok(out)
}

/// `bev.json`: the map's geometry, its elevation range and what its layers hold.
pub fn bev_json(g: &BevGeometry, m: &Manifest, (lo, hi): (f32, f32)) -> serde_json::Value {
    let note = if layers::dense(g) {
        "origin is the world x of the west edge and y of the north edge; row 0 is north; \
         elevation.npy/.f32 hold world z in metres, NaN where the map is empty"
    } else {
        "origin is the world x of the west edge and y of the north edge; row 0 is north; \
         the map is too large for whole-image layers: they are in the tiled GeoTIFFs \
         (elevation.tif holds z in the dataset's frame) and map.rogsmap (docs/MAP.md)"
    };
    serde_json::json!({
        "origin": g.origin, "resolution": g.resolution, "width": g.width, "height": g.height,
        "note": note,
        "elevation_min_m": lo, "elevation_max_m": hi,
        "world_frame": m.world_frame, "frame": m.frame_description(),
    })
}

/// The map's small files beside its layers: `bev.json` and the legends of the
/// colour-mapped layers.
pub fn side_files(
    g: &BevGeometry,
    m: &Manifest,
    (lo, hi): (f32, f32),
    truth: bool,
) -> Vec<(String, Vec<u8>)> {
    let mut out = vec![
        (
            "bev.json".into(),
            serde_json::to_vec_pretty(&bev_json(g, m, (lo, hi))).unwrap_or_default(),
        ),
        (
            "elevation_legend.png".into(),
            png(&legend(LEGEND_WIDTH, lo, hi, &|v| format!("{v:.2}m")).into()),
        ),
    ];
    if truth {
        out.push((
            "error_legend.png".into(),
            png(&legend(LEGEND_WIDTH, 0.0, 0.1, &|v| format!("{:.0}cm", v * 100.0)).into()),
        ));
    }
    out
}

/// Width of the legend images, pixels.
const LEGEND_WIDTH: u32 = 400;

/// Values through the colour ramp from `lo` to `hi`, as RGBA (transparent where NaN).
pub fn ramp_rgba(v: &[f32], lo: f32, hi: f32) -> Vec<u8> {
    v.iter()
        .flat_map(|&x| {
            let c = colour::ramp((x - lo) / (hi - lo).max(1e-6));
            [c[0], c[1], c[2], if x.is_finite() { 255 } else { 0 }]
        })
        .collect()
}

/// Names of the layers `layer_rgba` renders.
pub const LAYERS: [&str; 6] = [
    "rgb",
    "semantic",
    "elevation",
    "confidence",
    "density",
    "error",
];

/// A layer as RGBA pixels for display (transparent where the map is empty), with the
/// map's size; `None` for an unknown name, `error` without truth or `semantic` for
/// a drive without labels.
pub fn layer_rgba(o: &Outcome, m: &Manifest, name: &str) -> Option<Vec<u8>> {
    layer_rgba_in(o, m, name, range(&elevation(o)))
}

/// As `layer_rgba`, the elevation's colours spanning `range` (a block of a map
/// takes the whole map's).
pub fn layer_rgba_in(o: &Outcome, m: &Manifest, name: &str, range: (f32, f32)) -> Option<Vec<u8>> {
    let r = &o.raster;
    let (w, h) = (o.geometry.width, o.geometry.height);
    let valid = |i: usize| r.valid.as_raw()[i] != 0;
    let from_rgb = |img: &RgbImage| -> Vec<u8> {
        img.pixels()
            .enumerate()
            .flat_map(|(i, p)| [p.0[0], p.0[1], p.0[2], if valid(i) { 255 } else { 0 }])
            .collect()
    };
    let from_values = ramp_rgba;
    match name {
        "rgb" => Some(from_rgb(&r.rgb)),
        "semantic" if m.labelled() => Some(from_rgb(&semantic_colours(m, &r.class_ids, &r.valid))),
        "elevation" => Some(from_values(&elevation(o), range.0, range.1)),
        "confidence" => Some(from_rgb(
            &image::DynamicImage::from(grey(&o.confidence, w, h)).to_rgb8(),
        )),
        "density" => Some(from_rgb(
            &image::DynamicImage::from(grey(&o.density, w, h)).to_rgb8(),
        )),
        "error" => elevation_error(o).map(|e| from_values(&e, 0.0, 0.1)),
        _ => None,
    }
}
