//! Scene bundle v1: the manifest types (`manifest.json` at the bundle root).
//!
//! Everything here is plain serde data. Semantic checks live in `validate.rs`, so
//! that parsing never fails on a value that is merely wrong: the validator reports
//! every problem at once, each with the field path it came from.

use serde::{Deserialize, Serialize};

/// The `format` string every bundle carries.
pub const FORMAT: &str = "rogs-bundle";
/// The manifest version this build reads and writes.
pub const VERSION: u32 = 1;

/// A row-major 4×4 rigid transform, `[[r00,r01,r02,tx],[..],[..],[0,0,0,1]]`.
pub type Mat4Rows = [[f64; 4]; 4];

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    /// Free text shown in summaries.
    #[serde(default)]
    pub name: String,
    /// Height of the vehicle frame's origin above the road surface, in metres
    /// (0 when the vehicle frame sits on the ground, as nuScenes' ego frame does).
    #[serde(default)]
    pub vehicle_height_m: f64,
    /// The classes of the label images. May be empty when no view has a label (a
    /// drive without masks); then it only describes the truth's `class_ids`.
    #[serde(default)]
    pub semantic_classes: Vec<SemanticClass>,
    pub cameras: Vec<Camera>,
    pub frames: Vec<Frame>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar: Option<LidarSensor>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ground_truth: Option<GroundTruth>,
    /// The frame the poses are in, when it is a dataset's own (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub world_frame: Option<WorldFrame>,
    /// The corridor half-width a map of this drive uses when none is asked for
    /// (metres): importers set their dataset's (nuScenes 8, KITTI 4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corridor_half_width_m: Option<f64>,
}

/// A bundle's world frame in a dataset's terms: a point at bundle coordinates `p` is
/// at `p + offset_m` in the frame called `name` (e.g. the nuScenes map of one
/// location), so that a map lines up with the dataset's own maps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorldFrame {
    pub name: String,
    pub offset_m: [f64; 3],
}

/// What a class means to the optimiser.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ClassRole {
    /// Part of the road surface: reconstructed and supervised.
    Road,
    /// Excluded from every loss (cars, people, sky, …).
    Ignore,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SemanticClass {
    /// The pixel value in label images.
    pub id: u8,
    pub name: String,
    /// Display colour, sRGB.
    pub color: [u8; 3],
    pub role: ClassRole,
}

impl SemanticClass {
    pub fn new(id: u8, name: &str, color: [u8; 3], role: ClassRole) -> Self {
        Self {
            id,
            name: name.into(),
            color,
            role,
        }
    }
}

/// The label value of the supervised road plane in a drive without labels (0 is
/// outside it: above the horizon, beyond `SURFACE_RANGE_M`, the vehicle's body).
pub const SURFACE_ID: u8 = 1;

/// The one class of a map trained without labels.
pub fn surface_class() -> SemanticClass {
    SemanticClass {
        id: SURFACE_ID,
        name: "surface".into(),
        color: [128, 128, 128],
        role: ClassRole::Road,
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Camera-to-vehicle transform. Camera axes: x right, y down, z forward.
    pub camera_to_vehicle: Mat4Rows,
    /// Optional 8-bit PNG of the camera's size, non-zero where the vehicle's own body
    /// (bonnet, mirrors) covers the image: never supervised. Used by drives without
    /// labels; with labels, label the body with an ignore class instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Seconds, increasing.
    pub timestamp: f64,
    /// Vehicle-to-world transform (world z up; vehicle x forward, y left, z up).
    pub vehicle_to_world: Mat4Rows,
    /// One entry per camera that has an image in this frame.
    pub views: Vec<View>,
    /// Path of this frame's LiDAR sweep (needs the top-level `lidar` sensor).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar: Option<String>,
}

impl Frame {
    /// The vehicle pose a view's camera is placed with: its own, else the frame's.
    pub fn view_pose<'a>(&'a self, v: &'a View) -> &'a Mat4Rows {
        v.vehicle_to_world
            .as_ref()
            .unwrap_or(&self.vehicle_to_world)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct View {
    /// Name of a camera in `cameras`.
    pub camera: String,
    /// RGB image (PNG or JPEG), `width × height` of its camera, undistorted.
    pub image: String,
    /// 8-bit PNG of class ids, same size as the image. Absent in a drive without
    /// masks (then no view has one): the road plane below the horizon is supervised
    /// instead and the map has no semantic layer (docs/BUNDLE.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub label: Option<String>,
    /// This view's own vehicle-to-world pose, when its camera fired at another time
    /// than the frame's pose was taken (nuScenes cameras fire along the LiDAR sweep,
    /// up to ~50 ms apart). Absent: the frame's `vehicle_to_world`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vehicle_to_world: Option<Mat4Rows>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LidarSensor {
    /// Float32 values per point: 3 (x, y, z) or 4 (x, y, z, intensity).
    pub floats_per_point: u32,
    /// LiDAR-to-vehicle transform.
    pub lidar_to_vehicle: Mat4Rows,
}

/// Bird's-eye-view truth rasters. Row 0 is the north edge (largest y), column 0 the
/// west edge (smallest x): pixel (col, row) has its centre at
/// `x = origin[0] + (col + 0.5)·resolution`, `y = origin[1] − (row + 0.5)·resolution`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundTruth {
    /// World x of the raster's west edge, world y of its north edge (metres).
    pub origin: [f64; 2],
    /// Metres per pixel.
    pub resolution: f64,
    pub width: u32,
    pub height: u32,
    /// RGB PNG.
    pub rgb: String,
    /// 8-bit PNG of class ids.
    pub class_ids: String,
    /// Raw little-endian float32 elevation, `width × height` values, row-major.
    pub elevation: String,
    /// 8-bit PNG, non-zero where the truth is valid.
    pub valid: String,
    /// Optional JSON file: every frame's exact `vehicle_to_world` (an array of
    /// row-major 4×4 matrices, one per frame in order), for scoring pose refinement.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub poses: Option<String>,
}

impl Manifest {
    /// Every frame's `vehicle_to_world`, in order.
    pub fn vehicle_poses(&self) -> Vec<Mat4Rows> {
        self.frames.iter().map(|f| f.vehicle_to_world).collect()
    }

    /// The offset from the bundle's world to its dataset frame (zero without one).
    pub fn frame_offset(&self) -> [f64; 3] {
        self.world_frame.as_ref().map_or([0.0; 3], |f| f.offset_m)
    }

    /// The world frame in words, for file headers: the dataset frame and offset, or
    /// the bundle's own local frame.
    pub fn frame_description(&self) -> String {
        match &self.world_frame {
            Some(f) => format!(
                "{}; bundle world = {} minus [{:.3}, {:.3}, {:.3}] m",
                f.name, f.name, f.offset_m[0], f.offset_m[1], f.offset_m[2]
            ),
            None => format!("the local world frame of {:?}", self.name),
        }
    }

    /// Every file path the manifest references, with the field it came from.
    pub fn referenced_files(&self) -> Vec<(String, &str)> {
        let mut out = Vec::new();
        for (fi, f) in self.frames.iter().enumerate() {
            for (vi, v) in f.views.iter().enumerate() {
                out.push((format!("frames[{fi}].views[{vi}].image"), v.image.as_str()));
                if let Some(l) = &v.label {
                    out.push((format!("frames[{fi}].views[{vi}].label"), l.as_str()));
                }
            }
            if let Some(l) = &f.lidar {
                out.push((format!("frames[{fi}].lidar"), l.as_str()));
            }
        }
        for (ci, c) in self.cameras.iter().enumerate() {
            if let Some(mask) = &c.mask {
                out.push((format!("cameras[{ci}].mask"), mask.as_str()));
            }
        }
        if let Some(gt) = &self.ground_truth {
            out.push(("ground_truth.rgb".into(), gt.rgb.as_str()));
            out.push(("ground_truth.class_ids".into(), gt.class_ids.as_str()));
            out.push(("ground_truth.elevation".into(), gt.elevation.as_str()));
            out.push(("ground_truth.valid".into(), gt.valid.as_str()));
        }
        out
    }

    /// Whether the views carry label images (all of them do, or none).
    pub fn labelled(&self) -> bool {
        self.frames
            .iter()
            .flat_map(|f| &f.views)
            .any(|v| v.label.is_some())
    }

    /// The classes the map is trained with: the label images' table, or for a drive
    /// without labels the one class `SURFACE` (the road plane below the horizon).
    pub fn classes(&self) -> std::borrow::Cow<'_, [SemanticClass]> {
        if self.labelled() {
            std::borrow::Cow::Borrowed(&self.semantic_classes)
        } else {
            std::borrow::Cow::Owned(vec![surface_class()])
        }
    }

    pub fn camera(&self, name: &str) -> Option<&Camera> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// Length of the vehicle path projected on the xy-plane, in metres.
    pub fn trajectory_length_m(&self) -> f64 {
        self.frames
            .windows(2)
            .map(|w| {
                let a = &w[0].vehicle_to_world;
                let b = &w[1].vehicle_to_world;
                (b[0][3] - a[0][3]).hypot(b[1][3] - a[1][3])
            })
            .sum()
    }
}
