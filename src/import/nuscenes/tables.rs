//! The nuScenes tables we read, with only the fields we use (serde skips the rest),
//! and a reader that filters records while parsing: sample_data.json and
//! ego_pose.json of the full dataset hold millions of records, of which one scene
//! needs a few thousand.

use serde::de::{DeserializeOwned, DeserializeSeed, SeqAccess, Visitor};
use serde::Deserialize;
use std::fmt;
use std::io::BufReader;
use std::marker::PhantomData;
use std::path::Path;

#[derive(Clone, Debug, Deserialize)]
pub struct Scene {
    pub token: String,
    pub name: String,
    #[serde(default)]
    pub log_token: String,
}

/// A drive's log: where it was recorded (the map expansion's location name).
#[derive(Clone, Debug, Deserialize)]
pub struct Log {
    pub token: String,
    #[serde(default)]
    pub location: String,
}

#[derive(Clone, Debug, Deserialize)]
pub struct Sample {
    pub token: String,
    /// Microseconds.
    pub timestamp: i64,
    pub scene_token: String,
}

#[derive(Clone, Debug, Deserialize)]
pub struct SampleData {
    pub token: String,
    pub sample_token: String,
    pub ego_pose_token: String,
    pub calibrated_sensor_token: String,
    /// Microseconds.
    pub timestamp: i64,
    pub is_key_frame: bool,
    /// Relative to the dataset root, e.g. `samples/CAM_FRONT/….jpg`.
    pub filename: String,
    /// Image size (0 for LiDAR).
    #[serde(default)]
    pub width: u32,
    #[serde(default)]
    pub height: u32,
}

/// Ego (vehicle) to global: `rotation` is a quaternion `[w, x, y, z]`.
#[derive(Clone, Debug, Deserialize)]
pub struct EgoPose {
    pub token: String,
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
}

/// Sensor to ego: `rotation` is a quaternion `[w, x, y, z]`.
#[derive(Clone, Debug, Deserialize)]
pub struct CalibratedSensor {
    pub token: String,
    pub sensor_token: String,
    pub translation: [f64; 3],
    pub rotation: [f64; 4],
    /// 3×3 rows for cameras, empty for other sensors.
    #[serde(default)]
    pub camera_intrinsic: Vec<Vec<f64>>,
}

#[derive(Clone, Debug, Deserialize)]
pub struct Sensor {
    pub token: String,
    pub channel: String,
}

/// Reads `dir/name`, a JSON array of records, keeping those `keep` accepts.
pub fn read<T: DeserializeOwned>(
    dir: &Path,
    name: &str,
    keep: impl FnMut(&T) -> bool,
) -> Result<Vec<T>, String> {
    let path = dir.join(name);
    let file = std::fs::File::open(&path).map_err(|e| {
        format!(
            "{}: cannot open the nuScenes table ({e}); expected the tables of \
             --version in ROOT/VERSION/",
            path.display()
        )
    })?;
    parse(BufReader::with_capacity(1 << 20, file), &path, keep)
}

/// A table from `reader` (`path` names it in errors), keeping the records `keep`
/// accepts: the others are never held.
pub fn parse<T: DeserializeOwned>(
    reader: impl std::io::Read,
    path: &Path,
    keep: impl FnMut(&T) -> bool,
) -> Result<Vec<T>, String> {
    let mut de = serde_json::Deserializer::from_reader(reader);
    let filter = Filter {
        keep,
        _t: PhantomData,
    };
    filter
        .deserialize(&mut de)
        .and_then(|v| de.end().map(|_| v))
        .map_err(|e| {
            format!(
                "{}: not a nuScenes table ({e}); expected a JSON array of records in the \
                 devkit schema",
                path.display()
            )
        })
}

struct Filter<T, F> {
    keep: F,
    _t: PhantomData<T>,
}

impl<'de, T: Deserialize<'de>, F: FnMut(&T) -> bool> DeserializeSeed<'de> for Filter<T, F> {
    type Value = Vec<T>;
    fn deserialize<D: serde::Deserializer<'de>>(self, d: D) -> Result<Vec<T>, D::Error> {
        d.deserialize_seq(self)
    }
}

impl<'de, T: Deserialize<'de>, F: FnMut(&T) -> bool> Visitor<'de> for Filter<T, F> {
    type Value = Vec<T>;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a JSON array of records")
    }

    fn visit_seq<A: SeqAccess<'de>>(mut self, mut seq: A) -> Result<Vec<T>, A::Error> {
        let mut out = Vec::new();
        while let Some(record) = seq.next_element::<T>()? {
            if (self.keep)(&record) {
                out.push(record);
            }
        }
        Ok(out)
    }
}
