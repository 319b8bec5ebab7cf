//! nuScenes (the devkit's JSON tables, read directly) → scene bundle.
//!
//! A bundle frame has one vehicle pose shared by all its cameras, while every
//! nuScenes sample_data carries its own ego pose (the six cameras fire within about
//! 50 ms of one another). We take the anchor camera's (CAM_FRONT's) ego pose for the
//! frame and report how far the others' poses are from it: this is the one
//! approximation of the importer. LiDAR sweeps are moved exactly into the frame's
//! vehicle pose instead, since their points are rewritten anyway (5 floats → 4).
//! Tables are filtered while they are parsed, so that the full trainval tables
//! (gigabytes of JSON) need not fit in memory.

mod labels;
pub mod tables;

use super::{
    apply, header_dims, inverse, mul, read_file, resolve, rigid, ImportError, Imported, Output,
    ProgressFn, NO_LABELS_WARNING,
};
use crate::bundle::{
    Camera, Frame, LidarSensor, Manifest, Mat4Rows, View, WorldFrame, FORMAT, VERSION,
};
use labels::{find_label, remap_label};
pub use labels::{ids, vistas_classes, vistas_remap};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
pub use tables::{CalibratedSensor, EgoPose, SampleData};
use tables::{Log, Sample, Scene, Sensor};

/// The six cameras, in the order the bundle lists them.
pub const CAMERAS: [&str; 6] = [
    "CAM_FRONT",
    "CAM_FRONT_LEFT",
    "CAM_FRONT_RIGHT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_BACK_RIGHT",
];
pub const LIDAR: &str = "LIDAR_TOP";

/// Largest time between an anchor image and the sweep of another sensor put in its
/// frame: cameras run at 12 Hz, the LiDAR at 20 Hz.
const MATCH_US: i64 = 50_000;

const LAYOUT: &str = concat!(
    "expected the nuScenes layout:\n",
    "  ROOT/VERSION/scene.json, sample.json, sample_data.json, ego_pose.json,\n",
    "               calibrated_sensor.json, sensor.json\n",
    "  ROOT/samples/CAM_FRONT/….jpg, ROOT/samples/LIDAR_TOP/….pcd.bin (keyframes)\n",
    "  ROOT/sweeps/CAM_FRONT/….jpg, ROOT/sweeps/LIDAR_TOP/….pcd.bin (for --sweeps)"
);

#[derive(Clone, Debug)]
pub struct NuScenesOptions {
    /// The dataset root holding `samples/`, `sweeps/` and the version folder.
    pub root: PathBuf,
    /// Table folder name, e.g. "v1.0-mini".
    pub version: String,
    /// Scene name, e.g. "scene-0655".
    pub scene: String,
    pub out: PathBuf,
    /// Mask2Former Mapillary-Vistas label PNGs (`DIR/seg_CAM_FRONT/<stem>.png`).
    pub labels: Option<PathBuf>,
    /// Camera channels; the first one listed of CAM_FRONT (else the first) anchors frames.
    pub cameras: Vec<String>,
    /// Also import the non-keyframe camera images (12 Hz instead of 2 Hz).
    pub sweeps: bool,
}

impl NuScenesOptions {
    pub fn new(root: impl Into<PathBuf>, scene: &str, out: impl Into<PathBuf>) -> Self {
        Self {
            root: root.into(),
            version: "v1.0-mini".into(),
            scene: scene.into(),
            out: out.into(),
            labels: None,
            cameras: CAMERAS.iter().map(|c| c.to_string()).collect(),
            sweeps: false,
        }
    }
}

/// Rotation of a unit quaternion given as nuScenes writes it, `[w, x, y, z]`
/// (normalised first: the tables round to ~1e-8).
pub fn quaternion_rotation(q: [f64; 4]) -> Result<[[f64; 3]; 3], String> {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(n.is_finite() && n > 1e-6) {
        return Err(format!(
            "quaternion {q:?} has no rotation (its norm is {n})"
        ));
    }
    let [w, x, y, z] = q.map(|v| v / n);
    Ok([
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ])
}

/// The 4×4 of a nuScenes `rotation` + `translation` pair.
pub fn transform(rotation: [f64; 4], translation: [f64; 3]) -> Result<Mat4Rows, String> {
    Ok(rigid(quaternion_rotation(rotation)?, translation))
}

/// Everything of one scene the import needs, read from the tables.
struct SceneData {
    /// Sample-data records per channel, sorted by time.
    records: HashMap<String, Vec<SampleData>>,
    calib: HashMap<String, CalibratedSensor>,
    ego: HashMap<String, EgoPose>,
    /// First and last keyframe times, µs.
    span: (i64, i64),
    /// The scene's location (log.json), when the tables have it.
    location: Option<String>,
}

fn load(opts: &NuScenesOptions, channels: &HashSet<String>) -> Result<SceneData, String> {
    let dir = opts.root.join(&opts.version);
    if !dir.join("scene.json").is_file() {
        return Err(format!(
            "{}: no scene.json (is --version right?); {LAYOUT}",
            dir.display()
        ));
    }
    let scenes: Vec<Scene> = tables::read(&dir, "scene.json", |_: &Scene| true)?;
    let Some(scene) = scenes.iter().find(|s| s.name == opts.scene) else {
        let names: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).take(20).collect();
        return Err(format!(
            "scene {:?} is not in {}; available: {}{}",
            opts.scene,
            dir.join("scene.json").display(),
            names.join(", "),
            if scenes.len() > 20 { ", …" } else { "" }
        ));
    };
    let samples: Vec<Sample> = tables::read(&dir, "sample.json", |s: &Sample| {
        s.scene_token == scene.token
    })?;
    let sample_tokens: HashSet<&str> = samples.iter().map(|s| s.token.as_str()).collect();
    let span = (
        samples.iter().map(|s| s.timestamp).min().unwrap_or(0),
        samples.iter().map(|s| s.timestamp).max().unwrap_or(0),
    );
    let sensors: Vec<Sensor> = tables::read(&dir, "sensor.json", |_: &Sensor| true)?;
    let channel_of: HashMap<&str, &str> = sensors
        .iter()
        .map(|s| (s.token.as_str(), s.channel.as_str()))
        .collect();
    let calibs: Vec<CalibratedSensor> =
        tables::read(&dir, "calibrated_sensor.json", |c: &CalibratedSensor| {
            channel_of
                .get(c.sensor_token.as_str())
                .is_some_and(|ch| channels.contains(*ch))
        })?;
    let calib_channel: HashMap<String, String> = calibs
        .iter()
        .filter_map(|c| {
            let ch = channel_of.get(c.sensor_token.as_str())?;
            Some((c.token.clone(), ch.to_string()))
        })
        .collect();
    let data: Vec<SampleData> = tables::read(&dir, "sample_data.json", |d: &SampleData| {
        (opts.sweeps || d.is_key_frame)
            && sample_tokens.contains(d.sample_token.as_str())
            && calib_channel.contains_key(&d.calibrated_sensor_token)
    })?;
    let pose_tokens: HashSet<&str> = data.iter().map(|d| d.ego_pose_token.as_str()).collect();
    let ego: Vec<EgoPose> = tables::read(&dir, "ego_pose.json", |e: &EgoPose| {
        pose_tokens.contains(e.token.as_str())
    })?;
    let ego = ego.into_iter().map(|e| (e.token.clone(), e)).collect();
    let mut records: HashMap<String, Vec<SampleData>> = HashMap::new();
    for d in data {
        if let Some(ch) = calib_channel.get(&d.calibrated_sensor_token) {
            records.entry(ch.clone()).or_default().push(d);
        }
    }
    for r in records.values_mut() {
        r.sort_by_key(|d| d.timestamp);
    }
    let calib = calibs.into_iter().map(|c| (c.token.clone(), c)).collect();
    let location = if dir.join("log.json").is_file() {
        let logs: Vec<Log> = tables::read(&dir, "log.json", |l: &Log| l.token == scene.log_token)?;
        logs.into_iter()
            .next()
            .map(|l| l.location)
            .filter(|l| !l.is_empty())
    } else {
        None
    };
    Ok(SceneData {
        records,
        calib,
        ego,
        span,
        location,
    })
}

impl SceneData {
    fn pose(&self, d: &SampleData) -> Result<Mat4Rows, String> {
        let e = self.ego.get(&d.ego_pose_token).ok_or_else(|| {
            format!(
                "ego_pose.json has no record {:?} (sample_data {:?})",
                d.ego_pose_token, d.token
            )
        })?;
        transform(e.rotation, e.translation).map_err(|m| format!("ego_pose {}: {m}", e.token))
    }

    /// The channel's sensor-to-ego transform, refusing a calibration that changes
    /// within the scene (the bundle has one extrinsic per sensor).
    fn calibration(&self, channel: &str) -> Result<Option<&CalibratedSensor>, String> {
        let Some(recs) = self.records.get(channel) else {
            return Ok(None);
        };
        let tokens: HashSet<&str> = recs
            .iter()
            .map(|d| d.calibrated_sensor_token.as_str())
            .collect();
        let mut cals = tokens.iter().filter_map(|t| self.calib.get(*t));
        let Some(first) = cals.next() else {
            return Ok(None);
        };
        if cals.any(|c| c.rotation != first.rotation || c.translation != first.translation) {
            return Err(format!(
                "{channel}: its calibration changes within the scene; a bundle has one \
                 extrinsic per sensor (import the parts separately)"
            ));
        }
        Ok(Some(first))
    }

    /// The record of `channel` that belongs in the frame anchored at `anchor`: the same
    /// sample's keyframe, or for a sweep the nearest unused sweep within `MATCH_US`.
    fn partner(
        &self,
        channel: &str,
        anchor: &SampleData,
        used: &HashSet<&str>,
    ) -> Option<&SampleData> {
        let recs = self.records.get(channel)?;
        if anchor.is_key_frame {
            return recs
                .iter()
                .find(|d| d.is_key_frame && d.sample_token == anchor.sample_token);
        }
        recs.iter()
            .filter(|d| !d.is_key_frame && !used.contains(d.token.as_str()))
            .map(|d| ((d.timestamp - anchor.timestamp).abs(), d))
            .filter(|(dt, _)| *dt <= MATCH_US)
            .min_by_key(|(dt, _)| *dt)
            .map(|(_, d)| d)
    }
}

/// Rewrites a `.pcd.bin` sweep (x, y, z, intensity, ring) as x, y, z, intensity, and
/// moves it from its own ego pose into the frame's: `L⁻¹·E_f⁻¹·E_s·L`.
fn convert_sweep(bytes: &[u8], motion: Option<&Mat4Rows>) -> Vec<u8> {
    let mut out = Vec::with_capacity(bytes.len() / 5 * 4);
    for p in bytes.chunks_exact(20) {
        let f = |i: usize| f32::from_le_bytes([p[4 * i], p[4 * i + 1], p[4 * i + 2], p[4 * i + 3]]);
        let mut xyz = [f(0), f(1), f(2)];
        if let Some(m) = motion {
            xyz = apply(m, xyz.map(f64::from)).map(|v| v as f32);
        }
        for v in [xyz[0], xyz[1], xyz[2], f(3)] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

fn file_name(filename: &str) -> &str {
    filename.rsplit('/').next().unwrap_or(filename)
}

/// Largest time and pose differences between a frame's views and its anchor.
#[derive(Default)]
struct Spread {
    dt_us: i64,
    metres: f64,
    degrees: f64,
}

impl Spread {
    fn add(&mut self, dt_us: i64, a: &Mat4Rows, b: &Mat4Rows) {
        let d = mul(&inverse(a), b);
        let trace = d[0][0] + d[1][1] + d[2][2];
        self.dt_us = self.dt_us.max(dt_us.abs());
        self.metres = self.metres.max(d[0][3].hypot(d[1][3]).hypot(d[2][3]));
        self.degrees = self
            .degrees
            .max(((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees());
    }
}

/// Imports one nuScenes scene into a validated bundle at `opts.out`.
pub fn import(opts: &NuScenesOptions, progress: ProgressFn) -> Result<Imported, ImportError> {
    if opts.cameras.is_empty() {
        return Err("--cameras: no camera given".to_string().into());
    }
    let mut channels: HashSet<String> = opts.cameras.iter().cloned().collect();
    channels.insert(LIDAR.into());
    let scene = load(opts, &channels)?;
    for c in &opts.cameras {
        if !scene.records.contains_key(c) {
            let mut have: Vec<&String> = scene.records.keys().collect();
            have.sort();
            return Err(format!(
                "camera {c:?} has no images in {} (channels found: {have:?}); expected \
                 names like {CAMERAS:?}",
                opts.scene
            )
            .into());
        }
    }
    let anchor_channel = if opts.cameras.iter().any(|c| c == "CAM_FRONT") {
        "CAM_FRONT"
    } else {
        opts.cameras[0].as_str()
    };
    let mut warnings = Vec::new();
    let (classes, labels, lut) = match &opts.labels {
        Some(dir) => {
            let dir = resolve(&opts.root, dir);
            if !dir.is_dir() {
                return Err(format!(
                    "{}: label folder not found; expected DIR/seg_CAM_FRONT/<image stem>.png …",
                    dir.display()
                )
                .into());
            }
            (vistas_classes(), Some(dir), vistas_remap())
        }
        None => {
            warnings.push(NO_LABELS_WARNING.to_string());
            (Vec::new(), None, [0; 256])
        }
    };

    let cameras = opts
        .cameras
        .iter()
        .map(|name| camera(&scene, opts, name))
        .collect::<Result<Vec<_>, _>>()?;
    let lidar = match scene.calibration(LIDAR)? {
        Some(c) => Some(
            transform(c.rotation, c.translation)
                .map_err(|m| format!("calibrated_sensor {}: {m}", c.token))?,
        ),
        None => None,
    };

    let (t_lo, t_hi) = scene.span;
    let anchors: Vec<&SampleData> = scene.records[anchor_channel]
        .iter()
        .filter(|d| d.timestamp >= t_lo - MATCH_US && d.timestamp <= t_hi + MATCH_US)
        .collect();
    let Some(first) = anchors.first() else {
        return Err(format!("{}: no {anchor_channel} images", opts.scene).into());
    };
    // The world is the global (map) frame shifted to the first frame's ego position:
    // map coordinates run to thousands of metres, too coarse for float32 on the GPU.
    let origin = scene.pose(first)?;
    let shift = rigid(
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [-origin[0][3], -origin[1][3], -origin[2][3]],
    );
    let t0 = first.timestamp;

    let mut out = Output::create(&opts.out)?;
    let mut used: HashSet<&str> = HashSet::new();
    let mut spread = Spread::default();
    let mut frames = Vec::with_capacity(anchors.len());
    for (k, anchor) in anchors.iter().enumerate() {
        let pose = scene.pose(anchor)?;
        let mut views = Vec::new();
        for cam in &cameras {
            let rec = if cam.name == anchor_channel {
                Some(*anchor)
            } else {
                scene.partner(&cam.name, anchor, &used)
            };
            let Some(rec) = rec else { continue };
            used.insert(rec.token.as_str());
            let own = scene.pose(rec)?;
            spread.add(rec.timestamp - anchor.timestamp, &pose, &own);
            let mut view = write_view(&mut out, opts, cam, rec, labels.as_deref(), &lut)?;
            // Each camera is placed with its own sample_data's ego pose: cameras fire
            // along the sweep, up to ~50 ms (0.5 m at 10 m/s) from the anchor's.
            if rec.token != anchor.token {
                view.vehicle_to_world = Some(mul(&shift, &own));
            }
            views.push(view);
        }
        let lidar_path = match &lidar {
            Some(l2v) => write_sweep(&mut out, opts, &scene, anchor, &pose, l2v)?,
            None => None,
        };
        frames.push(Frame {
            timestamp: (anchor.timestamp - t0) as f64 * 1e-6,
            vehicle_to_world: mul(&shift, &pose),
            views,
            lidar: lidar_path,
        });
        progress("importing", k + 1, anchors.len());
    }
    if cameras.len() > 1 {
        warnings.push(format!(
            "each view carries its own ego pose: the other cameras fired up to {:.0} ms from \
             {anchor_channel}'s and their ego poses differ from its by up to {:.3} m and {:.2}°",
            spread.dt_us as f64 / 1000.0,
            spread.metres,
            spread.degrees
        ));
    }
    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        name: format!(
            "nuScenes {} {}{} (world: global frame shifted by [{:.3}, {:.3}, {:.3}] m)",
            opts.version,
            opts.scene,
            if opts.sweeps { " with sweeps" } else { "" },
            -origin[0][3],
            -origin[1][3],
            -origin[2][3]
        ),
        vehicle_height_m: 0.0,
        semantic_classes: classes,
        cameras,
        frames,
        lidar: lidar.map(|l2v| LidarSensor {
            floats_per_point: 4,
            lidar_to_vehicle: l2v,
        }),
        ground_truth: None,
        world_frame: Some(WorldFrame {
            name: match &scene.location {
                Some(l) => format!("nuScenes global frame of {l} (the map expansion's)"),
                None => "nuScenes global frame".into(),
            },
            offset_m: [origin[0][3], origin[1][3], origin[2][3]],
        }),
        corridor_half_width_m: Some(8.0),
    };
    out.finish(manifest, warnings, progress)
}

/// A camera's intrinsics and extrinsic from its calibrated_sensor record.
fn camera(scene: &SceneData, opts: &NuScenesOptions, name: &str) -> Result<Camera, String> {
    let cal = scene
        .calibration(name)?
        .ok_or_else(|| format!("{name}: calibrated_sensor.json has no record for it"))?;
    let k = &cal.camera_intrinsic;
    if k.len() != 3 || k.iter().any(|r| r.len() != 3) {
        return Err(format!(
            "calibrated_sensor {}: camera_intrinsic is not a 3×3 matrix",
            cal.token
        ));
    }
    let first = &scene.records[name][0];
    // sample_data carries the image size; read the header only when it does not.
    let (width, height) = if first.width > 0 && first.height > 0 {
        (first.width, first.height)
    } else {
        let src = opts.root.join(&first.filename);
        header_dims(&src, &read_file(&src, "the camera image")?)?
    };
    Ok(Camera {
        name: name.to_string(),
        width,
        height,
        fx: k[0][0],
        fy: k[1][1],
        cx: k[0][2],
        cy: k[1][2],
        camera_to_vehicle: transform(cal.rotation, cal.translation)
            .map_err(|m| format!("calibrated_sensor {}: {m}", cal.token))?,
        mask: None,
    })
}

fn nearest(recs: &[SampleData], t: i64) -> Option<&SampleData> {
    recs.iter()
        .map(|d| ((d.timestamp - t).abs(), d))
        .filter(|(dt, _)| *dt <= MATCH_US)
        .min_by_key(|(dt, _)| *dt)
        .map(|(_, d)| d)
}

/// Writes the LiDAR sweep of the frame anchored at `anchor` (pose `pose`): the same
/// sample's keyframe sweep, or for a camera sweep the nearest LiDAR sweep in time.
fn write_sweep(
    out: &mut Output,
    opts: &NuScenesOptions,
    scene: &SceneData,
    anchor: &SampleData,
    pose: &Mat4Rows,
    lidar_to_vehicle: &Mat4Rows,
) -> Result<Option<String>, String> {
    let rec = if anchor.is_key_frame {
        scene.partner(LIDAR, anchor, &HashSet::new())
    } else {
        nearest(&scene.records[LIDAR], anchor.timestamp)
    };
    let Some(rec) = rec else { return Ok(None) };
    let src = opts.root.join(&rec.filename);
    let bytes = read_file(&src, "the LiDAR sweep").map_err(|e| format!("{e}; {LAYOUT}"))?;
    if bytes.len() % 20 != 0 {
        return Err(format!(
            "{}: {} bytes is not a multiple of 20 (5 float32 per point: x, y, z, \
             intensity, ring)",
            src.display(),
            bytes.len()
        ));
    }
    let motion = if rec.ego_pose_token == anchor.ego_pose_token {
        None
    } else {
        let ego_motion = mul(&inverse(pose), &scene.pose(rec)?);
        Some(mul(
            &mul(&inverse(lidar_to_vehicle), &ego_motion),
            lidar_to_vehicle,
        ))
    };
    let stem = file_name(&anchor.filename);
    let stem = stem.rsplit_once('.').map_or(stem, |(s, _)| s);
    let name = format!("lidar/{stem}.bin");
    out.add(&name, &convert_sweep(&bytes, motion.as_ref()))?;
    Ok(Some(name))
}

/// Copies one camera image (JPEG as it is) and writes its label.
fn write_view(
    out: &mut Output,
    opts: &NuScenesOptions,
    cam: &Camera,
    rec: &SampleData,
    labels: Option<&Path>,
    lut: &[u8; 256],
) -> Result<View, String> {
    let src = opts.root.join(&rec.filename);
    let bytes = read_file(&src, "the camera image").map_err(|e| format!("{e}; {LAYOUT}"))?;
    let dims = header_dims(&src, &bytes)?;
    if dims != (cam.width, cam.height) {
        return Err(format!(
            "{}: {}×{}, but sample_data.json says {}×{} for {}",
            src.display(),
            dims.0,
            dims.1,
            cam.width,
            cam.height,
            cam.name
        ));
    }
    let name = file_name(&rec.filename);
    let image = format!("images/{}/{name}", cam.name);
    out.add(&image, &bytes)?;
    // Without labels: a drive without masks (docs/BUNDLE.md).
    let label = match labels {
        Some(dir) => {
            let path = find_label(dir, &cam.name, &rec.filename)?;
            let stem = Path::new(name)
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or(name);
            let label = format!("labels/{}/{stem}.png", cam.name);
            out.add(&label, &remap_label(&path, dims, lut)?)?;
            Some(label)
        }
        None => None,
    };
    Ok(View {
        camera: cam.name.clone(),
        image,
        label,
        vehicle_to_world: None,
    })
}
