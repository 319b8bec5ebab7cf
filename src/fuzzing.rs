//! What fuzzing feeds each reader: one function per target of `fuzz/` (coverage-guided,
//! cargo-fuzz) and of `tests/fuzz_corpus.rs` (the kept corpus and a short mutation
//! run in CI), so that both exercise the same calls. Each takes any bytes; a reader
//! may refuse them, never panic, hang or allocate without bound.

use crate::import::nuscenes::{tables, transform};
use crate::import::{kitti, parse_classes};
use std::path::Path;

/// Any bytes as a dropped bundle, every image decoded (as `rogs inspect` and the page).
pub fn bundle(data: &[u8]) {
    let limits = crate::bundle::Limits {
        decode_images: true,
        ..Default::default()
    };
    let _ = crate::bundle::Bundle::from_zip_bytes(data.to_vec(), limits);
}

/// Any bytes as a tile checkpoint (`--resume`, `rogs merge`).
pub fn checkpoint(data: &[u8]) {
    let _ = crate::tiles::checkpoint::decode(data);
}

/// Any bytes as a map file (`.rogsmap`), checked completely as `rogs inspect` does.
pub fn map_file(data: &[u8]) {
    let _ = crate::export::map_file::validate(data.to_vec(), &crate::bundle::Limits::default());
}

/// Any bytes as one of the importers' tables, the first byte choosing which: KITTI's
/// calib.txt and poses, a class table (`--classes`), nuScenes' JSON tables (each
/// record type, then the transform its quaternions make).
pub fn importers(data: &[u8]) {
    let Some((&which, rest)) = data.split_first() else {
        return;
    };
    let path = Path::new("fuzz");
    let text = std::str::from_utf8(rest).ok();
    match which % 8 {
        0 => {
            if let Some(Ok(c)) = text.map(|t| kitti::parse_calib(t, path)) {
                for p in c.p.iter().flatten() {
                    let _ = kitti::intrinsics(p);
                    let _ = kitti::camera_to_vehicle(p, 1.65);
                }
            }
        }
        1 => {
            if let Some(Ok(poses)) = text.map(|t| kitti::parse_poses(t, path)) {
                let _ = kitti::vehicle_poses(&poses, 1.65);
            }
        }
        2 => {
            let _ = parse_classes(rest, path);
        }
        3 => {
            if let Ok(v) = tables::parse(rest, path, |_: &tables::CalibratedSensor| true) {
                for c in v {
                    let _ = transform(c.rotation, c.translation);
                }
            }
        }
        4 => {
            if let Ok(v) = tables::parse(rest, path, |_: &tables::EgoPose| true) {
                for e in v {
                    let _ = transform(e.rotation, e.translation);
                }
            }
        }
        5 => {
            let _ = tables::parse(rest, path, |d: &tables::SampleData| d.is_key_frame);
        }
        6 => {
            let _ = tables::parse(rest, path, |_: &tables::Sample| true);
            let _ = tables::parse(rest, path, |_: &tables::Sensor| true);
        }
        _ => {
            let _ = tables::parse(rest, path, |_: &tables::Scene| true);
            let _ = tables::parse(rest, path, |_: &tables::Log| true);
        }
    }
}

/// A target: any bytes in, nothing out (a panic is the failure).
pub type Target = fn(&[u8]);

/// The targets by name, as `fuzz/` and `fuzz/corpus/` call them.
pub const TARGETS: [(&str, Target); 4] = [
    ("bundle", bundle),
    ("checkpoint", checkpoint),
    ("importers", importers),
    ("map_file", map_file),
];
