//! Full validation of a bundle before any work starts. It collects every problem
//! instead of stopping at the first, so one run tells the author all that is wrong.

use super::error::Problem;
use super::manifest::{Camera, Manifest, Mat4Rows, FORMAT, VERSION};
use super::source::{is_safe_path, Limits, Source};
use std::collections::HashSet;

/// Farthest a vehicle may be from the world origin, metres (a quarter of the way
/// round the Earth; a world frame is local, docs/BUNDLE.md).
pub const MAX_WORLD_M: f64 = 1e7;
const WORLD_ADVICE: &str = "Positions are metres in a local world frame: subtract a nearby origin \
    (and record it in world_frame.offset_m).";
/// Farthest a sensor may be mounted from the vehicle's origin, metres.
pub const MAX_MOUNT_M: f64 = 100.0;
const MOUNT_ADVICE: &str = "Mounts are metres in the vehicle frame (check the units).";

/// Largest tolerated deviation of RᵀR from the identity.
pub const ROTATION_TOLERANCE: f64 = 1e-3;
/// The vehicle frame's origin above the road, metres: a frame under the road or on a
/// mast is a unit or sign mistake.
pub const MIN_VEHICLE_HEIGHT_M: f64 = -2.0;
pub const MAX_VEHICLE_HEIGHT_M: f64 = 10.0;
/// A bundle's own corridor half-width, metres: from a lane to a wide square.
pub const MIN_CORRIDOR_M: f64 = 0.5;
pub const MAX_CORRIDOR_M: f64 = 100.0;

/// Checks the manifest against the files in `source`: every problem found, and when
/// there is none, advice on a legal bundle that cannot make a useful map (a vehicle
/// that does not move, labels with no road, a camera that never sees it: warnings,
/// not problems). `progress(done, total)` is called as files are checked (image
/// decoding dominates the time).
pub fn validate(
    m: &Manifest,
    source: &dyn Source,
    limits: &Limits,
    progress: &mut dyn FnMut(usize, usize),
) -> (Vec<Problem>, Vec<String>) {
    let mut v = Validator::new(source, limits, true);
    v.manifest_fields(m);
    v.files(m, progress);
    let advice = if v.problems.is_empty() {
        advice(m, &v.road_pixels)
    } else {
        Vec::new()
    };
    (v.problems, advice)
}

/// Travel below which a drive is taken for a vehicle standing still, metres.
pub const STILL_M: f64 = 0.5;

/// Warnings for a legal bundle that makes a poor map; `road`: per camera, label
/// pixels of road classes and all label pixels (empty when labels were not read).
fn advice(m: &Manifest, road: &std::collections::BTreeMap<String, (u64, u64)>) -> Vec<String> {
    let mut out = Vec::new();
    let travel = m.trajectory_length_m();
    if m.frames.len() > 1 && travel < STILL_M {
        out.push(format!(
            "the vehicle moves {travel:.2} m over {} frames: every view is taken from one place, \
             so the map covers only the ground those views see at a grazing angle; \
             map a drive that moves (or check that the poses are not all the same)",
            m.frames.len()
        ));
    }
    let (all_road, all) = road.values().fold((0, 0), |(a, b), &(r, t)| (a + r, b + t));
    let road_classes: Vec<&str> = m
        .semantic_classes
        .iter()
        .filter(|c| c.role == super::manifest::ClassRole::Road)
        .map(|c| c.name.as_str())
        .collect();
    if all > 0 && all_road == 0 {
        out.push(format!(
            "no label pixel is of a road class ({}): nothing is supervised and the map \
             will be empty; check the labels' values against semantic_classes and their roles",
            road_classes.join(", ")
        ));
    } else if all_road > 0 {
        for (camera, &(r, t)) in road {
            if t > 0 && r == 0 {
                out.push(format!(
                    "camera {camera} never sees the road in its labels (0 of {t} pixels are of a \
                     road class): its views only cost time; leave them out, or check its \
                     labels and its mount"
                ));
            }
        }
    }
    out
}

/// Every check of `validate` but those that read a file's content (images, labels):
/// the manifest, every referenced file present, sizes. A bundle opened lazily is
/// checked so at once, and each view's files by `validate_views` when they are read.
pub fn validate_structure(m: &Manifest, source: &dyn Source, limits: &Limits) -> Vec<Problem> {
    let mut v = Validator::new(source, limits, false);
    v.manifest_fields(m);
    v.files(m, &mut |_, _| {});
    v.problems
}

/// The content checks of `validate` for the given views (frame, view) only, and the
/// truth's images when `truth`: the image's size, the label's size, format and
/// class ids; of those files, the ones `only` accepts.
pub fn validate_views(
    m: &Manifest,
    source: &dyn Source,
    limits: &Limits,
    views: &[(usize, usize)],
    truth: bool,
    only: &dyn Fn(&str) -> bool,
) -> Vec<Problem> {
    let mut v = Validator::new(source, limits, true);
    v.classes(m);
    v.problems.clear();
    if let (Some(gt), true) = (&m.ground_truth, truth) {
        let present = [&gt.rgb, &gt.valid, &gt.class_ids]
            .into_iter()
            .map(|p| p.as_str())
            .collect();
        v.truth_images(gt, &present);
    }
    for &(f, k) in views {
        let Some(view) = m.frames.get(f).and_then(|fr| fr.views.get(k)) else {
            continue;
        };
        if let Some(cam) = m.camera(&view.camera) {
            if only(&view.image) {
                v.image_size(&view.image, &cam.name, cam.width, cam.height);
            }
            if let Some(label) = view.label.as_deref().filter(|l| only(l)) {
                v.label(label, &cam.name, cam.width, cam.height);
            }
            if let Some(mask) = cam.mask.as_deref().filter(|p| only(p)) {
                v.gray_of_size(mask, &cam.name, cam.width, cam.height);
            }
        }
    }
    v.problems
}

struct Validator<'a> {
    source: &'a dyn Source,
    limits: Limits,
    problems: Vec<Problem>,
    class_ids: [bool; 256],
    /// Classes of the road role (by id).
    road_ids: [bool; 256],
    /// Per camera: label pixels of road classes, all label pixels (what was read).
    road_pixels: std::collections::BTreeMap<String, (u64, u64)>,
    /// Whether images and labels are read (false: presence and sizes only).
    content: bool,
}

impl<'a> Validator<'a> {
    fn new(source: &'a dyn Source, limits: &'a Limits, content: bool) -> Self {
        Self {
            source,
            limits: *limits,
            problems: Vec::new(),
            class_ids: [false; 256],
            road_ids: [false; 256],
            road_pixels: Default::default(),
            content,
        }
    }

    fn invalid(&mut self, field: impl Into<String>, what: impl Into<String>) {
        self.problems.push(Problem::Invalid {
            field: field.into(),
            what: what.into(),
        });
    }

    fn manifest_fields(&mut self, m: &Manifest) {
        if m.format != FORMAT {
            self.problems.push(Problem::Format {
                found: m.format.clone(),
            });
        }
        if m.version != VERSION {
            self.problems.push(Problem::Version {
                found: m.version,
                supported: VERSION,
            });
        }
        if !m.vehicle_height_m.is_finite() {
            self.problems.push(Problem::NonFinite {
                field: "vehicle_height_m".into(),
            });
        } else if !(MIN_VEHICLE_HEIGHT_M..=MAX_VEHICLE_HEIGHT_M).contains(&m.vehicle_height_m) {
            self.invalid(
                "vehicle_height_m",
                format!(
                    "{} m; expected {MIN_VEHICLE_HEIGHT_M} to {MAX_VEHICLE_HEIGHT_M} m: the height of the \
                     vehicle frame's origin above the road (0 for an origin on the ground, about \
                     1.7 for a roof LiDAR's frame)",
                    m.vehicle_height_m
                ),
            );
        }
        if let Some(hw) = m.corridor_half_width_m {
            if !(hw.is_finite() && (MIN_CORRIDOR_M..=MAX_CORRIDOR_M).contains(&hw)) {
                self.invalid(
                    "corridor_half_width_m",
                    format!(
                        "{hw} m; expected {MIN_CORRIDOR_M} to {MAX_CORRIDOR_M} m: how far either side of \
                         the trajectory the map reaches (4 for one carriageway, 8 for a street \
                         with its sidewalks)"
                    ),
                );
            }
        }
        self.classes(m);
        if m.labelled() {
            let missing: Vec<String> = m
                .frames
                .iter()
                .enumerate()
                .flat_map(|(fi, f)| f.views.iter().enumerate().map(move |(vi, v)| (fi, vi, v)))
                .filter(|(_, _, v)| v.label.is_none())
                .map(|(fi, vi, _)| format!("frames[{fi}].views[{vi}].label"))
                .collect();
            if let Some(first) = missing.first() {
                self.invalid(
                    first.clone(),
                    format!(
                        "missing ({} views have no label) while other views have one; give \
                         every view a label, or none for a drive without masks (rogs segment \
                         can label a drive)",
                        missing.len()
                    ),
                );
            }
        }
        let mut names = HashSet::new();
        if m.cameras.is_empty() {
            self.invalid("cameras", "no camera; expected at least one");
        }
        for (i, c) in m.cameras.iter().enumerate() {
            if !names.insert(c.name.as_str()) {
                self.invalid(
                    format!("cameras[{i}].name"),
                    format!("duplicate camera name {:?}", c.name),
                );
            }
            self.camera(i, c);
        }
        if let Some(l) = &m.lidar {
            if !(3..=16).contains(&l.floats_per_point) {
                self.invalid(
                    "lidar.floats_per_point",
                    format!(
                        "{} is not supported; expected 3 (x,y,z) or 4 (x,y,z,intensity)",
                        l.floats_per_point
                    ),
                );
            }
            self.rigid("lidar.lidar_to_vehicle", &l.lidar_to_vehicle);
            self.within(
                "lidar.lidar_to_vehicle",
                &l.lidar_to_vehicle,
                MAX_MOUNT_M,
                MOUNT_ADVICE,
            );
        }
        if m.frames.len() < 2 {
            self.problems.push(Problem::TooFewFrames {
                found: m.frames.len(),
            });
        }
        let mut last_t = f64::NEG_INFINITY;
        for (fi, f) in m.frames.iter().enumerate() {
            if !f.timestamp.is_finite() {
                self.problems.push(Problem::NonFinite {
                    field: format!("frames[{fi}].timestamp"),
                });
            } else if f.timestamp < last_t {
                self.invalid(
                    format!("frames[{fi}].timestamp"),
                    "timestamps must not decrease from one frame to the next",
                );
            }
            last_t = f.timestamp;
            let pose = format!("frames[{fi}].vehicle_to_world");
            self.rigid(&pose, &f.vehicle_to_world);
            self.within(&pose, &f.vehicle_to_world, MAX_WORLD_M, WORLD_ADVICE);
            for (vi, v) in f.views.iter().enumerate() {
                if let Some(t) = &v.vehicle_to_world {
                    let field = format!("frames[{fi}].views[{vi}].vehicle_to_world");
                    self.rigid(&field, t);
                    self.within(&field, t, MAX_WORLD_M, WORLD_ADVICE);
                }
            }
            if f.views.is_empty() {
                self.invalid(
                    format!("frames[{fi}].views"),
                    "no view; expected at least one camera image per frame",
                );
            }
            let mut seen = HashSet::new();
            for (vi, view) in f.views.iter().enumerate() {
                if m.camera(&view.camera).is_none() {
                    self.invalid(
                        format!("frames[{fi}].views[{vi}].camera"),
                        format!(
                            "unknown camera {:?}; expected one of the names in cameras",
                            view.camera
                        ),
                    );
                }
                if !seen.insert(view.camera.as_str()) {
                    self.invalid(
                        format!("frames[{fi}].views[{vi}].camera"),
                        "camera listed twice in one frame",
                    );
                }
            }
            if f.lidar.is_some() && m.lidar.is_none() {
                self.invalid(
                    format!("frames[{fi}].lidar"),
                    "frame has a LiDAR file but the manifest has no top-level lidar sensor",
                );
            }
        }
        if let Some(gt) = &m.ground_truth {
            if !(gt.resolution.is_finite() && gt.resolution > 0.0) {
                self.invalid(
                    "ground_truth.resolution",
                    "expected a positive number of metres per pixel",
                );
            }
            if !gt.origin.iter().all(|v| v.is_finite()) {
                self.problems.push(Problem::NonFinite {
                    field: "ground_truth.origin".into(),
                });
            }
            self.dims("ground_truth", gt.width, gt.height);
        }
    }

    fn classes(&mut self, m: &Manifest) {
        let mut names = HashSet::new();
        // A drive without labels needs no class table (one may describe its truth).
        if m.semantic_classes.is_empty() && m.labelled() {
            self.invalid(
                "semantic_classes",
                "no class; expected at least one class with role \"road\"",
            );
        }
        for (i, c) in m.semantic_classes.iter().enumerate() {
            if self.class_ids[c.id as usize] {
                self.invalid(
                    format!("semantic_classes[{i}].id"),
                    format!("duplicate class id {}", c.id),
                );
            }
            self.class_ids[c.id as usize] = true;
            self.road_ids[c.id as usize] = c.role == super::ClassRole::Road;
            if !names.insert(c.name.as_str()) {
                self.invalid(
                    format!("semantic_classes[{i}].name"),
                    format!("duplicate class name {:?}", c.name),
                );
            }
        }
        if !m.semantic_classes.is_empty()
            && !m
                .semantic_classes
                .iter()
                .any(|c| c.role == super::ClassRole::Road)
        {
            self.invalid(
                "semantic_classes",
                "no class has role \"road\"; nothing would be reconstructed",
            );
        }
    }

    fn dims(&mut self, field: &str, w: u32, h: u32) {
        let side = if field == "ground_truth" {
            self.limits.for_truth().max_image_side
        } else {
            self.limits.max_image_side
        };
        self.dims_within(field, w, h, side);
    }

    fn dims_within(&mut self, field: &str, w: u32, h: u32, side: u32) {
        if w == 0 || h == 0 || w > side || h > side {
            self.invalid(
                format!("{field}.width/height"),
                format!("{w}×{h}; expected 1..={} pixels per side", side),
            );
        }
    }

    fn camera(&mut self, i: usize, c: &Camera) {
        let f = format!("cameras[{i}]");
        self.dims(&f, c.width, c.height);
        if ![c.fx, c.fy, c.cx, c.cy].iter().all(|v| v.is_finite()) {
            self.problems.push(Problem::NonFinite {
                field: format!("{f}.intrinsics"),
            });
        } else if c.fx <= 0.0 || c.fy <= 0.0 {
            self.invalid(
                format!("{f}.fx/fy"),
                "focal lengths must be positive pixels",
            );
        }
        let mount = format!("{f}.camera_to_vehicle");
        self.rigid(&mount, &c.camera_to_vehicle);
        self.within(&mount, &c.camera_to_vehicle, MAX_MOUNT_M, MOUNT_ADVICE);
        self.intrinsics(&f, c);
    }

    /// Focal lengths and principal point against the image: a field of view between
    /// about 1° and 170°, a principal point within a frame's width of the image.
    fn intrinsics(&mut self, f: &str, c: &Camera) {
        if ![c.fx, c.fy, c.cx, c.cy].iter().all(|v| v.is_finite()) || c.fx <= 0.0 || c.fy <= 0.0 {
            return;
        }
        let (w, h) = (c.width.max(1) as f64, c.height.max(1) as f64);
        for (name, focal, side) in [("fx", c.fx, w), ("fy", c.fy, h)] {
            if !(0.04 * side..=60.0 * side).contains(&focal) {
                self.invalid(
                    format!("{f}.{name}"),
                    format!(
                        "{focal} px for an image {side} px across is a field of view outside 1°–170°; \
                         expected {:.0}–{:.0} px (focal lengths are in pixels, not millimetres)",
                        0.04 * side,
                        60.0 * side
                    ),
                );
            }
        }
        for (name, v, side) in [("cx", c.cx, w), ("cy", c.cy, h)] {
            if !(-side..=2.0 * side).contains(&v) {
                self.invalid(
                    format!("{f}.{name}"),
                    format!(
                        "{v} px lies more than an image away from an image {side} px across; \
                         expected about {:.0} (the principal point is in pixels from the top-left)",
                        side / 2.0
                    ),
                );
            }
        }
    }

    /// A transform's translation within `limit` metres of the origin.
    fn within(&mut self, field: &str, t: &Mat4Rows, limit: f64, advice: &str) {
        let d = t[0][3].hypot(t[1][3]).hypot(t[2][3]);
        if d > limit {
            self.invalid(
                format!("{field} translation"),
                format!("{d:.3e} m from the origin; expected at most {limit:.0e} m. {advice}"),
            );
        }
    }

    fn rigid(&mut self, field: &str, t: &Mat4Rows) {
        if let Some(p) = check_rigid(field, t) {
            self.problems.push(p);
        }
    }

    fn files(&mut self, m: &Manifest, progress: &mut dyn FnMut(usize, usize)) {
        let truth: HashSet<&str> = m
            .ground_truth
            .iter()
            .flat_map(|gt| [&gt.rgb, &gt.class_ids, &gt.elevation, &gt.valid])
            .map(|p| p.as_str())
            .collect();
        for (path, size) in self.source.oversize() {
            if !truth.contains(path.as_str()) {
                self.problems.push(Problem::FileTooLarge {
                    path,
                    size,
                    limit: self.limits.max_file_bytes,
                });
            }
        }
        let refs = m.referenced_files();
        let total = refs.len();
        let mut present = HashSet::new();
        for (field, path) in &refs {
            if !is_safe_path(path) {
                self.problems.push(Problem::UnsafePath {
                    field: field.clone(),
                    path: path.to_string(),
                });
            } else if self.source.size(path).is_none() {
                self.problems.push(Problem::MissingFile {
                    field: field.clone(),
                    path: path.to_string(),
                });
            } else {
                present.insert(*path);
            }
        }
        let mut done = 0;
        for f in &m.frames {
            for v in &f.views {
                if let (Some(cam), true) = (m.camera(&v.camera), self.content) {
                    if present.contains(v.image.as_str()) {
                        self.image_size(&v.image, &cam.name, cam.width, cam.height);
                    }
                    if let Some(label) = v.label.as_deref().filter(|l| present.contains(l)) {
                        self.label(label, &cam.name, cam.width, cam.height);
                    }
                }
                done += 1 + v.label.is_some() as usize;
                progress(done, total);
            }
            if let (Some(path), Some(sensor)) = (&f.lidar, &m.lidar) {
                if let (true, Some(len)) = (present.contains(path.as_str()), self.source.size(path))
                {
                    let stride = 4 * sensor.floats_per_point as u64;
                    if stride > 0 && len % stride != 0 {
                        self.problems.push(Problem::LidarStride {
                            path: path.clone(),
                            len,
                            stride,
                            floats: sensor.floats_per_point,
                        });
                    }
                }
                done += 1;
            }
        }
        if self.content {
            for c in &m.cameras {
                if let Some(mask) = c.mask.as_deref().filter(|p| present.contains(p)) {
                    self.gray_of_size(mask, &c.name, c.width, c.height);
                }
            }
        }
        if let Some(gt) = &m.ground_truth {
            let (w, h) = (gt.width, gt.height);
            if self.content {
                self.truth_images(gt, &present);
            }
            if let Some(len) = self.source.size(&gt.elevation) {
                let expected = 4 * w as u64 * h as u64;
                if len != expected {
                    self.problems.push(Problem::ElevationSize {
                        path: gt.elevation.clone(),
                        len,
                        expected,
                    });
                }
            }
        }
        progress(total, total);
    }

    fn truth_images(&mut self, gt: &super::manifest::GroundTruth, present: &HashSet<&str>) {
        // The truth covers the whole drive: its rasters get the truth's limits.
        let saved = self.limits;
        self.limits = saved.for_truth();
        self.truth_images_within(gt, present);
        self.limits = saved;
    }

    fn truth_images_within(&mut self, gt: &super::manifest::GroundTruth, present: &HashSet<&str>) {
        let (w, h) = (gt.width, gt.height);
        for p in [&gt.rgb, &gt.valid] {
            if present.contains(p.as_str()) {
                self.image_size(p, "ground_truth", w, h);
            }
        }
        if present.contains(gt.class_ids.as_str()) {
            self.label(&gt.class_ids, "ground_truth", w, h);
            // The truth is not a camera: its road pixels say nothing of the labels.
            self.road_pixels.remove("ground_truth");
        }
    }

    /// Reads only the header: dimensions are checked without decoding pixels.
    fn image_size(&mut self, path: &str, camera: &str, w: u32, h: u32) {
        let bytes = match self.source.read(path, &self.limits) {
            Ok(b) => b,
            Err(p) => return self.problems.push(p),
        };
        let dims = if self.limits.decode_images {
            decode_rgb(path, &bytes, &self.limits).map(|i| i.dimensions())
        } else {
            image_dims(path, &bytes, &self.limits)
        };
        match dims {
            Ok((fw, fh)) if (fw, fh) != (w, h) => self.problems.push(Problem::ImageSize {
                path: path.into(),
                camera: camera.into(),
                expected_w: w,
                expected_h: h,
                found_w: fw,
                found_h: fh,
            }),
            Ok(_) => {}
            Err(p) => self.problems.push(p),
        }
    }

    /// A grey PNG of the camera's size, decoded; `None` once its problem is recorded.
    fn gray_of_size(
        &mut self,
        path: &str,
        camera: &str,
        w: u32,
        h: u32,
    ) -> Option<image::GrayImage> {
        let bytes = match self.source.read(path, &self.limits) {
            Ok(b) => b,
            Err(p) => {
                self.problems.push(p);
                return None;
            }
        };
        let img = match decode_label(path, &bytes, &self.limits) {
            Ok(i) => i,
            Err(p) => {
                self.problems.push(p);
                return None;
            }
        };
        if img.dimensions() != (w, h) {
            self.problems.push(Problem::ImageSize {
                path: path.into(),
                camera: camera.into(),
                expected_w: w,
                expected_h: h,
                found_w: img.width(),
                found_h: img.height(),
            });
            return None;
        }
        Some(img)
    }

    fn label(&mut self, path: &str, camera: &str, w: u32, h: u32) {
        let Some(img) = self.gray_of_size(path, camera, w, h) else {
            return;
        };
        let mut first = None;
        let mut bad = 0u64;
        let mut road = 0u64;
        for (x, y, p) in img.enumerate_pixels() {
            if !self.class_ids[p.0[0] as usize] {
                bad += 1;
                first.get_or_insert((x, y, p.0[0]));
            }
            road += self.road_ids[p.0[0] as usize] as u64;
        }
        let seen = self.road_pixels.entry(camera.to_string()).or_default();
        seen.0 += road;
        seen.1 += img.len() as u64;
        if let Some((x, y, value)) = first {
            self.problems.push(Problem::LabelOutOfRange {
                path: path.into(),
                value,
                x,
                y,
                pixels: bad,
            });
        }
    }
}

/// Checks a 4×4 transform: finite, orthonormal rotation with det +1, last row 0 0 0 1.
pub fn check_rigid(field: &str, t: &Mat4Rows) -> Option<Problem> {
    if !t.iter().flatten().all(|v| v.is_finite()) {
        return Some(Problem::NonFinite {
            field: field.into(),
        });
    }
    if t[3] != [0.0, 0.0, 0.0, 1.0] {
        return Some(Problem::NotRigid {
            field: field.into(),
        });
    }
    let mut deviation: f64 = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| t[k][i] * t[k][j]).sum();
            deviation = deviation.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let r = |i: usize, j: usize| t[i][j];
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1))
        - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    if det < 0.0 {
        deviation = deviation.max(1.0 - det);
    }
    (deviation > ROTATION_TOLERANCE).then(|| Problem::NotRotation {
        field: field.into(),
        deviation,
        tolerance: ROTATION_TOLERANCE,
    })
}

/// Image dimensions from the header, refusing images past the size limit.
pub fn image_dims(path: &str, bytes: &[u8], limits: &Limits) -> Result<(u32, u32), Problem> {
    let decode = |e: image::ImageError| Problem::ImageDecode {
        path: path.into(),
        reason: e.to_string(),
    };
    let (w, h) = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| Problem::ImageDecode {
            path: path.into(),
            reason: e.to_string(),
        })?
        .into_dimensions()
        .map_err(decode)?;
    if w > limits.max_image_side || h > limits.max_image_side {
        return Err(Problem::ImageTooLarge {
            path: path.into(),
            width: w,
            height: h,
            limit: limits.max_image_side,
        });
    }
    Ok((w, h))
}

/// Decodes an RGB image (PNG or JPEG; grey is widened), after the size check.
pub fn decode_rgb(path: &str, bytes: &[u8], limits: &Limits) -> Result<image::RgbImage, Problem> {
    image_dims(path, bytes, limits)?;
    image::load_from_memory(bytes)
        .map(|i| i.to_rgb8())
        .map_err(|e| Problem::ImageDecode {
            path: path.into(),
            reason: e.to_string(),
        })
}

/// Decodes an 8-bit single-channel label PNG, after the size check.
pub fn decode_label(
    path: &str,
    bytes: &[u8],
    limits: &Limits,
) -> Result<image::GrayImage, Problem> {
    image_dims(path, bytes, limits)?;
    match image::load_from_memory(bytes) {
        Ok(image::DynamicImage::ImageLuma8(g)) => Ok(g),
        Ok(other) => Err(Problem::LabelFormat {
            path: path.into(),
            found: format!("{:?}", other.color()),
        }),
        Err(e) => Err(Problem::ImageDecode {
            path: path.into(),
            reason: e.to_string(),
        }),
    }
}
