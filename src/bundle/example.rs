//! A minimal well-formed bundle: every optional part present, tiny images. It exists
//! for format tests, the docs' example and page fixtures; it is not a road scene
//! (the synthetic-scene generator makes those).

use super::manifest::*;
use super::write::BundleFile;
use image::{GrayImage, ImageFormat, Luma, Rgb, RgbImage};
use std::io::Cursor;

pub const WIDTH: u32 = 64;
pub const HEIGHT: u32 = 48;
pub const FRAMES: usize = 3;
pub const LIDAR_POINTS: usize = 100;

/// Camera looking forward, 1.5 m above the vehicle origin, pitched to the road.
pub fn front_camera() -> Camera {
    Camera {
        name: "front".into(),
        width: WIDTH,
        height: HEIGHT,
        fx: 50.0,
        fy: 50.0,
        cx: 32.0,
        cy: 24.0,
        // Camera (x right, y down, z forward) to vehicle (x forward, y left, z up).
        camera_to_vehicle: [
            [0.0, 0.0, 1.0, 1.0],
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, -1.0, 0.0, 1.5],
            [0.0, 0.0, 0.0, 1.0],
        ],
        mask: None,
    }
}

pub fn classes() -> Vec<SemanticClass> {
    let c = SemanticClass::new;
    vec![
        c(0, "road", [128, 64, 128], ClassRole::Road),
        c(1, "lane_marking", [255, 255, 255], ClassRole::Road),
        c(10, "sky", [70, 130, 180], ClassRole::Ignore),
    ]
}

pub fn translation(x: f64, y: f64, z: f64) -> Mat4Rows {
    [
        [1.0, 0.0, 0.0, x],
        [0.0, 1.0, 0.0, y],
        [0.0, 0.0, 1.0, z],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

pub fn png_rgb(img: &RgbImage) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    // Writing a PNG into memory cannot fail for a well-formed buffer.
    img.write_to(&mut out, ImageFormat::Png)
        .expect("PNG encoding into memory");
    out.into_inner()
}

pub fn png_gray(img: &GrayImage) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png)
        .expect("PNG encoding into memory");
    out.into_inner()
}

/// The tiny bundle: 3 frames 1 m apart, one camera, LiDAR and a 16×8 BEV truth.
pub fn tiny() -> (Manifest, Vec<BundleFile>) {
    let mut files = Vec::new();
    let mut frames = Vec::new();
    for i in 0..FRAMES {
        let image = format!("images/front/{i:06}.png");
        let label = format!("labels/front/{i:06}.png");
        let lidar = format!("lidar/{i:06}.bin");
        let rgb = RgbImage::from_fn(WIDTH, HEIGHT, |x, y| {
            if y < HEIGHT / 2 {
                Rgb([120, 160, 220])
            } else {
                let v = 60 + ((x + y + 4 * i as u32) % 16) as u8 * 4;
                Rgb([v, v, v])
            }
        });
        let lab = GrayImage::from_fn(WIDTH, HEIGHT, |x, y| {
            match (y < HEIGHT / 2, x.abs_diff(WIDTH / 2) < 2) {
                (true, _) => Luma([10]),
                (false, true) => Luma([1]),
                (false, false) => Luma([0]),
            }
        });
        let pts: Vec<u8> = (0..LIDAR_POINTS)
            .flat_map(|k| {
                let (x, y) = (2.0 + (k % 10) as f32, -2.0 + (k / 10) as f32 * 0.4);
                [x, y, 0.0f32, 0.5].into_iter().flat_map(f32::to_le_bytes)
            })
            .collect();
        files.push((image.clone(), png_rgb(&rgb)));
        files.push((label.clone(), png_gray(&lab)));
        files.push((lidar.clone(), pts));
        frames.push(Frame {
            timestamp: i as f64 * 0.1,
            vehicle_to_world: translation(i as f64, 0.0, 0.0),
            views: vec![View {
                camera: "front".into(),
                image,
                label: Some(label),
                vehicle_to_world: None,
            }],
            lidar: Some(lidar),
        });
    }
    let (gw, gh) = (16, 8);
    files.push((
        "truth/rgb.png".into(),
        png_rgb(&RgbImage::from_pixel(gw, gh, Rgb([90, 90, 90]))),
    ));
    files.push((
        "truth/class_ids.png".into(),
        png_gray(&GrayImage::from_pixel(gw, gh, Luma([0]))),
    ));
    files.push((
        "truth/valid.png".into(),
        png_gray(&GrayImage::from_pixel(gw, gh, Luma([255]))),
    ));
    let elevation: Vec<u8> = (0..gw * gh).flat_map(|_| 0.0f32.to_le_bytes()).collect();
    files.push(("truth/elevation.f32".into(), elevation));
    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        name: "tiny example".into(),
        vehicle_height_m: 0.0,
        semantic_classes: classes(),
        cameras: vec![front_camera()],
        frames,
        lidar: Some(LidarSensor {
            floats_per_point: 4,
            lidar_to_vehicle: translation(0.0, 0.0, 1.8),
        }),
        ground_truth: Some(GroundTruth {
            origin: [0.0, 2.0],
            resolution: 0.25,
            width: gw,
            height: gh,
            rgb: "truth/rgb.png".into(),
            class_ids: "truth/class_ids.png".into(),
            elevation: "truth/elevation.f32".into(),
            valid: "truth/valid.png".into(),
            poses: None,
        }),
        world_frame: None,
        corridor_half_width_m: None,
    };
    (manifest, files)
}
