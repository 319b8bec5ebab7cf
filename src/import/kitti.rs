//! KITTI odometry (development-kit layout) → scene bundle.
//!
//! KITTI poses are camera-0 poses in a world that is camera 0 at frame 0 (x right,
//! y down, z forward). The bundle wants a z-up world and a vehicle frame on the road
//! (x forward, y left, z up), so we put a vehicle frame on the ground under camera 0,
//! `camera_height` below it, and take the vehicle frame of the first imported frame
//! as the world. Images are copied byte for byte (KITTI's PNGs are already what a
//! bundle holds), so importing is I/O bound.

use super::{
    check_label, header_dims, inverse, known_ids, mul, read_classes, read_file, resolve, rigid,
    ImportError, Imported, Output, ProgressFn, NO_LABELS_WARNING,
};
use crate::bundle::{
    Camera, Frame, LidarSensor, Manifest, Mat4Rows, SemanticClass, View, FORMAT, VERSION,
};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// KITTI's camera height above the road (setup description of the recording car).
pub const DEFAULT_CAMERA_HEIGHT_M: f64 = 1.65;

/// KITTI records at 10 Hz; used when `times.txt` is absent.
pub const FRAME_PERIOD_S: f64 = 0.1;

/// Camera axes (x right, y down, z forward) into vehicle axes (x forward, y left,
/// z up): vehicle x = camera z, vehicle y = −camera x, vehicle z = −camera y.
pub const CAMERA_TO_VEHICLE_ROTATION: [[f64; 3]; 3] =
    [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]];

const LAYOUT: &str = concat!(
    "expected the KITTI odometry development-kit layout:\n",
    "  ROOT/poses/NN.txt                      (12 numbers per line: 3×4 camera-0-to-world)\n",
    "  ROOT/sequences/NN/calib.txt            (lines P0: … P3: and optionally Tr:)\n",
    "  ROOT/sequences/NN/image_0/000000.png … (image_2 for --camera 2)\n",
    "  ROOT/sequences/NN/times.txt            (optional, one time in seconds per frame)\n",
    "  ROOT/sequences/NN/velodyne/000000.bin  (optional, for --velodyne)"
);

/// Where the class table comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum Classes {
    /// The TwinLiteNet road/lane masks of the shared KITTI sample.
    TwinLiteNet,
    /// A JSON array of bundle `SemanticClass` objects.
    File(PathBuf),
}

impl std::str::FromStr for Classes {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Ok(if s == "twinlitenet" {
            Classes::TwinLiteNet
        } else {
            Classes::File(s.into())
        })
    }
}

/// TwinLiteNet masks: 0 = other, 1 = drivable road, 2 = lane marking.
pub use crate::segment::twinlitenet_classes;

#[derive(Clone, Debug)]
pub struct KittiOptions {
    /// The dataset root holding `poses/` and `sequences/`.
    pub root: PathBuf,
    /// Sequence number as in the folder name, e.g. "00".
    pub sequence: String,
    pub out: PathBuf,
    /// 0 (left grey) or 2 (left colour).
    pub camera: u8,
    /// Frame indices (rows of the pose file) to import; all when `None`.
    pub frames: Option<Range<usize>>,
    /// Folder with one 8-bit label PNG per frame, named like the image.
    pub labels: Option<PathBuf>,
    pub classes: Option<Classes>,
    pub velodyne: bool,
    pub camera_height: f64,
}

impl KittiOptions {
    pub fn new(root: impl Into<PathBuf>, sequence: &str, out: impl Into<PathBuf>) -> Self {
        Self {
            root: root.into(),
            sequence: sequence.into(),
            out: out.into(),
            camera: 0,
            frames: None,
            labels: None,
            classes: None,
            velodyne: false,
            camera_height: DEFAULT_CAMERA_HEIGHT_M,
        }
    }
}

/// A 3×4 row-major matrix as KITTI writes them.
pub type Mat34 = [[f64; 4]; 3];

/// The projection matrices `P0`..`P3` and the velodyne-to-camera-0 `Tr` of calib.txt.
#[derive(Clone, Debug, Default)]
pub struct Calib {
    pub p: [Option<Mat34>; 4],
    pub tr: Option<Mat34>,
}

fn mat34(values: &[f64]) -> Mat34 {
    [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| values[4 * r + c]))
}

fn numbers(line: &str, path: &Path, lineno: usize) -> Result<Vec<f64>, String> {
    line.split_whitespace()
        .map(|w| {
            w.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| format!("{}:{lineno}: {w:?} is not a finite number", path.display()))
        })
        .collect()
}

pub fn parse_calib(text: &str, path: &Path) -> Result<Calib, String> {
    let mut calib = Calib::default();
    for (i, line) in text.lines().enumerate() {
        let Some((key, rest)) = line.split_once(':') else {
            continue;
        };
        let slot = match key.trim() {
            "P0" => &mut calib.p[0],
            "P1" => &mut calib.p[1],
            "P2" => &mut calib.p[2],
            "P3" => &mut calib.p[3],
            "Tr" => &mut calib.tr,
            _ => continue,
        };
        let v = numbers(rest, path, i + 1)?;
        if v.len() != 12 {
            return Err(format!(
                "{}:{}: {} has {} numbers, expected 12 (a row-major 3×4 matrix)",
                path.display(),
                i + 1,
                key.trim(),
                v.len()
            ));
        }
        *slot = Some(mat34(&v));
    }
    Ok(calib)
}

/// One 4×4 camera-0-to-world pose per non-empty line.
pub fn parse_poses(text: &str, path: &Path) -> Result<Vec<Mat4Rows>, String> {
    let mut poses = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v = numbers(line, path, i + 1)?;
        if v.len() != 12 {
            return Err(format!(
                "{}:{}: {} numbers, expected 12 (a row-major 3×4 camera-0-to-world matrix)",
                path.display(),
                i + 1,
                v.len()
            ));
        }
        poses.push(to4(&mat34(&v)));
    }
    Ok(poses)
}

fn to4(m: &Mat34) -> Mat4Rows {
    [m[0], m[1], m[2], [0.0, 0.0, 0.0, 1.0]]
}

/// Camera 0 into the vehicle frame on the road below it.
pub fn camera0_to_vehicle(camera_height: f64) -> Mat4Rows {
    rigid(CAMERA_TO_VEHICLE_ROTATION, [0.0, 0.0, camera_height])
}

/// A rectified camera `P = K·[I | t]` into the vehicle frame. `t = K⁻¹·P[:,3]` is
/// where camera 0's origin lies in this camera's axes (for camera 2 mostly along x:
/// `P2[0][3]/fx`), so this camera sits at `−t` in camera 0's frame.
pub fn camera_to_vehicle(p: &Mat34, camera_height: f64) -> Mat4Rows {
    let (fx, fy, cx, cy) = intrinsics(p);
    let tz = p[2][3];
    let ty = (p[1][3] - cy * tz) / fy;
    let tx = (p[0][3] - cx * tz) / fx;
    let to_cam0 = rigid(
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [-tx, -ty, -tz],
    );
    mul(&camera0_to_vehicle(camera_height), &to_cam0)
}

/// `(fx, fy, cx, cy)` of a rectified projection matrix.
pub fn intrinsics(p: &Mat34) -> (f64, f64, f64, f64) {
    (p[0][0], p[1][1], p[0][2], p[1][2])
}

/// KITTI camera-0 poses → bundle vehicle-to-world, with the world being the vehicle
/// frame of `poses[0]`: `C · P₀⁻¹ · Pᵢ · C⁻¹`, `C` = camera 0 to vehicle.
pub fn vehicle_poses(poses: &[Mat4Rows], camera_height: f64) -> Vec<Mat4Rows> {
    let c = camera0_to_vehicle(camera_height);
    let c_inv = inverse(&c);
    let Some(first) = poses.first() else {
        return Vec::new();
    };
    let world = mul(&c, &inverse(first));
    poses.iter().map(|p| mul(&mul(&world, p), &c_inv)).collect()
}

fn timestamps(seq: &Path, n: usize) -> Result<Vec<f64>, String> {
    let path = seq.join("times.txt");
    if !path.exists() {
        return Ok((0..n).map(|i| i as f64 * FRAME_PERIOD_S).collect());
    }
    let text = read_text(&path, "the frame times")?;
    let mut times = Vec::new();
    for (i, line) in text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
    {
        let v = numbers(line, &path, i + 1)?;
        times.push(*v.first().unwrap_or(&0.0));
    }
    if times.len() < n {
        return Err(format!(
            "{}: {} times for {n} poses; expected one line per frame (or delete the file \
             to use 0.1 s per frame)",
            path.display(),
            times.len()
        ));
    }
    Ok(times)
}

/// Imports a KITTI odometry sequence into a validated bundle at `opts.out`.
pub fn import(opts: &KittiOptions, progress: ProgressFn) -> Result<Imported, ImportError> {
    let root = &opts.root;
    let seq = root.join("sequences").join(&opts.sequence);
    if opts.camera != 0 && opts.camera != 2 {
        return Err(format!(
            "--camera {}: only 0 (left grey) and 2 (left colour) are supported",
            opts.camera
        )
        .into());
    }
    if !(opts.camera_height.is_finite() && opts.camera_height > 0.0) {
        return Err(format!(
            "--camera-height {}: expected the camera's height above the road in metres (KITTI: 1.65)",
            opts.camera_height
        )
        .into());
    }
    let calib_path = seq.join("calib.txt");
    if !calib_path.is_file() {
        return Err(format!("{} not found; {LAYOUT}", calib_path.display()).into());
    }
    let calib = parse_calib(&read_text(&calib_path, "the calibration")?, &calib_path)?;
    let cam = opts.camera as usize;
    let p = calib.p[cam].ok_or_else(|| {
        format!(
            "{}: no P{cam}: line; camera {cam} needs its 3×4 projection matrix",
            calib_path.display()
        )
    })?;
    let (fx, fy, cx, cy) = intrinsics(&p);
    let pose_path = root.join("poses").join(format!("{}.txt", opts.sequence));
    if !pose_path.is_file() {
        return Err(format!(
            "{} not found (KITTI publishes poses for sequences 00-10 only, in \
             data_odometry_poses); {LAYOUT}",
            pose_path.display()
        )
        .into());
    }
    let all_poses = parse_poses(&read_text(&pose_path, "the poses")?, &pose_path)?;
    let range = select(opts.frames.clone(), all_poses.len(), &pose_path)?;
    let times = timestamps(&seq, all_poses.len())?;
    let vehicle_to_world = vehicle_poses(&all_poses[range.clone()], opts.camera_height);

    let mut warnings = Vec::new();
    let (classes, labels_dir) = class_table(opts, &mut warnings)?;
    let known = known_ids(&classes);

    let lidar = if opts.velodyne {
        let tr = calib.tr.ok_or_else(|| {
            format!(
                "{}: --velodyne needs the Tr: line (velodyne to camera 0); KITTI ships it \
                 in data_odometry_calib",
                calib_path.display()
            )
        })?;
        Some(LidarSensor {
            floats_per_point: 4,
            lidar_to_vehicle: mul(&camera0_to_vehicle(opts.camera_height), &to4(&tr)),
        })
    } else {
        None
    };

    let cam_name = format!("cam{cam}");
    let image_dir = seq.join(format!("image_{cam}"));
    if !image_dir.is_dir() {
        return Err(format!("{} not found; {LAYOUT}", image_dir.display()).into());
    }
    let mut out = Output::create(&opts.out)?;
    let mut size = None;
    let mut frames = Vec::with_capacity(range.len());
    for (k, i) in range.clone().enumerate() {
        let file = format!("{i:06}.png");
        let src = image_dir.join(&file);
        let bytes = read_file(&src, "the image")?;
        let dims = header_dims(&src, &bytes)?;
        let size = *size.get_or_insert(dims);
        if dims != size {
            return Err(format!(
                "{}: {}×{}, but the sequence's first image is {}×{}; all images of a \
                 camera must have one size",
                src.display(),
                dims.0,
                dims.1,
                size.0,
                size.1
            )
            .into());
        }
        let image = format!("images/{cam_name}/{file}");
        out.add(&image, &bytes)?;
        let label = match &labels_dir {
            Some(dir) => {
                let src = dir.join(&file);
                let bytes = read_file(&src, "the label")?;
                check_label(&src, &bytes, size, &known)?;
                let label = format!("labels/{cam_name}/{file}");
                out.add(&label, &bytes)?;
                Some(label)
            }
            // A drive without masks (docs/BUNDLE.md).
            None => None,
        };
        let lidar_path = if opts.velodyne {
            let src = seq.join("velodyne").join(format!("{i:06}.bin"));
            let bytes = read_file(&src, "the velodyne scan")?;
            if bytes.len() % 16 != 0 {
                return Err(format!(
                    "{}: {} bytes is not a multiple of 16 (4 float32 per point: x, y, z, \
                     reflectance)",
                    src.display(),
                    bytes.len()
                )
                .into());
            }
            let name = format!("lidar/{i:06}.bin");
            out.add(&name, &bytes)?;
            Some(name)
        } else {
            None
        };
        frames.push(Frame {
            timestamp: times[i],
            vehicle_to_world: vehicle_to_world[k],
            views: vec![View {
                camera: cam_name.clone(),
                image,
                label,
                vehicle_to_world: None,
            }],
            lidar: lidar_path,
        });
        progress("importing", k + 1, range.len());
    }
    let (width, height) = size.unwrap_or((0, 0));
    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        name: format!(
            "KITTI odometry sequence {}, camera {cam}, frames {}..{}",
            opts.sequence, range.start, range.end
        ),
        vehicle_height_m: 0.0,
        semantic_classes: classes,
        cameras: vec![Camera {
            name: cam_name,
            width,
            height,
            fx,
            fy,
            cx,
            cy,
            camera_to_vehicle: camera_to_vehicle(&p, opts.camera_height),
            mask: None,
        }],
        frames,
        lidar,
        ground_truth: None,
        world_frame: Some(crate::bundle::WorldFrame {
            name: format!(
                "KITTI odometry sequence {} (the frame of its poses file, turned z up)",
                opts.sequence
            ),
            offset_m: [0.0; 3],
        }),
        corridor_half_width_m: Some(4.0),
    };
    out.finish(manifest, warnings, progress)
}

/// The class table and label folder from `--labels`/`--classes`, or none (a drive
/// without masks, with its warning) when neither is given.
fn class_table(
    opts: &KittiOptions,
    warnings: &mut Vec<String>,
) -> Result<(Vec<SemanticClass>, Option<PathBuf>), String> {
    let root = &opts.root;
    match (&opts.labels, &opts.classes) {
        (Some(dir), Some(c)) => {
            let classes = match c {
                Classes::TwinLiteNet => twinlitenet_classes(),
                Classes::File(f) => read_classes(&resolve(root, f))?,
            };
            let dir = resolve(root, dir);
            if !dir.is_dir() {
                return Err(format!(
                    "{}: label folder not found; expected one 8-bit PNG of class ids per \
                     frame, named like the images (000000.png …)",
                    dir.display()
                ));
            }
            Ok((classes, Some(dir)))
        }
        (Some(_), None) => {
            Err("--labels needs --classes: a JSON class table or the preset 'twinlitenet'".into())
        }
        (None, Some(_)) => Err("--classes needs --labels (the folder of label PNGs)".into()),
        (None, None) => {
            warnings.push(NO_LABELS_WARNING.to_string());
            Ok((Vec::new(), None))
        }
    }
}

fn read_text(path: &Path, what: &str) -> Result<String, String> {
    String::from_utf8(read_file(path, what)?)
        .map_err(|_| format!("{}: {what} is not UTF-8 text", path.display()))
}

/// The requested frame range clipped to the poses, refusing fewer than two frames.
fn select(frames: Option<Range<usize>>, n: usize, poses: &Path) -> Result<Range<usize>, String> {
    let asked = frames.unwrap_or(0..n);
    let r = asked.start..asked.end.min(n);
    if r.len() < 2 {
        return Err(format!(
            "--frames {}..{}: selects {} of the {n} frames in {}; a bundle needs at least 2",
            asked.start,
            asked.end,
            r.len(),
            poses.display()
        ));
    }
    Ok(r)
}
