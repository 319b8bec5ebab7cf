//! Fields of manifest.json that no part of rogs reads: a misspelled optional field
//! (`corridor_half_width` for `corridor_half_width_m`) would otherwise be ignored in
//! silence. They are found by comparing the manifest as written with the same
//! manifest re-serialised with every optional field filled in (so the schema is the
//! types' own, never a second list), and reported as warnings with the nearest
//! known name.

use super::manifest::{GroundTruth, LidarSensor, Manifest, WorldFrame};
use serde_json::Value;

/// One warning per unknown field: `frames[3].views[0].vehicle_to_wrld: unknown field,
/// ignored (did you mean vehicle_to_world?)`.
pub fn unknown_fields(text: &[u8], m: &Manifest) -> Vec<String> {
    let Ok(written) = serde_json::from_slice::<Value>(text) else {
        return Vec::new();
    };
    let Ok(full) = serde_json::to_value(filled(m)) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    walk(&written, &full, "", &mut out);
    out
}

/// `m` with every optional field present.
fn filled(m: &Manifest) -> Manifest {
    let id = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let mut f = m.clone();
    f.lidar.get_or_insert(LidarSensor {
        floats_per_point: 3,
        lidar_to_vehicle: id,
    });
    f.ground_truth.get_or_insert(GroundTruth {
        origin: [0.0; 2],
        resolution: 1.0,
        width: 1,
        height: 1,
        rgb: String::new(),
        class_ids: String::new(),
        elevation: String::new(),
        valid: String::new(),
        poses: None,
    });
    f.world_frame.get_or_insert(WorldFrame {
        name: String::new(),
        offset_m: [0.0; 3],
    });
    f.corridor_half_width_m.get_or_insert(0.0);
    for fr in &mut f.frames {
        fr.lidar.get_or_insert_with(String::new);
        for v in &mut fr.views {
            v.vehicle_to_world.get_or_insert(id);
        }
    }
    f
}

fn walk(written: &Value, known: &Value, path: &str, out: &mut Vec<String>) {
    match (written, known) {
        (Value::Object(w), Value::Object(k)) => {
            for (name, v) in w {
                let here = if path.is_empty() {
                    name.clone()
                } else {
                    format!("{path}.{name}")
                };
                match k.get(name) {
                    Some(kv) => walk(v, kv, &here, out),
                    None => {
                        let near = k
                            .keys()
                            .filter(|c| !w.contains_key(*c))
                            .map(|c| (distance(name, c), c))
                            .min();
                        let hint = match near {
                            Some((d, c)) if d <= 3.max(name.len() / 3) => {
                                format!(" (did you mean {c}?)")
                            }
                            _ => String::new(),
                        };
                        out.push(format!("{here}: unknown field, ignored{hint}"));
                    }
                }
            }
        }
        (Value::Array(w), Value::Array(k)) => {
            for (i, (wv, kv)) in w.iter().zip(k).enumerate() {
                walk(wv, kv, &format!("{path}[{i}]"), out);
            }
        }
        _ => {}
    }
}

/// Levenshtein distance.
fn distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for j in 0..b.len() {
            let cur = row[j + 1];
            row[j + 1] = (prev + (ca != b[j]) as usize).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}
