//! Semantic labels for nuScenes: Mask2Former Mapillary-Vistas predictions (the
//! masks RoMe and RoGS use), found in either of their folder layouts and remapped to
//! the bundle's road classes with RoGS's table.

use crate::bundle::example::png_gray;
use crate::bundle::{decode_label, ClassRole, Limits, SemanticClass};
use crate::import::{class, read_file};
use std::path::{Path, PathBuf};

/// Bundle class ids of the nuScenes import.
pub mod ids {
    pub const OTHER: u8 = 0;
    pub const ROAD: u8 = 1;
    pub const LANE_MARKING: u8 = 2;
    pub const CURB: u8 = 3;
    pub const MANHOLE: u8 = 4;
    pub const SIDEWALK: u8 = 5;
    pub const TERRAIN: u8 = 6;
    pub const MOVABLE: u8 = 7;
}

/// The class table for remapped Vistas labels. Sidewalk and terrain are `road` (part
/// of the reconstructed surface), as in RoGS, whose road mask keeps them.
pub fn vistas_classes() -> Vec<SemanticClass> {
    use ids::*;
    vec![
        class(OTHER, "other", [0, 0, 0], ClassRole::Ignore),
        class(ROAD, "road", [128, 64, 128], ClassRole::Road),
        class(
            LANE_MARKING,
            "lane_marking",
            [255, 255, 255],
            ClassRole::Road,
        ),
        class(CURB, "curb", [196, 196, 196], ClassRole::Road),
        class(MANHOLE, "manhole", [100, 128, 160], ClassRole::Road),
        class(SIDEWALK, "sidewalk", [244, 35, 232], ClassRole::Road),
        class(TERRAIN, "terrain", [152, 251, 152], ClassRole::Road),
        class(MOVABLE, "movable", [0, 0, 142], ClassRole::Ignore),
    ]
}

/// Mapillary Vistas id (Mask2Former's output) → bundle class id, RoGS's remap.
pub fn vistas_remap() -> [u8; 256] {
    use ids::*;
    let mut lut = [OTHER; 256];
    for v in [7, 8, 14, 23, 24] {
        lut[v] = LANE_MARKING; // bike lane, crosswalk, service lane, markings
    }
    lut[2] = CURB;
    lut[9] = CURB; // curb cut
    lut[13] = ROAD;
    lut[41] = MANHOLE;
    lut[15] = SIDEWALK;
    lut[29] = TERRAIN;
    // Vehicles, the ego car's body and "unlabeled" (52..=65): masked out of every loss.
    lut[52..].fill(MOVABLE);
    lut
}

/// Where a label for `filename` lives: `DIR/seg_CAM_X/<stem>.png` or RoGS's
/// `DIR/samples/seg_CAM_X/<stem>.png` (the image path with `/CAM` → `/seg_CAM`).
pub(super) fn find_label(dir: &Path, channel: &str, filename: &str) -> Result<PathBuf, String> {
    let stem = Path::new(filename)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or(filename);
    let flat = dir
        .join(format!("seg_{channel}"))
        .join(format!("{stem}.png"));
    let rogs = dir.join(Path::new(&filename.replace("/CAM", "/seg_CAM")).with_extension("png"));
    if flat.is_file() {
        return Ok(flat);
    }
    if rogs.is_file() {
        return Ok(rogs);
    }
    Err(format!(
        "no label for {filename}: looked for {} and {}; expected Mask2Former \
         Mapillary-Vistas masks (8-bit PNGs of Vistas ids) named like the image",
        flat.display(),
        rogs.display()
    ))
}

/// Reads a Vistas label, checks its size and remaps it to the bundle classes.
pub(super) fn remap_label(
    path: &Path,
    size: (u32, u32),
    lut: &[u8; 256],
) -> Result<Vec<u8>, String> {
    let bytes = read_file(path, "the label")?;
    let mut img = decode_label(&path.display().to_string(), &bytes, &Limits::default())
        .map_err(|p| format!("{p}; expected an 8-bit PNG of Mapillary Vistas ids"))?;
    if img.dimensions() != size {
        return Err(format!(
            "{}: label is {}×{}, its image is {}×{}; labels must match their image",
            path.display(),
            img.width(),
            img.height(),
            size.0,
            size.1
        ));
    }
    for p in img.pixels_mut() {
        p.0[0] = lut[p.0[0] as usize];
    }
    Ok(png_gray(&img))
}
