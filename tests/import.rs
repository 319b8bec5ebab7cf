#![cfg(not(target_arch = "wasm32"))]
//! Dataset importers. KITTI: the real sample in ../shared/data must give a valid
//! bundle whose poses and extrinsics put the road plane onto road-labelled pixels
//! (checked against deliberately broken variants, so the check can fail). nuScenes: a
//! fixture in the devkit schema with known non-trivial poses and calibrations must
//! come out exactly, matrices rebuilt here independently with glam.

use glam::{DMat4, DQuat, DVec3};
use image::GrayImage;
use rogs::bundle::{Bundle, Limits, Manifest, Mat4Rows};
use rogs::import::kitti::{self, KittiOptions};
use rogs::import::nuscenes::{self, ids, NuScenesOptions};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::Command;

fn temp(name: &str) -> PathBuf {
    let p = std::env::temp_dir().join(format!("rogs-import-{}-{name}", std::process::id()));
    std::fs::remove_dir_all(&p).ok();
    std::fs::create_dir_all(&p).unwrap();
    p
}

fn kitti_sample() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/kitti-odometry-sample");
    assert!(
        p.join("poses/00.txt").is_file(),
        "the KITTI sample is missing: expected {} (the shared data folder beside the \
         repository, as in CI: main/ and shared/ side by side)",
        p.display()
    );
    p
}

fn rows(m: DMat4) -> Mat4Rows {
    let mut r = [[0.0; 4]; 4];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = m.col(j)[i];
        }
    }
    r
}

fn mat(r: &Mat4Rows) -> DMat4 {
    DMat4::from_cols_array_2d(r).transpose()
}

fn max_diff(a: &Mat4Rows, b: &Mat4Rows) -> f64 {
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

// ---------------------------------------------------------------- KITTI, real data

/// Frames ahead whose road is checked: about 8 to 16 m on the sample (the image's
/// bottom edge sees the road from 6.2 m on).
const AHEAD: std::ops::RangeInclusive<usize> = 8..=15;

/// Share of frames in which at least 70 % of the road ahead lands on road or lane
/// pixels. The road ahead of frame i is the road plane under the vehicle's own later
/// poses (frames i+8 … i+15, |y| ≤ 1.5 m, z = 0 in each vehicle frame), taken into the
/// world through those poses and into frame i's camera through its pose and extrinsic:
/// a wrong extrinsic, camera height or pose conversion moves it off the road. (A
/// straight patch in front of frame i leaves the road in the curve.)
fn road_score(m: &Manifest, labels: &[GrayImage]) -> f64 {
    let cam = &m.cameras[0];
    let c = mat(&cam.camera_to_vehicle);
    let road: Vec<u8> = m
        .semantic_classes
        .iter()
        .filter(|c| c.name == "road" || c.name == "lane_marking")
        .map(|c| c.id)
        .collect();
    let n = m.frames.len() - AHEAD.end();
    let mut good = 0;
    for (i, label) in labels.iter().enumerate().take(n) {
        let world_to_cam = (mat(&m.frames[i].vehicle_to_world) * c).inverse();
        let (mut hits, mut total) = (0, 0);
        for j in AHEAD.map(|a| i + a) {
            let under = mat(&m.frames[j].vehicle_to_world);
            for yi in -3..=3 {
                let p = world_to_cam.transform_point3(under.transform_point3(DVec3::new(
                    0.0,
                    yi as f64 * 0.5,
                    0.0,
                )));
                total += 1;
                if p.z <= 0.1 {
                    continue;
                }
                let u = cam.fx * p.x / p.z + cam.cx;
                let v = cam.fy * p.y / p.z + cam.cy;
                if u >= 0.0 && v >= 0.0 && u < cam.width as f64 && v < cam.height as f64 {
                    let id = label.get_pixel(u as u32, v as u32).0[0];
                    hits += road.contains(&id) as usize;
                }
            }
        }
        good += (hits as f64 >= 0.7 * total as f64) as usize;
    }
    good as f64 / n as f64
}

#[test]
fn kitti_sample_gives_a_valid_bundle_whose_road_lands_on_road_labels() {
    let root = kitti_sample();
    let dir = temp("kitti");
    let out = dir.join("kitti.zip");
    let t0 = std::time::Instant::now();
    let o = Command::new(env!("CARGO_BIN_EXE_rogs"))
        .args(["import", "kitti"])
        .arg(&root)
        .args(["--sequence", "00", "--out"])
        .arg(&out)
        .args([
            "--labels",
            "sequences/00/semantic_twinlitenet",
            "--classes",
            "twinlitenet",
        ])
        .output()
        .expect("run rogs");
    let seconds = t0.elapsed().as_secs_f64();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    eprintln!("KITTI sample import: {seconds:.2} s; {err}");

    let b = Bundle::open(&out, Limits::default(), &mut |_, _| {}).expect("valid bundle");
    let m = &b.manifest;
    assert_eq!(m.frames.len(), 51);
    assert_eq!((m.cameras[0].width, m.cameras[0].height), (1241, 376));
    let len = m.trajectory_length_m();
    assert!(
        (len - 51.8).abs() <= 0.5,
        "trajectory {len:.2} m, expected 51.8 ± 0.5"
    );
    // Frame 0 is the world origin, on the road, z up.
    assert!(max_diff(&m.frames[0].vehicle_to_world, &rows(DMat4::IDENTITY)) < 1e-6);

    let labels: Vec<GrayImage> = (0..m.frames.len())
        .map(|f| b.read_view_label(f, 0).expect("label"))
        .collect();
    let score = road_score(m, &labels);
    eprintln!("road ahead on road pixels in {score:.2} of frames");
    assert!(
        score >= 0.8,
        "road ahead on road pixels in only {score:.2} of frames"
    );

    // The same check on broken conversions must fail: it is not vacuous.
    let mut flipped = m.clone();
    flipped.cameras[0].camera_to_vehicle[2][3] *= -1.0; // camera below the road
    let mut upside_down = m.clone();
    let r = &mut upside_down.cameras[0].camera_to_vehicle;
    // vehicle y = +camera x, z = +camera y: still a rotation, wrong axes.
    (r[1][0], r[2][1]) = (1.0, 1.0);
    let mut mirrored = m.clone(); // the trajectory turning the wrong way
    for f in &mut mirrored.frames {
        let s = DMat4::from_scale(DVec3::new(1.0, -1.0, 1.0));
        f.vehicle_to_world = rows(s * mat(&f.vehicle_to_world) * s);
    }
    for (what, bad) in [
        ("negated camera height", &flipped),
        ("wrong camera axes", &upside_down),
        ("mirrored trajectory", &mirrored),
    ] {
        let s = road_score(bad, &labels);
        eprintln!("{what}: {s:.2}");
        assert!(s < 0.8, "{what} still scores {s:.2}: the check cannot fail");
    }
    std::fs::remove_dir_all(dir).ok();
}

// ------------------------------------------------ KITTI, synthetic: camera 2, velodyne

fn write(path: &Path, bytes: impl AsRef<[u8]>) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn kitti_camera_2_velodyne_times_and_frame_range() {
    let root = temp("kitti-fixture");
    let seq = root.join("sequences/07");
    let p2 = "P2: 700 0 600 44.857 0 700 180 0.2163 0 0 1 0.002745";
    let tr = "Tr: 0 -1 0 -0.004 0 0 -1 -0.076 1 0 0 -0.27";
    write(
        &seq.join("calib.txt"),
        format!("P0: 700 0 600 0 0 700 180 0 0 0 1 0\nP1: 700 0 600 -380 0 700 180 0 0 0 1 0\n{p2}\nP3: 700 0 600 -330 0 700 180 0 0 0 1 0\n{tr}\n"),
    );
    // Camera 0 moving 1 m forward (camera z) per frame.
    let poses: String = (0..4)
        .map(|i| format!("1 0 0 0 0 1 0 0 0 0 1 {i}\n"))
        .collect();
    write(&root.join("poses/07.txt"), poses);
    write(&seq.join("times.txt"), "0.0\n0.11\n0.2\n0.31\n");
    let rgb = rogs::bundle::example::png_rgb(&image::RgbImage::new(1241, 376));
    for i in 0..4 {
        write(&seq.join(format!("image_2/{i:06}.png")), &rgb);
        let pts: Vec<u8> = [1.0f32, 2.0, 3.0, 0.5, 4.0, 5.0, 6.0, 0.25]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        write(&seq.join(format!("velodyne/{i:06}.bin")), pts);
    }
    let mut opts = KittiOptions::new(&root, "07", root.join("out.zip"));
    opts.camera = 2;
    opts.velodyne = true;
    opts.frames = Some(1..3);
    opts.camera_height = 1.7;
    let done = kitti::import(&opts, &mut |_, _, _| {}).expect("import");
    assert!(done.warnings.iter().any(|w| w.contains("no labels")));
    let m = &done.manifest;
    // Without --labels: a drive without masks, no class table.
    assert!(!m.labelled() && m.semantic_classes.is_empty());
    assert_eq!(m.frames.len(), 2);
    assert_eq!(m.frames[0].timestamp, 0.11);
    assert_eq!(m.frames[1].timestamp, 0.2);
    assert!(max_diff(&m.frames[0].vehicle_to_world, &rows(DMat4::IDENTITY)) < 1e-12);
    let forward = DMat4::from_translation(DVec3::X);
    assert!(max_diff(&m.frames[1].vehicle_to_world, &rows(forward)) < 1e-12);
    let cam = &m.cameras[0];
    assert_eq!(
        (cam.name.as_str(), cam.fx, cam.cx, cam.cy),
        ("cam2", 700.0, 600.0, 180.0)
    );
    // Camera axes → vehicle axes, camera 0 at 1.7 m; camera 2 sits at −K⁻¹·P2[:,3]
    // in camera 0's frame.
    let cam_axes = DMat4::from_cols_array_2d(&[
        [0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, -1.0, 0.0],
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.7, 1.0],
    ]);
    let tz = 0.002745;
    let t = DVec3::new(
        (44.857 - 600.0 * tz) / 700.0,
        (0.2163 - 180.0 * tz) / 700.0,
        tz,
    );
    let expected = cam_axes * DMat4::from_translation(-t);
    assert!(max_diff(&cam.camera_to_vehicle, &rows(expected)) < 1e-12);
    // Camera 2 is left of camera 0 (vehicle y > 0).
    assert!(cam.camera_to_vehicle[1][3] > 0.06);
    let velo_to_cam0 = DMat4::from_cols_array_2d(&[
        [0.0, 0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
        [-0.004, -0.076, -0.27, 1.0],
    ]);
    let lidar = m.lidar.as_ref().expect("lidar");
    assert_eq!(lidar.floats_per_point, 4);
    assert!(max_diff(&lidar.lidar_to_vehicle, &rows(cam_axes * velo_to_cam0)) < 1e-12);
    let b = Bundle::open(&done.path, Limits::default(), &mut |_, _| {}).expect("valid");
    let pts = b.read_lidar(m.frames[0].lidar.as_ref().unwrap()).unwrap();
    assert_eq!(pts, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    std::fs::remove_dir_all(root).ok();
}

#[test]
fn kitti_errors_name_the_missing_file_and_the_layout() {
    let root = temp("kitti-empty");
    let o = Command::new(env!("CARGO_BIN_EXE_rogs"))
        .args(["import", "kitti"])
        .arg(&root)
        .args(["--sequence", "00", "--out"])
        .arg(root.join("x.zip"))
        .output()
        .expect("run rogs");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("sequences/00/calib.txt not found"), "{err}");
    assert!(err.contains("ROOT/poses/NN.txt"), "{err}");
    assert!(!root.join("x.zip").exists() && !root.join("x.zip.partial").exists());
    std::fs::remove_dir_all(root).ok();
}

#[test]
fn kitti_invalid_result_lists_problems_with_exit_code_2() {
    let root = kitti_sample();
    let dir = temp("kitti-dup");
    // Duplicate class ids pass the importer's label check but not the validator.
    let classes = dir.join("classes.json");
    let c = |id: u8, name: &str, role: &str| json!({"id": id, "name": name, "color": [0, 0, 0], "role": role});
    write(
        &classes,
        serde_json::to_vec(&json!([
            c(0, "other", "ignore"),
            c(1, "road", "road"),
            c(2, "lane", "road"),
            c(2, "lane2", "road")
        ]))
        .unwrap(),
    );
    let out = dir.join("dup.zip");
    let o = Command::new(env!("CARGO_BIN_EXE_rogs"))
        .args(["import", "kitti"])
        .arg(&root)
        .args(["--sequence", "00", "--frames", "0..3", "--out"])
        .arg(&out)
        .args(["--labels", "sequences/00/semantic_twinlitenet", "--classes"])
        .arg(&classes)
        .output()
        .expect("run rogs");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("duplicate class id 2"), "{err}");
    assert!(
        !out.exists() && dir.join("dup.zip.partial").exists(),
        "{err}"
    );
    std::fs::remove_dir_all(dir).ok();
}

// ------------------------------------------------------------ nuScenes, fixture

/// Ego pose of sensor `s` (0 front camera, 1 back camera, 2 LiDAR) at sample `k`:
/// a vehicle driving along a gentle curve, each sensor's record a little apart in time.
fn ego(k: usize, s: usize) -> ([f64; 4], [f64; 3]) {
    let t = k as f64 + 0.02 * s as f64;
    let yaw = 0.3 + 0.05 * t;
    let q = DQuat::from_rotation_z(yaw) * DQuat::from_rotation_x(0.01 * t);
    (
        [q.w, q.x, q.y, q.z],
        [600.0 + 4.0 * t, 1500.0 + 1.5 * t, 0.02 * t],
    )
}

fn calib(s: usize) -> ([f64; 4], [f64; 3]) {
    // nuScenes-like: cameras look along ±x with OpenCV axes; LiDAR yawed 90°.
    let cam_axes = DQuat::from_mat3(&glam::DMat3::from_cols(
        DVec3::new(0.0, -1.0, 0.0),
        DVec3::new(0.0, 0.0, -1.0),
        DVec3::new(1.0, 0.0, 0.0),
    ));
    let (q, t) = match s {
        0 => (
            DQuat::from_rotation_z(0.02) * DQuat::from_rotation_y(0.03) * cam_axes,
            [1.70, 0.01, 1.51],
        ),
        1 => (DQuat::from_rotation_z(3.12) * cam_axes, [0.05, -0.01, 1.55]),
        _ => (
            DQuat::from_rotation_z(-1.55) * DQuat::from_rotation_x(0.004),
            [0.94, 0.0, 1.84],
        ),
    };
    ([q.w, q.x, q.y, q.z], t)
}

fn transform((q, t): ([f64; 4], [f64; 3])) -> DMat4 {
    // nuScenes writes [w, x, y, z]; glam wants x, y, z, w.
    let q = DQuat::from_xyzw(q[1], q[2], q[3], q[0]).normalize();
    DMat4::from_rotation_translation(q, DVec3::from_array(t))
}

const CHANNELS: [&str; 3] = ["CAM_FRONT", "CAM_BACK", "LIDAR_TOP"];
const LIDAR_POINTS: [[f32; 5]; 3] = [
    [10.0, 0.5, -1.8, 12.0, 3.0],
    [-4.0, 7.0, -1.7, 40.0, 17.0],
    [0.3, -20.0, 0.2, 1.0, 31.0],
];

fn jpeg(w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 15) as u8, (y * 20) as u8, 90])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
    out.into_inner()
}

/// A nuScenes tree: scene-0001 with 3 samples (+ one camera sweep between samples 0
/// and 1), and scene-0002 with one sample that must be left out.
fn nuscenes_fixture(root: &Path) {
    let (w, h) = (16u32, 10u32);
    let ts = |k: usize, s: usize| 1_531_000_000_000_000i64 + k as i64 * 500_000 + s as i64 * 20_000;
    let mut samples = vec![];
    let mut data = vec![];
    let mut poses = vec![];
    for k in 0..4 {
        let scene = if k < 3 { "sc1" } else { "sc2" };
        samples.push(
            json!({"token": format!("s{k}"), "timestamp": ts(k, 2), "scene_token": scene,
            "prev": if k == 0 { String::new() } else { format!("s{}", k - 1) }, "next": ""}),
        );
        for (s, ch) in CHANNELS.iter().enumerate() {
            let (q, t) = ego(k, s);
            poses.push(json!({"token": format!("e{k}{s}"), "timestamp": ts(k, s), "rotation": q, "translation": t}));
            let (dir, ext) = if s == 2 {
                ("LIDAR_TOP", "pcd.bin")
            } else {
                (*ch, "jpg")
            };
            let file = format!("samples/{dir}/n008__{ch}__{}.{ext}", ts(k, s));
            data.push(
                json!({"token": format!("d{k}{s}"), "sample_token": format!("s{k}"),
                "ego_pose_token": format!("e{k}{s}"), "calibrated_sensor_token": format!("c{s}"),
                "timestamp": ts(k, s), "fileformat": ext, "is_key_frame": true,
                "height": if s == 2 { 0 } else { h }, "width": if s == 2 { 0 } else { w },
                "filename": file, "prev": "", "next": ""}),
            );
            if s == 2 {
                let bytes: Vec<u8> = LIDAR_POINTS
                    .iter()
                    .flatten()
                    .flat_map(|v| v.to_le_bytes())
                    .collect();
                write(&root.join(&file), bytes);
            } else {
                write(&root.join(&file), jpeg(w, h));
            }
        }
    }
    // A camera sweep of both cameras 0.25 s after sample 0 (belongs to sample 1).
    for (s, ch) in CHANNELS.iter().enumerate().take(2) {
        let t = ts(0, s) + 250_000;
        let file = format!("sweeps/{ch}/n008__{ch}__{t}.jpg");
        write(&root.join(&file), jpeg(w, h));
        data.push(json!({"token": format!("w{s}"), "sample_token": "s1", "ego_pose_token": format!("e1{s}"),
            "calibrated_sensor_token": format!("c{s}"), "timestamp": t, "fileformat": "jpg",
            "is_key_frame": false, "height": h, "width": w, "filename": file, "prev": "", "next": ""}));
    }
    let sensors: Vec<_> = CHANNELS
        .iter()
        .enumerate()
        .map(|(s, ch)| {
            json!({"token": format!("n{s}"), "channel": ch,
            "modality": if s == 2 { "lidar" } else { "camera" }})
        })
        .collect();
    let calibs: Vec<_> = (0..3)
        .map(|s| {
            let (q, t) = calib(s);
            let k = if s == 2 {
                json!([])
            } else {
                json!([
                    [12.5 + s as f64, 0.0, 8.25],
                    [0.0, 12.75, 5.5],
                    [0.0, 0.0, 1.0]
                ])
            };
            json!({"token": format!("c{s}"), "sensor_token": format!("n{s}"), "translation": t,
                "rotation": q, "camera_intrinsic": k})
        })
        .collect();
    let scenes = json!([
        {"token": "sc1", "log_token": "l", "nbr_samples": 3, "first_sample_token": "s0",
         "last_sample_token": "s2", "name": "scene-0001", "description": "fixture"},
        {"token": "sc2", "log_token": "l", "nbr_samples": 1, "first_sample_token": "s3",
         "last_sample_token": "s3", "name": "scene-0002", "description": "other"}
    ]);
    let v = root.join("v1.0-mini");
    for (name, table) in [
        ("scene.json", scenes),
        ("sample.json", json!(samples)),
        ("sample_data.json", json!(data)),
        ("ego_pose.json", json!(poses)),
        ("sensor.json", json!(sensors)),
        ("calibrated_sensor.json", json!(calibs)),
    ] {
        write(&v.join(name), serde_json::to_vec_pretty(&table).unwrap());
    }
}

/// Vistas labels: left half road (13), a lane-marking column (7), a car block (55),
/// sky row (27).
fn vistas_label(w: u32, h: u32) -> GrayImage {
    GrayImage::from_fn(w, h, |x, y| {
        image::Luma([match (x, y) {
            (_, 0) => 27,
            (4, _) => 7,
            (x, y) if x >= 12 && y >= 6 => 55,
            _ => 13,
        }])
    })
}

#[test]
fn nuscenes_fixture_poses_calibrations_lidar_and_labels_come_out_exactly() {
    let root = temp("nusc");
    nuscenes_fixture(&root);
    let labels = root.join("seg");
    for k in 0..3 {
        let front = format!(
            "seg_CAM_FRONT/n008__CAM_FRONT__{}.png",
            1_531_000_000_000_000i64 + k * 500_000
        );
        // CAM_BACK in RoGS's layout: the image path with /CAM → /seg_CAM.
        let back = format!(
            "samples/seg_CAM_BACK/n008__CAM_BACK__{}.png",
            1_531_000_000_000_000i64 + k * 500_000 + 20_000
        );
        for p in [front, back] {
            let p = labels.join(p);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            vistas_label(16, 10).save(p).unwrap();
        }
    }
    let mut opts = NuScenesOptions::new(&root, "scene-0001", root.join("out.zip"));
    opts.cameras = vec!["CAM_FRONT".into(), "CAM_BACK".into()];
    opts.labels = Some(labels);
    let done = nuscenes::import(&opts, &mut |_, _, _| {}).expect("import");
    let m = &done.manifest;
    assert_eq!(m.frames.len(), 3, "keyframes of scene-0001 only");
    assert_eq!(m.vehicle_height_m, 0.0);
    // The world is the global frame shifted to the first pose; the shift is recorded.
    let wf = m.world_frame.as_ref().expect("world frame");
    assert!(wf.name.starts_with("nuScenes global frame"), "{}", wf.name);
    let t0 = [0, 1, 2].map(|i| m.frames[0].vehicle_to_world[i][3]);
    assert!(
        t0.iter().all(|v| v.abs() < 1e-9),
        "first pose at the origin: {t0:?}"
    );
    assert_eq!(m.corridor_half_width_m, Some(8.0));
    eprintln!("warnings: {:?}", done.warnings);
    assert!(
        done.warnings
            .iter()
            .any(|w| w.contains("each view carries its own ego pose")),
        "{:?}",
        done.warnings
    );

    // Calibrations: sensor-to-ego straight from the quaternions.
    for (s, name) in ["CAM_FRONT", "CAM_BACK"].iter().enumerate() {
        let cam = m.camera(name).expect("camera");
        let d = max_diff(&cam.camera_to_vehicle, &rows(transform(calib(s))));
        assert!(d < 1e-9, "{name} camera_to_vehicle off by {d}");
        assert_eq!(
            (cam.fx, cam.fy, cam.cx, cam.cy),
            (12.5 + s as f64, 12.75, 8.25, 5.5)
        );
        assert_eq!((cam.width, cam.height), (16, 10));
    }
    let lidar = m.lidar.as_ref().expect("lidar");
    assert_eq!(lidar.floats_per_point, 4);
    let l2v = transform(calib(2));
    assert!(max_diff(&lidar.lidar_to_vehicle, &rows(l2v)) < 1e-9);

    // Poses: CAM_FRONT's ego pose, the world shifted to the first frame's position.
    let shift = DMat4::from_translation(-DVec3::from_array(ego(0, 0).1));
    for (k, f) in m.frames.iter().enumerate() {
        let expected = shift * transform(ego(k, 0));
        let d = max_diff(&f.vehicle_to_world, &rows(expected));
        assert!(d < 1e-9, "frame {k} vehicle_to_world off by {d}");
        assert!((f.timestamp - 0.5 * k as f64).abs() < 1e-9);
        assert_eq!(f.views.len(), 2);
        // CAM_BACK fired at another time: its view carries its own ego pose.
        assert!(
            f.views[0].vehicle_to_world.is_none(),
            "CAM_FRONT is the anchor"
        );
        let own = f.views[1].vehicle_to_world.expect("CAM_BACK's own pose");
        let d = max_diff(&own, &rows(shift * transform(ego(k, 1))));
        assert!(d < 1e-9, "frame {k} CAM_BACK pose off by {d}");
    }

    // LiDAR: 4 floats per point, moved from the LiDAR's ego pose into the frame's.
    let b = Bundle::open(&done.path, Limits::default(), &mut |_, _| {}).expect("valid");
    for (k, f) in m.frames.iter().enumerate() {
        let path = f.lidar.as_ref().expect("sweep");
        let raw = b.read(path).unwrap();
        assert_eq!(raw.len(), LIDAR_POINTS.len() * 16);
        let motion = l2v.inverse() * transform(ego(k, 0)).inverse() * transform(ego(k, 2)) * l2v;
        for (p, q) in raw.chunks_exact(16).zip(LIDAR_POINTS) {
            let f: Vec<f32> = p
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .collect();
            let e = motion.transform_point3(DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64));
            let err = (DVec3::new(f[0] as f64, f[1] as f64, f[2] as f64) - e).length();
            assert!(err < 1e-4, "frame {k}: point {f:?}, expected {e:?}");
            assert_eq!(f[3], q[3], "intensity kept, ring dropped");
        }
    }

    // Labels: Vistas ids remapped (13 road, 7 lane marking, 55 movable, 27 other).
    for f in &m.frames {
        for v in &f.views {
            let path = v.label.as_deref().expect("labelled");
            let l = b.read_label(path).unwrap();
            assert_eq!(l.get_pixel(0, 5).0[0], ids::ROAD, "{path}");
            assert_eq!(l.get_pixel(4, 5).0[0], ids::LANE_MARKING);
            assert_eq!(l.get_pixel(13, 8).0[0], ids::MOVABLE);
            assert_eq!(l.get_pixel(3, 0).0[0], ids::OTHER);
        }
    }
    let role = |id: u8| {
        m.semantic_classes
            .iter()
            .find(|c| c.id == id)
            .map(|c| c.role)
    };
    assert_eq!(role(ids::ROAD), Some(rogs::bundle::ClassRole::Road));
    assert_eq!(role(ids::MOVABLE), Some(rogs::bundle::ClassRole::Ignore));
    std::fs::remove_dir_all(root).ok();
}

#[test]
fn nuscenes_sweeps_add_frames_between_keyframes() {
    let root = temp("nusc-sweeps");
    nuscenes_fixture(&root);
    let mut opts = NuScenesOptions::new(&root, "scene-0001", root.join("out.zip"));
    opts.cameras = vec!["CAM_FRONT".into(), "CAM_BACK".into()];
    opts.sweeps = true;
    let done = nuscenes::import(&opts, &mut |_, _, _| {}).expect("import");
    let m = &done.manifest;
    assert!(done.warnings.iter().any(|w| w.contains("no labels")));
    assert!(!m.labelled());
    assert_eq!(m.frames.len(), 4);
    let sweep = &m.frames[1];
    assert!((sweep.timestamp - 0.25).abs() < 1e-9);
    assert_eq!(
        sweep.views.len(),
        2,
        "the back camera's sweep joins the front's"
    );
    assert!(sweep.views[0].image.starts_with("images/CAM_FRONT/"));
    // The sweep's pose is its own record's ego pose.
    let shift = DMat4::from_translation(-DVec3::from_array(ego(0, 0).1));
    let d = max_diff(&sweep.vehicle_to_world, &rows(shift * transform(ego(1, 0))));
    assert!(d < 1e-9);

    // An unknown scene names the ones there are.
    let mut bad = opts.clone();
    bad.scene = "scene-9999".into();
    let e = nuscenes::import(&bad, &mut |_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("scene-0001, scene-0002"), "{e}");
    std::fs::remove_dir_all(root).ok();
}
