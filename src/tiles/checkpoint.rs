//! Checkpoints of finished tiles, so that a run which stopped (a tile that failed, a
//! lost device, a killed process) resumes where it stopped instead of training every
//! tile again.
//!
//! A tile's checkpoint is everything the run keeps of it once it is trained: its
//! layers over its window of the map (what the stitcher blends), the surfels of its
//! core (what `surfels.ply` holds), the surfel centres some view saw (the metrics),
//! its held-out sums and its report. Restoring one is adding those to the run exactly
//! as `TiledRun::record` did, so a resumed map is the map the uninterrupted run makes
//! (tiles are independent jobs: no tile's training reads another's).
//!
//! The file is a zip (`tile.json` and one little-endian array per entry, deflated)
//! that any unzip tool opens. `tile.json` carries the run's fingerprint: a hash of
//! the manifest, the settings and the tile plan, so that a checkpoint made with other
//! settings or bundles is refused by name instead of mixed into the map.

use super::TileReport;
use crate::bev::BevImage;
use crate::reconstruct::{HoldoutSums, Layers};
use crate::render::Params;
use serde::{Deserialize, Serialize};
use std::io::{Cursor, Read, Write};

/// What a finished tile adds to the run.
#[derive(Default)]
pub struct Finished {
    /// The tile's index in the plan.
    pub index: usize,
    pub report: TileReport,
    /// The tile's layers over its window (`None` when the window misses the map).
    pub layers: Option<Layers>,
    /// The surfels of the tile's core, in the run's model frame.
    pub model: Params<f32>,
    /// World centres of the core surfels some view saw.
    pub centres: Vec<[f64; 3]>,
    /// Σ Δz² and count over the core surfels (report's `z_change_rms_m`).
    pub z_change: (f64, usize),
    /// Σ (initial z − truth)² and count over `centres` where the truth is valid
    /// (metrics' `initial_elevation_rmse_m`).
    pub initial_error: (f64, usize),
    pub holdout: HoldoutSums,
    pub holdout_views: usize,
}

pub const FORMAT: &str = "rogs-tile";
pub const VERSION: u32 = 1;
/// File name suffix of a tile checkpoint.
pub const SUFFIX: &str = ".tile";

#[derive(Serialize, Deserialize)]
struct Header {
    format: String,
    version: u32,
    /// The run's fingerprint, hex.
    fingerprint: String,
    index: usize,
    report: TileReport,
    /// [width, height, channels] of the layers, absent when the tile has none.
    layers: Option<[usize; 3]>,
    surfels: usize,
    channels: usize,
    centres: usize,
    z_change: (f64, usize),
    #[serde(default)]
    initial_error: (f64, usize),
    holdout_se: f64,
    holdout_se_ipm: f64,
    holdout_n: u64,
    holdout_frames: Vec<usize>,
    holdout_views: usize,
}

/// 64-bit FNV-1a, for the run's fingerprint (not for security: it tells runs apart).
pub fn fnv1a(parts: &[&[u8]]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for p in parts {
        for &b in p.iter() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        // A separator, so that ("ab", "c") and ("a", "bc") differ.
        h ^= 0xff;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn le<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

/// The checkpoint file of `f` for a run of fingerprint `fingerprint`, in memory
/// (the page, which has no disk).
pub fn encode(f: &Finished, fingerprint: u64) -> Result<Vec<u8>, String> {
    Ok(encode_into(f, fingerprint, Cursor::new(Vec::new()))?.into_inner())
}

/// Natively: writes the checkpoint of `f` into `dir/name` as it is encoded, with no
/// copy of it in memory. Returns the file's path.
pub fn write_file(
    f: &Finished,
    fingerprint: u64,
    dir: &std::path::Path,
    name: &str,
) -> Result<std::path::PathBuf, String> {
    write_whole(dir, name, |w| encode_into(f, fingerprint, w).map(drop))
}

/// Natively: a checkpoint file `dir/name` written by `fill`: to `name.part`, then
/// renamed, so a run killed while writing leaves no half checkpoint. Returns the
/// file's path; an error names the file.
pub fn write_whole(
    dir: &std::path::Path,
    name: &str,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> Result<(), String>,
) -> Result<std::path::PathBuf, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let part = dir.join(format!("{name}.part"));
    let cannot = |e: &dyn std::fmt::Display| format!("cannot write {}: {e}", part.display());
    let file = std::fs::File::create(&part).map_err(|e| cannot(&e))?;
    let mut w = std::io::BufWriter::new(file);
    fill(&mut w).map_err(|e| cannot(&e))?;
    w.into_inner().map_err(|e| cannot(&e))?;
    let to = dir.join(name);
    std::fs::rename(&part, &to).map_err(|e| format!("cannot write {}: {e}", to.display()))?;
    Ok(to)
}

/// The checkpoint file of `f` for a run of fingerprint `fingerprint`, into `w`.
fn encode_into<W: std::io::Write + std::io::Seek>(
    f: &Finished,
    fingerprint: u64,
    w: W,
) -> Result<W, String> {
    let h = Header {
        format: FORMAT.into(),
        version: VERSION,
        fingerprint: format!("{fingerprint:016x}"),
        index: f.index,
        report: f.report.clone(),
        layers: f
            .layers
            .as_ref()
            .map(|l| [l.bev.width as usize, l.bev.height as usize, l.bev.channels]),
        surfels: f.model.len(),
        channels: f.model.channels,
        centres: f.centres.len(),
        z_change: f.z_change,
        initial_error: f.initial_error,
        holdout_se: f.holdout.se,
        holdout_se_ipm: f.holdout.se_ipm,
        holdout_n: f.holdout.n,
        holdout_frames: f.holdout.frames.iter().copied().collect(),
        holdout_views: f.holdout_views,
    };
    let json = serde_json::to_vec_pretty(&h).map_err(|e| e.to_string())?;
    let mut zip = zip::ZipWriter::new(w);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .compression_level(Some(1));
    let mut add = |name: &str, bytes: &[u8]| -> Result<(), String> {
        zip.start_file(name, opts)
            .and_then(|_| zip.write_all(bytes).map_err(Into::into))
            .map_err(|e| format!("{name}: {e}"))
    };
    add("tile.json", &json)?;
    if let Some(l) = &f.layers {
        add("layers/rgb.f32", le(&l.bev.rgb))?;
        add("layers/logits.f32", le(&l.bev.logits))?;
        add("layers/elevation.f32", le(&l.bev.elevation))?;
        add("layers/alpha.f32", le(&l.bev.alpha))?;
        add("layers/confidence.f32", le(&l.confidence))?;
        add("layers/density.f32", le(&l.density))?;
    }
    let p = &f.model;
    add("surfels/pos.f32", le(&p.pos))?;
    add("surfels/rgb.f32", le(&p.rgb))?;
    add("surfels/log_scale.f32", le(&p.log_scale))?;
    add("surfels/opacity.f32", le(&p.opacity))?;
    add("surfels/rotation.f32", le(&p.rotation))?;
    add("surfels/logits.f32", le(&p.logits))?;
    add("centres.f64", le(&f.centres))?;
    zip.finish().map_err(|e| e.to_string())
}

/// Reads a checkpoint; `Err` says which entry is wrong and what it should hold.
/// Returns the tile and the fingerprint of the run that wrote it.
pub fn decode(bytes: &[u8]) -> Result<(Finished, u64), String> {
    let (mut zip, h, fingerprint) = open(bytes)?;
    let layers = match h.layers {
        None => None,
        Some([w, ht, ch]) => {
            let n = w.saturating_mul(ht);
            if n == 0 || n > MAX_PX || ch > MAX_CHANNELS {
                return Err(format!(
                    "tile.json: layers of {w}×{ht} px, {ch} channels is out of range"
                ));
            }
            let mut f32s = |name: &str, per: usize| read_f32(&mut zip, name, n * per);
            Some(Layers {
                bev: BevImage {
                    width: w as u32,
                    height: ht as u32,
                    channels: ch,
                    rgb: f32s("layers/rgb.f32", 3)?,
                    logits: f32s("layers/logits.f32", ch)?,
                    elevation: f32s("layers/elevation.f32", 1)?,
                    alpha: f32s("layers/alpha.f32", 1)?,
                },
                confidence: f32s("layers/confidence.f32", 1)?,
                density: f32s("layers/density.f32", 1)?,
            })
        }
    };
    let model = read_model(&mut zip, &h)?;
    let centres = read_centres(&mut zip, &h)?;
    let f = Finished {
        index: h.index,
        report: h.report,
        layers,
        model,
        centres,
        z_change: h.z_change,
        initial_error: h.initial_error,
        holdout: HoldoutSums {
            se: h.holdout_se,
            se_ipm: h.holdout_se_ipm,
            n: h.holdout_n,
            frames: h.holdout_frames.into_iter().collect(),
        },
        holdout_views: h.holdout_views,
    };
    Ok((f, fingerprint))
}

/// The surfels and the seen centres of a checkpoint alone, checked as `decode`
/// checks them: a tile whose model was left in its checkpoint
/// (`TiledRun::spill_models`), read back to write the model's files and score it.
pub fn decode_model(bytes: &[u8]) -> Result<(Params<f32>, Vec<[f64; 3]>), String> {
    let (mut zip, h, _) = open(bytes)?;
    Ok((read_model(&mut zip, &h)?, read_centres(&mut zip, &h)?))
}

// Every count comes from the header: the arrays are bounded before they are read.
const MAX_PX: usize = 1 << 28;
const MAX_SURFELS: usize = 1 << 28;
const MAX_CHANNELS: usize = 256;

type Zip<'a> = zip::ZipArchive<Cursor<&'a [u8]>>;

/// The checkpoint's zip, its header (checked) and the fingerprint it carries.
fn open(bytes: &[u8]) -> Result<(Zip<'_>, Header, u64), String> {
    let mut zip = zip::ZipArchive::new(Cursor::new(bytes))
        .map_err(|e| format!("not a tile checkpoint (a zip with tile.json): {e}"))?;
    let json = read_entry(&mut zip, "tile.json", None)?;
    let h: Header = serde_json::from_slice(&json).map_err(|e| format!("tile.json: {e}"))?;
    if h.format != FORMAT || h.version != VERSION {
        return Err(format!(
            "tile.json: format {:?} version {}, expected {FORMAT:?} version {VERSION}",
            h.format, h.version
        ));
    }
    let fingerprint = u64::from_str_radix(&h.fingerprint, 16)
        .map_err(|_| format!("tile.json: fingerprint {:?} is not hex", h.fingerprint))?;
    if h.channels > MAX_CHANNELS || h.surfels > MAX_SURFELS || h.centres > h.surfels {
        return Err(format!(
            "tile.json: {} surfels of {} channels and {} centres is out of range",
            h.surfels, h.channels, h.centres
        ));
    }
    Ok((zip, h, fingerprint))
}

/// The tile's surfels (`surfels/*.f32`).
fn read_model(zip: &mut Zip<'_>, h: &Header) -> Result<Params<f32>, String> {
    let n = h.surfels;
    let mut f32s = |name: &str, per: usize| read_f32(zip, name, n * per);
    let pos = f32s("surfels/pos.f32", 3)?;
    let rgb = f32s("surfels/rgb.f32", 3)?;
    let log_scale = f32s("surfels/log_scale.f32", 2)?;
    let opacity = f32s("surfels/opacity.f32", 1)?;
    let rotation = f32s("surfels/rotation.f32", 4)?;
    let logits = f32s("surfels/logits.f32", h.channels)?;
    Ok(Params {
        pos: pos.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        rgb: rgb.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        log_scale: log_scale.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
        opacity,
        rotation: rotation
            .chunks_exact(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect(),
        logits,
        channels: h.channels,
    })
}

/// World centres of the core surfels some view saw (`centres.f64`).
fn read_centres(zip: &mut Zip<'_>, h: &Header) -> Result<Vec<[f64; 3]>, String> {
    let raw = read_entry(zip, "centres.f64", Some(h.centres * 24))?;
    Ok(raw
        .chunks_exact(24)
        .map(|c| {
            let v = |k: usize| f64::from_le_bytes(c[8 * k..8 * k + 8].try_into().unwrap_or([0; 8]));
            [v(0), v(1), v(2)]
        })
        .collect())
}

/// Entry `name`, which must hold exactly `len` bytes when `len` is given (checked
/// before it is inflated).
fn read_entry<R: Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    name: &str,
    len: Option<usize>,
) -> Result<Vec<u8>, String> {
    let mut e = zip
        .by_name(name)
        .map_err(|_| format!("the entry {name} is missing"))?;
    let size = e.size() as usize;
    if let Some(len) = len {
        if size != len {
            return Err(format!("{name} holds {size} bytes, expected {len}"));
        }
    } else if size > 16 << 20 {
        return Err(format!(
            "{name} holds {size} bytes, expected at most 16 MiB"
        ));
    }
    let mut out = Vec::with_capacity(size);
    e.read_to_end(&mut out)
        .map_err(|err| format!("{name}: cannot be read: {err}"))?;
    if out.len() != size {
        return Err(format!(
            "{name} inflates to {} bytes, expected {size}",
            out.len()
        ));
    }
    Ok(out)
}

fn read_f32<R: Read + std::io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    name: &str,
    count: usize,
) -> Result<Vec<f32>, String> {
    let raw = read_entry(zip, name, Some(count * 4))?;
    Ok(raw
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A checkpoint written into its file as it is encoded is the one encoded in
    /// memory, byte for byte, decodes to the same tile, and leaves no `.part`.
    #[test]
    fn written_into_its_file_as_encoded_in_memory() {
        let mut f = Finished {
            index: 3,
            centres: vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.5]],
            ..Default::default()
        };
        f.model.channels = 2;
        for k in 0..2 {
            f.model.pos.push([k as f32, 1.0, 0.25]);
            f.model.rgb.push([0.5; 3]);
            f.model.log_scale.push([-3.0; 2]);
            f.model.opacity.push(0.9);
            f.model.rotation.push([1.0, 0.0, 0.0, 0.0]);
            f.model.logits.extend([0.1, k as f32]);
        }
        f.report.name = "x1_y2".into();
        let dir = std::env::temp_dir().join(format!("rogs-ckpt-{}", std::process::id()));
        let path = write_file(&f, 7, &dir, "x1_y2.tile").expect("write");
        let bytes = std::fs::read(&path).expect("read");
        assert_eq!(bytes, encode(&f, 7).expect("encode"));
        let (back, fingerprint) = decode(&bytes).expect("decode");
        assert_eq!((back.index, fingerprint), (3, 7));
        assert_eq!(back.model.logits, f.model.logits);
        assert_eq!(back.centres, f.centres);
        let names: Vec<_> = std::fs::read_dir(&dir)
            .expect("dir")
            .filter_map(|e| e.ok().map(|e| e.file_name()))
            .collect();
        assert_eq!(names, ["x1_y2.tile"], "only the renamed file is left");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
