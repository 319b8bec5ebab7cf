//! A catalogue of malformed bundles: each case breaks exactly one thing of the tiny
//! example (`example::tiny`) and says which field or file the refusal must name and a
//! phrase of its rule. `rogs example --malformed DIR` writes them (one zip per case and
//! `catalogue.json`); `tests/catalogue.rs` runs them through `rogs inspect` and `rogs
//! reconstruct`, and the page tests drop them on the page. Writers of other importers
//! can check their own reader against the same cases.

use super::example::{self, png_gray, png_rgb};
use super::write::BundleFile;
use super::MANIFEST;
use serde_json::{json, Value};
use std::io::{Cursor, Write};
use zip::write::SimpleFileOptions;

/// One malformed bundle and what its refusal must say.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Malformed {
    /// The file name stem: `NN-short-name`.
    pub name: String,
    /// What this case breaks, in words.
    pub breaks: &'static str,
    /// The field or file the message must name (empty: the archive itself).
    pub names: &'static str,
    /// A phrase of the rule the message must state.
    pub says: &'static str,
    #[serde(skip)]
    pub zip: Vec<u8>,
}

/// The example's manifest as JSON and its files: what each case edits.
struct Parts {
    manifest: Value,
    files: Vec<BundleFile>,
}

impl Parts {
    fn tiny() -> Self {
        let (m, files) = example::tiny();
        let manifest = serde_json::to_value(&m).unwrap_or(Value::Null);
        Self { manifest, files }
    }

    /// Sets the value at a JSON pointer (`/frames/0/timestamp`): an object's key is
    /// added if missing, an array's element must exist.
    fn set(mut self, pointer: &str, value: Value) -> Self {
        let (parent, key) = pointer.rsplit_once('/').unwrap_or(("", pointer));
        match self.manifest.pointer_mut(parent) {
            Some(Value::Object(o)) => {
                o.insert(key.to_string(), value);
            }
            Some(Value::Array(a)) => {
                if let Some(v) = key.parse::<usize>().ok().and_then(|i| a.get_mut(i)) {
                    *v = value;
                }
            }
            _ => {}
        }
        self
    }

    fn remove(mut self, pointer: &str) -> Self {
        let (parent, key) = pointer.rsplit_once('/').unwrap_or(("", pointer));
        match self.manifest.pointer_mut(parent) {
            Some(Value::Object(o)) => {
                o.remove(key);
            }
            Some(Value::Array(a)) => {
                if let Some(i) = key.parse::<usize>().ok().filter(|&i| i < a.len()) {
                    a.remove(i);
                }
            }
            _ => {}
        }
        self
    }

    fn file(mut self, path: &str, bytes: Vec<u8>) -> Self {
        match self.files.iter_mut().find(|(p, _)| p == path) {
            Some(f) => f.1 = bytes,
            None => self.files.push((path.into(), bytes)),
        }
        self
    }

    fn without(mut self, path: &str) -> Self {
        self.files.retain(|(p, _)| p != path);
        self
    }

    fn bytes(&self, path: &str) -> Vec<u8> {
        self.files
            .iter()
            .find(|(p, _)| p == path)
            .map(|f| f.1.clone())
            .unwrap_or_default()
    }

    fn manifest_bytes(&self) -> Vec<u8> {
        serde_json::to_vec_pretty(&self.manifest).unwrap_or_default()
    }

    /// The archive: the manifest (unless `manifest` says otherwise), then the files.
    fn zip_with(&self, manifest: Option<(&str, &[u8])>) -> Result<Vec<u8>, String> {
        let own = self.manifest_bytes();
        let manifest = manifest.unwrap_or((MANIFEST, &own));
        let mut entries: Vec<(&str, &[u8])> = vec![manifest];
        entries.extend(self.files.iter().map(|(p, b)| (p.as_str(), b.as_slice())));
        raw_zip(&entries)
    }

    fn zip(&self) -> Result<Vec<u8>, String> {
        self.zip_with(None)
    }
}

/// A zip of these entries as given (names unchecked, stored uncompressed).
fn raw_zip(entries: &[(&str, &[u8])]) -> Result<Vec<u8>, String> {
    let mut z = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let opts = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
    for (name, bytes) in entries {
        z.start_file(*name, opts)
            .map_err(|e| format!("{name}: {e}"))?;
        z.write_all(bytes).map_err(|e| format!("{name}: {e}"))?;
    }
    Ok(z.finish().map_err(|e| e.to_string())?.into_inner())
}

/// The archive with a second entry named `dup`: the zip writer refuses one, so a twin
/// name of the same length is written and renamed in the bytes.
fn with_duplicate(p: &Parts, dup: &str) -> Result<Vec<u8>, String> {
    let mut twin = dup.to_string();
    twin.pop();
    twin.push('~');
    let own = p.manifest_bytes();
    let copy = p.bytes(dup);
    let mut entries: Vec<(&str, &[u8])> = vec![(MANIFEST, &own)];
    entries.extend(p.files.iter().map(|(n, b)| (n.as_str(), b.as_slice())));
    entries.push((&twin, &copy));
    let mut bytes = raw_zip(&entries)?;
    let (from, to) = (twin.as_bytes(), dup.as_bytes());
    let mut i = 0;
    while i + from.len() <= bytes.len() {
        if &bytes[i..i + from.len()] == from {
            bytes[i..i + from.len()].copy_from_slice(to);
        }
        i += 1;
    }
    Ok(bytes)
}

const IMAGE: &str = "images/front/000001.png";
const LABEL: &str = "labels/front/000001.png";
const LIDAR: &str = "lidar/000001.bin";

fn rgb(w: u32, h: u32) -> Vec<u8> {
    png_rgb(&image::RgbImage::from_pixel(w, h, image::Rgb([90, 90, 90])))
}

fn grey(w: u32, h: u32, v: u8) -> Vec<u8> {
    png_gray(&image::GrayImage::from_pixel(w, h, image::Luma([v])))
}

/// A rotation scaled by `s` in the row-major 4×4 `[[..];4]`.
fn scaled(s: f64, t: [f64; 3]) -> Value {
    json!([
        [s, 0.0, 0.0, t[0]],
        [0.0, s, 0.0, t[1]],
        [0.0, 0.0, s, t[2]],
        [0.0, 0.0, 0.0, 1.0]
    ])
}

type Build = Box<dyn Fn() -> Result<Vec<u8>, String>>;

/// Every case, in order. Each zip is built from a fresh copy of the example.
pub fn catalogue() -> Result<Vec<Malformed>, String> {
    let (w, h) = (example::WIDTH, example::HEIGHT);
    let edit = |f: fn(Parts) -> Parts| -> Build { Box::new(move || f(Parts::tiny()).zip()) };
    let cases: Vec<(&str, &'static str, &'static str, &'static str, Build)> = vec![
        // The archive.
        (
            "not-a-zip",
            "a text file renamed .zip",
            "",
            "not a readable zip",
            Box::new(|| Ok(b"frames, cameras, poses\n".to_vec())),
        ),
        (
            "empty-file",
            "a file of 0 bytes",
            "",
            "not a readable zip",
            Box::new(|| Ok(Vec::new())),
        ),
        (
            "truncated-zip",
            "the archive cut in half (its directory lost)",
            "",
            "not a readable zip",
            Box::new(|| {
                let z = Parts::tiny().zip()?;
                Ok(z[..z.len() / 2].to_vec())
            }),
        ),
        (
            "no-manifest",
            "manifest.json left out",
            "manifest.json",
            "missing at the bundle root",
            Box::new(|| {
                let p = Parts::tiny();
                let files: Vec<(&str, &[u8])> = p
                    .files
                    .iter()
                    .map(|(n, b)| (n.as_str(), b.as_slice()))
                    .collect();
                raw_zip(&files)
            }),
        ),
        (
            "manifest-in-folder",
            "manifest.json inside a sub-folder",
            "manifest.json",
            "not inside a sub-folder",
            Box::new(|| {
                let p = Parts::tiny();
                let m = p.manifest_bytes();
                p.zip_with(Some(("drive/manifest.json", &m)))
            }),
        ),
        (
            "manifest-not-json",
            "manifest.json with a trailing comma",
            "manifest.json",
            "not valid JSON",
            Box::new(|| {
                let p = Parts::tiny();
                let mut m = p.manifest_bytes();
                m.truncate(m.len() - 2);
                m.extend_from_slice(b",}");
                p.zip_with(Some((MANIFEST, &m)))
            }),
        ),
        (
            "manifest-empty",
            "manifest.json of 0 bytes",
            "manifest.json",
            "not valid JSON",
            Box::new(|| Parts::tiny().zip_with(Some((MANIFEST, b"")))),
        ),
        (
            "manifest-array",
            "manifest.json holding a list, not an object",
            "manifest.json",
            "expected an object",
            Box::new(|| Parts::tiny().zip_with(Some((MANIFEST, b"[1, 2, 3]")))),
        ),
        (
            "duplicate-entry",
            "two zip entries of one image's name",
            IMAGE,
            "two entries",
            Box::new(|| with_duplicate(&Parts::tiny(), IMAGE)),
        ),
        (
            "entry-parent",
            "a zip entry named ../evil.sh",
            "../evil.sh",
            "'..' component",
            Box::new(|| Parts::tiny().file("../evil.sh", b"rm -rf /".to_vec()).zip()),
        ),
        (
            "entry-absolute",
            "a zip entry with an absolute name",
            "/etc/cron.d/x",
            "absolute",
            Box::new(|| Parts::tiny().file("/etc/cron.d/x", b"x".to_vec()).zip()),
        ),
        (
            "entry-drive-letter",
            "a zip entry named C:/x.png",
            "C:/x.png",
            "':'",
            Box::new(|| Parts::tiny().file("C:/x.png", b"x".to_vec()).zip()),
        ),
        // The manifest's header.
        (
            "format",
            "format is not \"rogs-bundle\"",
            "format",
            "expected \"rogs-bundle\"",
            edit(|p| p.set("/format", json!("nuscenes"))),
        ),
        (
            "version",
            "version 2",
            "version",
            "this build reads version 1",
            edit(|p| p.set("/version", json!(2))),
        ),
        (
            "no-cameras-key",
            "the cameras key left out",
            "manifest.json",
            "missing field `cameras`",
            edit(|p| p.remove("/cameras")),
        ),
        (
            "no-frames-key",
            "the frames key left out",
            "manifest.json",
            "missing field `frames`",
            edit(|p| p.remove("/frames")),
        ),
        (
            "fx-string",
            "fx written as a string",
            "cameras[0].fx",
            "expected f64",
            edit(|p| p.set("/cameras/0/fx", json!("500"))),
        ),
        (
            "pose-null",
            "a pose entry null",
            "frames[1].vehicle_to_world[0][3]",
            "expected f64",
            edit(|p| p.set("/frames/1/vehicle_to_world/0/3", Value::Null)),
        ),
        (
            "pose-3x4",
            "a pose of 3 rows",
            "frames[1].vehicle_to_world",
            "expected an array of length 4",
            edit(|p| p.remove("/frames/1/vehicle_to_world/3")),
        ),
        (
            "role-unknown",
            "a class role that does not exist",
            "semantic_classes[0].role",
            "unknown variant",
            edit(|p| p.set("/semantic_classes/0/role", json!("sky"))),
        ),
        (
            "class-id-256",
            "a class id beyond 8 bits",
            "semantic_classes[0].id",
            "invalid value",
            edit(|p| p.set("/semantic_classes/0/id", json!(300))),
        ),
        (
            "height-nan",
            "vehicle_height_m null",
            "vehicle_height_m",
            "expected f64",
            edit(|p| p.set("/vehicle_height_m", Value::Null)),
        ),
        (
            "height-negative",
            "vehicle_height_m below the ground",
            "vehicle_height_m",
            "expected",
            edit(|p| p.set("/vehicle_height_m", json!(-5.0))),
        ),
        (
            "height-huge",
            "vehicle_height_m of a tower",
            "vehicle_height_m",
            "expected",
            edit(|p| p.set("/vehicle_height_m", json!(400.0))),
        ),
        (
            "corridor-zero",
            "corridor_half_width_m of 0",
            "corridor_half_width_m",
            "expected",
            edit(|p| p.set("/corridor_half_width_m", json!(0.0))),
        ),
        (
            "corridor-huge",
            "corridor_half_width_m of 5 km",
            "corridor_half_width_m",
            "expected",
            edit(|p| p.set("/corridor_half_width_m", json!(5000.0))),
        ),
        // Classes and cameras.
        (
            "no-classes",
            "an empty class table with labels",
            "semantic_classes",
            "no class",
            edit(|p| p.set("/semantic_classes", json!([]))),
        ),
        (
            "no-road-class",
            "no class with role road",
            "semantic_classes",
            "role \"road\"",
            edit(|p| {
                let n = p.manifest["semantic_classes"]
                    .as_array()
                    .map_or(0, |a| a.len());
                (0..n).fold(p, |p, i| {
                    p.set(&format!("/semantic_classes/{i}/role"), json!("ignore"))
                })
            }),
        ),
        (
            "class-id-twice",
            "two classes of one id",
            "semantic_classes[1].id",
            "duplicate class id",
            edit(|p| {
                let id = p.manifest["semantic_classes"][0]["id"].clone();
                p.set("/semantic_classes/1/id", id)
            }),
        ),
        (
            "no-camera",
            "an empty camera list",
            "cameras",
            "at least one",
            edit(|p| p.set("/cameras", json!([]))),
        ),
        (
            "camera-twice",
            "two cameras of one name",
            "cameras[1].name",
            "duplicate camera name",
            edit(|p| {
                let c = p.manifest["cameras"][0].clone();
                p.set("/cameras", json!([c.clone(), c]))
            }),
        ),
        (
            "width-zero",
            "a camera 0 pixels wide",
            "cameras[0].width/height",
            "pixels per side",
            edit(|p| p.set("/cameras/0/width", json!(0))),
        ),
        (
            "fx-millimetres",
            "a focal length in millimetres (2 mm)",
            "cameras[0].fx",
            "not millimetres",
            edit(|p| p.set("/cameras/0/fx", json!(2.0))),
        ),
        (
            "fy-tele",
            "a focal length of a 0.01° view",
            "cameras[0].fy",
            "field of view",
            edit(|p| p.set("/cameras/0/fy", json!(1e9))),
        ),
        (
            "cx-outside",
            "a principal point far outside the image",
            "cameras[0].cx",
            "principal point",
            edit(|p| p.set("/cameras/0/cx", json!(1e6))),
        ),
        (
            "mount-far",
            "a camera mounted a kilometre away",
            "cameras[0].camera_to_vehicle translation",
            "vehicle frame",
            edit(|p| p.set("/cameras/0/camera_to_vehicle/2/3", json!(1000.0))),
        ),
        (
            "mount-scaled",
            "a camera mount whose rotation is scaled",
            "cameras[0].camera_to_vehicle",
            "not orthonormal",
            edit(|p| p.set("/cameras/0/camera_to_vehicle/0/0", json!(2.0))),
        ),
        (
            "mask-missing",
            "a camera mask that is not in the archive",
            "cameras[0].mask",
            "not in the bundle",
            edit(|p| p.set("/cameras/0/mask", json!("masks/front.png"))),
        ),
        // Frames and poses.
        (
            "one-frame",
            "a single frame",
            "frames",
            "at least 2",
            edit(|p| p.remove("/frames/2").remove("/frames/1")),
        ),
        (
            "pose-far",
            "a pose 1e308 m away",
            "frames[1].vehicle_to_world translation",
            "local world frame",
            edit(|p| p.set("/frames/1/vehicle_to_world/0/3", json!(1e308))),
        ),
        (
            "pose-scaled",
            "a pose whose rotation is scaled by 2",
            "frames[2].vehicle_to_world",
            "not orthonormal",
            edit(|p| p.set("/frames/2/vehicle_to_world", scaled(2.0, [2.0, 0.0, 0.0]))),
        ),
        (
            "pose-mirrored",
            "a pose that mirrors the world",
            "frames[2].vehicle_to_world",
            "determinant +1",
            edit(|p| p.set("/frames/2/vehicle_to_world", scaled(-1.0, [2.0, 0.0, 0.0]))),
        ),
        (
            "pose-last-row",
            "a pose whose last row is not 0 0 0 1",
            "frames[1].vehicle_to_world",
            "last row",
            edit(|p| p.set("/frames/1/vehicle_to_world/3/0", json!(1.0))),
        ),
        (
            "time-backwards",
            "a timestamp earlier than the frame before",
            "frames[2].timestamp",
            "must not decrease",
            edit(|p| p.set("/frames/2/timestamp", json!(-5.0))),
        ),
        (
            "no-views",
            "a frame without a view",
            "frames[1].views",
            "no view",
            edit(|p| p.set("/frames/1/views", json!([]))),
        ),
        (
            "camera-unknown",
            "a view of a camera not in cameras",
            "frames[1].views[0].camera",
            "unknown camera",
            edit(|p| p.set("/frames/1/views/0/camera", json!("rear"))),
        ),
        (
            "view-pose-scaled",
            "a view's own pose with a scaled rotation",
            "frames[0].views[0].vehicle_to_world",
            "not orthonormal",
            edit(|p| p.set("/frames/0/views/0/vehicle_to_world", scaled(3.0, [0.0; 3]))),
        ),
        (
            "label-partial",
            "one view without a label while the others have one",
            "frames[1].views[0].label",
            "give every view a label",
            edit(|p| p.remove("/frames/1/views/0/label")),
        ),
        // Files.
        (
            "image-missing",
            "an image the manifest names left out of the archive",
            "frames[1].views[0].image",
            "not in the bundle",
            edit(|p| p.without(IMAGE)),
        ),
        (
            "image-path-parent",
            "an image path that climbs out of the bundle",
            "frames[0].views[0].image",
            "'..' component",
            edit(|p| p.set("/frames/0/views/0/image", json!("../../etc/passwd"))),
        ),
        (
            "label-path-absolute",
            "a label path that is absolute",
            "frames[1].views[0].label",
            "absolute",
            edit(|p| p.set("/frames/1/views/0/label", json!("/abs/label.png"))),
        ),
        (
            "image-garbage",
            "an image of random bytes",
            IMAGE,
            "cannot decode the image",
            edit(|p| p.file(IMAGE, b"\x89PNG\r\n\x1a\nnot really a png at all".to_vec())),
        ),
        (
            "image-truncated",
            "an image cut short",
            IMAGE,
            "cannot decode the image",
            edit(|p| {
                let b = p.bytes(IMAGE);
                let n = b.len() * 2 / 3;
                p.file(IMAGE, b[..n].to_vec())
            }),
        ),
        (
            "image-size",
            "an image of another size than its camera",
            IMAGE,
            "expected 64×48",
            Box::new(move || Parts::tiny().file(IMAGE, rgb(w / 2, h)).zip()),
        ),
        (
            "image-too-wide",
            "an image 9 000 pixels wide",
            IMAGE,
            "exceeds the limit",
            Box::new(|| Parts::tiny().file(IMAGE, rgb(9000, 1)).zip()),
        ),
        (
            "label-rgb",
            "a label saved as a colour image",
            LABEL,
            "single-channel",
            Box::new(move || Parts::tiny().file(LABEL, rgb(w, h)).zip()),
        ),
        (
            "label-value",
            "a label pixel of a class not in the table",
            LABEL,
            "label value 99",
            Box::new(move || Parts::tiny().file(LABEL, grey(w, h, 99)).zip()),
        ),
        (
            "label-size",
            "a label of another size than its camera",
            LABEL,
            "expected 64×48",
            Box::new(move || Parts::tiny().file(LABEL, grey(w, h / 2, 0)).zip()),
        ),
        (
            "lidar-missing",
            "a LiDAR sweep left out of the archive",
            "frames[1].lidar",
            "not in the bundle",
            edit(|p| p.without(LIDAR)),
        ),
        (
            "lidar-stride",
            "a LiDAR sweep cut mid-point",
            LIDAR,
            "not a multiple of the point size",
            edit(|p| {
                let b = p.bytes(LIDAR);
                let n = b.len() - 6;
                p.file(LIDAR, b[..n].to_vec())
            }),
        ),
        (
            "lidar-floats",
            "floats_per_point of 2",
            "lidar.floats_per_point",
            "expected 3",
            edit(|p| p.set("/lidar/floats_per_point", json!(2))),
        ),
        (
            "lidar-mount-far",
            "a LiDAR mounted 50 km away",
            "lidar.lidar_to_vehicle translation",
            "check the units",
            edit(|p| p.set("/lidar/lidar_to_vehicle/0/3", json!(5e4))),
        ),
        (
            "lidar-no-sensor",
            "sweeps without a lidar sensor",
            "frames[0].lidar",
            "no top-level lidar sensor",
            edit(|p| p.remove("/lidar")),
        ),
        (
            "truth-resolution",
            "a ground truth of resolution 0",
            "ground_truth.resolution",
            "positive number of metres",
            edit(|p| p.set("/ground_truth/resolution", json!(0.0))),
        ),
        (
            "truth-elevation-size",
            "a truth elevation of the wrong length",
            "truth/elevation.f32",
            "width × height",
            edit(|p| p.file("truth/elevation.f32", vec![0; 12])),
        ),
        (
            "truth-rgb-missing",
            "a truth image left out",
            "ground_truth.rgb",
            "not in the bundle",
            edit(|p| p.without("truth/rgb.png")),
        ),
    ];
    let mut out = Vec::with_capacity(cases.len());
    for (i, (name, breaks, names, says, build)) in cases.into_iter().enumerate() {
        let zip = build().map_err(|e| format!("catalogue case {name}: {e}"))?;
        out.push(Malformed {
            name: format!("{:02}-{name}", i + 1),
            breaks,
            names,
            says,
            zip,
        });
    }
    Ok(out)
}

/// Writes `DIR/NAME.zip` per case and `DIR/catalogue.json`; the number of cases.
pub fn write(dir: &std::path::Path) -> Result<usize, String> {
    let cases = catalogue()?;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for c in &cases {
        let p = dir.join(format!("{}.zip", c.name));
        std::fs::write(&p, &c.zip).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    let json = serde_json::to_vec_pretty(&cases).map_err(|e| e.to_string())?;
    let p = dir.join("catalogue.json");
    std::fs::write(&p, json).map_err(|e| format!("{}: {e}", p.display()))?;
    Ok(cases.len())
}
