//! Scene bundle v1: round trip, one test per validation-failure class, resource bounds.
#![cfg(not(target_arch = "wasm32"))]

use rogs::bundle::example::{self, png_gray, png_rgb};
use rogs::bundle::{write_zip, Bundle, BundleFile, Limits, Manifest, Problem};

fn zip(m: &Manifest, files: &[BundleFile]) -> Vec<u8> {
    write_zip(m, files).expect("zip writing")
}

fn open(m: &Manifest, files: &[BundleFile]) -> Result<Bundle, Vec<Problem>> {
    Bundle::from_zip_bytes(zip(m, files), Limits::default()).map_err(|e| e.0)
}

/// Opens a bundle that must be invalid and returns its problems.
fn problems(m: &Manifest, files: &[BundleFile]) -> Vec<Problem> {
    match open(m, files) {
        Ok(_) => panic!("bundle was accepted but should be invalid"),
        Err(p) => p,
    }
}

fn replace(files: &mut [BundleFile], path: &str, bytes: Vec<u8>) {
    let f = files
        .iter_mut()
        .find(|(p, _)| p == path)
        .expect("file in example");
    f.1 = bytes;
}

#[test]
fn round_trip_write_read_equal() {
    let (m, files) = example::tiny();
    let b = open(&m, &files).expect("example bundle is valid");
    assert_eq!(b.manifest, m);
    for (path, bytes) in &files {
        assert_eq!(&b.read(path).expect("file readable"), bytes, "{path}");
    }
    let s = b.summary();
    assert_eq!(s.frames, example::FRAMES);
    assert_eq!(
        s.lidar_points,
        (example::FRAMES * example::LIDAR_POINTS) as u64
    );
    assert!((s.trajectory_length_m - 2.0).abs() < 1e-9);
    assert!(s.ground_truth.is_some());
    let pts = b
        .read_lidar(&m.frames[0].lidar.clone().expect("lidar"))
        .expect("lidar");
    assert_eq!(pts.len(), example::LIDAR_POINTS);
    assert_eq!(pts[11], [3.0, -1.6, 0.0]);
}

#[test]
fn folder_bundle_reads_like_zip() {
    let (m, files) = example::tiny();
    let dir = std::env::temp_dir().join(format!("rogs-bundle-dir-{}", std::process::id()));
    rogs::bundle::write_dir(&dir, &m, &files).expect("write dir");
    let b = Bundle::open(&dir, Limits::default(), &mut |_, _| {}).expect("valid folder bundle");
    assert_eq!(b.manifest, m);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn wrong_format_and_version() {
    let (mut m, files) = example::tiny();
    m.format = "something-else".into();
    m.version = 7;
    let p = problems(&m, &files);
    assert!(p
        .iter()
        .any(|p| matches!(p, Problem::Format { .. }) && p.location() == "format"));
    assert!(p
        .iter()
        .any(|p| matches!(p, Problem::Version { found: 7, .. })));
}

#[test]
fn manifest_syntax_error_is_named() {
    let (_, files) = example::tiny();
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    z.start_file("manifest.json", zip::write::SimpleFileOptions::default())
        .unwrap();
    std::io::Write::write_all(&mut z, b"{\"format\": \"rogs-bundle\", ").unwrap();
    for (p, b) in &files {
        z.start_file(p.as_str(), zip::write::SimpleFileOptions::default())
            .unwrap();
        std::io::Write::write_all(&mut z, b).unwrap();
    }
    let bytes = z.finish().unwrap().into_inner();
    let e = Bundle::from_zip_bytes(bytes, Limits::default())
        .err()
        .expect("invalid")
        .0;
    assert!(matches!(&e[0], Problem::ManifestSyntax(_)));
    assert_eq!(e[0].location(), "manifest.json");
}

#[test]
fn manifest_type_error_names_the_field() {
    let (m, files) = example::tiny();
    let mut v = serde_json::to_value(&m).unwrap();
    v["cameras"][0]["fx"] = serde_json::json!("fifty");
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    z.start_file("manifest.json", zip::write::SimpleFileOptions::default())
        .unwrap();
    std::io::Write::write_all(&mut z, v.to_string().as_bytes()).unwrap();
    for (p, b) in &files {
        z.start_file(p.as_str(), zip::write::SimpleFileOptions::default())
            .unwrap();
        std::io::Write::write_all(&mut z, b).unwrap();
    }
    let e = Bundle::from_zip_bytes(z.finish().unwrap().into_inner(), Limits::default())
        .err()
        .expect("invalid")
        .0;
    assert_eq!(e[0].location(), "cameras[0].fx", "{e:?}");
    assert!(e[0].to_string().contains("expected f64"), "{e:?}");
}

#[test]
fn missing_manifest_and_not_a_zip() {
    let e = Bundle::from_zip_bytes(b"hello".to_vec(), Limits::default())
        .err()
        .expect("invalid")
        .0;
    assert!(matches!(e[0], Problem::NotZip(_)));
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    z.start_file(
        "scene/manifest.json",
        zip::write::SimpleFileOptions::default(),
    )
    .unwrap();
    let bytes = z.finish().unwrap().into_inner();
    let e = Bundle::from_zip_bytes(bytes, Limits::default())
        .err()
        .expect("invalid")
        .0;
    assert_eq!(e, vec![Problem::MissingManifest]);
}

#[test]
fn missing_file_names_field_and_path() {
    let (m, mut files) = example::tiny();
    files.retain(|(p, _)| p != "labels/front/000001.png");
    let p = problems(&m, &files);
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].location(), "frames[1].views[0].label");
    assert!(p[0].to_string().contains("labels/front/000001.png"));
}

/// The one problem is `path`, 32 pixels wide where its camera's 64 were expected.
fn only_width_problem(p: &[Problem], path: &str) {
    assert!(
        matches!(
            p,
            [Problem::ImageSize {
                found_w: 32,
                expected_w: 64,
                ..
            }]
        ),
        "{p:?}"
    );
    assert_eq!(p[0].location(), path);
}

#[test]
fn image_size_must_match_camera() {
    let (m, mut files) = example::tiny();
    replace(
        &mut files,
        "images/front/000002.png",
        png_rgb(&image::RgbImage::new(32, 48)),
    );
    only_width_problem(&problems(&m, &files), "images/front/000002.png");
}

#[test]
fn label_values_within_class_table() {
    let (m, mut files) = example::tiny();
    let mut lab = image::GrayImage::new(64, 48);
    lab.put_pixel(5, 7, image::Luma([42]));
    replace(&mut files, "labels/front/000000.png", png_gray(&lab));
    let p = problems(&m, &files);
    assert!(
        matches!(
            &p[..],
            [Problem::LabelOutOfRange {
                value: 42,
                x: 5,
                y: 7,
                pixels: 1,
                ..
            }]
        ),
        "{p:?}"
    );
    assert_eq!(p[0].location(), "labels/front/000000.png");
}

#[test]
fn label_must_be_single_channel() {
    let (m, mut files) = example::tiny();
    replace(
        &mut files,
        "labels/front/000000.png",
        png_rgb(&image::RgbImage::new(64, 48)),
    );
    let p = problems(&m, &files);
    assert!(matches!(&p[..], [Problem::LabelFormat { .. }]), "{p:?}");
}

#[test]
fn undecodable_image_is_named() {
    let (m, mut files) = example::tiny();
    replace(
        &mut files,
        "images/front/000001.png",
        b"not an image".to_vec(),
    );
    let p = problems(&m, &files);
    assert!(matches!(&p[..], [Problem::ImageDecode { .. }]), "{p:?}");
    assert_eq!(p[0].location(), "images/front/000001.png");
}

#[test]
fn poses_finite_and_orthonormal() {
    // JSON has no NaN: serde writes null, which the parser names by field.
    let (mut m, files) = example::tiny();
    m.frames[0].vehicle_to_world[0][3] = f64::NAN;
    let p = problems(&m, &files);
    assert!(
        matches!(&p[..], [Problem::ManifestField { field, .. }] if field == "frames[0].vehicle_to_world[0][3]"),
        "{p:?}"
    );
    assert!(matches!(
        rogs::bundle::check_rigid("f", &[[f64::NAN; 4]; 4]),
        Some(Problem::NonFinite { .. })
    ));
    let (mut m, files) = example::tiny();
    m.frames[1].vehicle_to_world[0][0] = 1.1;
    m.frames[2].vehicle_to_world[3] = [0.0, 0.0, 1.0, 1.0];
    m.cameras[0].camera_to_vehicle[0][0] = -1.0; // breaks orthogonality of the columns
    let p = problems(&m, &files);
    let loc: Vec<_> = p.iter().map(|p| p.location()).collect();
    assert!(p.iter().any(
        |p| matches!(p, Problem::NotRotation { field, .. } if field == "frames[1].vehicle_to_world")
    ));
    assert!(p.iter().any(
        |p| matches!(p, Problem::NotRigid { field } if field == "frames[2].vehicle_to_world")
    ));
    assert!(loc.contains(&"cameras[0].camera_to_vehicle"), "{loc:?}");
    // A reflection (det = -1) is orthonormal but not a rotation.
    let (mut m, files) = example::tiny();
    m.frames[1].vehicle_to_world[2][2] = -1.0;
    let p = problems(&m, &files);
    assert!(matches!(&p[..], [Problem::NotRotation { .. }]), "{p:?}");
    // A slightly noisy rotation within tolerance is fine.
    let (mut m, files) = example::tiny();
    m.frames[1].vehicle_to_world[0][1] = 1e-5;
    assert!(open(&m, &files).is_ok());
    // A view's own pose is checked as the frame's, and named as a view's.
    let (mut m, files) = example::tiny();
    let mut t = m.frames[1].vehicle_to_world;
    t[0][0] = 1.1;
    m.frames[1].views[0].vehicle_to_world = Some(t);
    let p = problems(&m, &files);
    assert!(
        p.iter().any(|p| matches!(p, Problem::NotRotation { field, .. } if field == "frames[1].views[0].vehicle_to_world")),
        "{p:?}"
    );
    let (mut m, files) = example::tiny();
    m.frames[1].views[0].vehicle_to_world = Some(m.frames[2].vehicle_to_world);
    assert!(open(&m, &files).is_ok());
}

#[test]
fn at_least_two_frames() {
    let (mut m, files) = example::tiny();
    m.frames.truncate(1);
    let p = problems(&m, &files);
    assert!(p
        .iter()
        .any(|p| matches!(p, Problem::TooFewFrames { found: 1 }) && p.location() == "frames"));
}

#[test]
fn lidar_length_multiple_of_stride() {
    let (m, mut files) = example::tiny();
    replace(&mut files, "lidar/000001.bin", vec![0u8; 16 * 10 + 12]);
    let p = problems(&m, &files);
    assert!(
        matches!(
            &p[..],
            [Problem::LidarStride {
                len: 172,
                stride: 16,
                ..
            }]
        ),
        "{p:?}"
    );
    assert_eq!(p[0].location(), "lidar/000001.bin");
}

#[test]
fn unknown_camera_and_duplicate_class() {
    let (mut m, files) = example::tiny();
    m.frames[1].views[0].camera = "rear".into();
    m.semantic_classes[1].id = 0;
    let p = problems(&m, &files);
    let loc: Vec<_> = p.iter().map(|p| p.location()).collect();
    assert!(loc.contains(&"frames[1].views[0].camera"), "{loc:?}");
    assert!(loc.contains(&"semantic_classes[1].id"), "{loc:?}");
}

#[test]
fn ground_truth_elevation_size() {
    let (m, mut files) = example::tiny();
    replace(&mut files, "truth/elevation.f32", vec![0u8; 100]);
    let p = problems(&m, &files);
    assert!(
        matches!(
            &p[..],
            [Problem::ElevationSize {
                len: 100,
                expected: 512,
                ..
            }]
        ),
        "{p:?}"
    );
}

#[test]
fn reports_all_problems_not_only_the_first() {
    let (mut m, mut files) = example::tiny();
    m.version = 2;
    files.retain(|(p, _)| p != "images/front/000000.png");
    replace(&mut files, "lidar/000002.bin", vec![0u8; 3]);
    m.frames[2].vehicle_to_world[1][1] = 3.0;
    let p = problems(&m, &files);
    assert_eq!(p.len(), 4, "{p:?}");
}

#[test]
fn path_traversal_is_refused() {
    // In the manifest …
    let (mut m, files) = example::tiny();
    m.frames[0].views[0].image = "../../etc/passwd".into();
    m.frames[1].views[0].label = Some("/abs/label.png".into());
    let p = problems(&m, &files);
    assert!(
        matches!(&p[0], Problem::UnsafePath { field, .. } if field == "frames[0].views[0].image"),
        "{p:?}"
    );
    assert!(
        matches!(&p[1], Problem::UnsafePath { field, .. } if field == "frames[1].views[0].label"),
        "{p:?}"
    );
    // … and as a zip entry name.
    let (m, mut files) = example::tiny();
    files.push(("../evil.sh".into(), b"rm -rf /".to_vec()));
    let p = problems(&m, &files);
    assert!(
        matches!(&p[..], [Problem::UnsafeEntry { path, .. }] if path == "../evil.sh"),
        "{p:?}"
    );
}

#[test]
fn zip_bomb_is_refused() {
    let (m, mut files) = example::tiny();
    // 64 MiB of zeros deflates to ~64 KiB: past a 16 MiB limit it must not be inflated.
    files.push(("padding.bin".into(), vec![0u8; 64 << 20]));
    let bytes = zip(&m, &files);
    assert!(bytes.len() < 1 << 20, "the bomb should be small on disk");
    let limits = Limits {
        max_file_bytes: 16 << 20,
        ..Limits::default()
    };
    let p = Bundle::from_zip_bytes(bytes, limits)
        .err()
        .expect("refused")
        .0;
    assert!(
        matches!(&p[..], [Problem::FileTooLarge { path, .. }] if path == "padding.bin"),
        "{p:?}"
    );
}

#[test]
fn oversized_image_dimensions_are_refused() {
    let (m, files) = example::tiny();
    let limits = Limits {
        max_image_side: 32,
        ..Limits::default()
    };
    let p = Bundle::from_zip_bytes(zip(&m, &files), limits)
        .err()
        .expect("refused")
        .0;
    assert!(
        p.iter()
            .any(|p| matches!(p, Problem::ImageTooLarge { width: 64, .. })),
        "{p:?}"
    );
}

/// The field a problem names, and its message.
fn named(p: &[Problem]) -> Vec<(String, String)> {
    p.iter()
        .map(|p| (p.location().to_string(), p.to_string()))
        .collect()
}

#[test]
fn implausible_numbers_are_refused_by_field_with_the_expected_range() {
    // Each case breaks one thing; each must be refused naming its field and rule.
    type Case = (&'static str, fn(&mut Manifest), &'static str, &'static str);
    let cases: [Case; 6] = [
        (
            "a pose 1e308 m away",
            |m| m.frames[1].vehicle_to_world[0][3] = 1e308,
            "frames[1].vehicle_to_world translation",
            "local world frame",
        ),
        (
            "a focal length in millimetres",
            |m| m.cameras[0].fx = 1.0,
            "cameras[0].fx",
            "not millimetres",
        ),
        (
            "a focal length of a 0.01° view",
            |m| m.cameras[0].fy = 1e9,
            "cameras[0].fy",
            "field of view",
        ),
        (
            "a principal point far outside the image",
            |m| m.cameras[0].cx = 1e6,
            "cameras[0].cx",
            "principal point",
        ),
        (
            "a camera mounted a kilometre from the vehicle",
            |m| m.cameras[0].camera_to_vehicle[2][3] = 1000.0,
            "cameras[0].camera_to_vehicle translation",
            "vehicle frame",
        ),
        (
            "a LiDAR mounted in another city",
            |m| {
                if let Some(l) = m.lidar.as_mut() {
                    l.lidar_to_vehicle[0][3] = 5e4;
                }
            },
            "lidar.lidar_to_vehicle translation",
            "check the units",
        ),
    ];
    for (what, break_it, field, rule) in cases {
        let (mut m, files) = example::tiny();
        break_it(&mut m);
        let p = named(&problems(&m, &files));
        assert!(
            p.iter().any(|(f, msg)| f == field && msg.contains(rule)),
            "{what}: {p:?}"
        );
    }
}

#[test]
fn entry_names_are_refused_with_the_rule_they_break_and_duplicates_by_name() {
    for (name, rule) in [
        ("a:b.png", "':'"),
        ("./a.png", "'.' component"),
        ("a//b.png", "empty component"),
        ("../a.png", "'..'"),
    ] {
        let (m, mut files) = example::tiny();
        files.push((name.into(), b"x".to_vec()));
        let Ok(z) = rogs::bundle::write_zip(&m, &files) else {
            continue; // the writer itself refused the name
        };
        let p = match Bundle::from_zip_bytes(z, Limits::default()) {
            Ok(_) => panic!("{name} accepted"),
            Err(e) => named(&e.0),
        };
        assert!(p.iter().any(|(_, msg)| msg.contains(rule)), "{name}: {p:?}");
        if name.contains("..") {
            assert!(p.iter().all(|(_, msg)| !msg.contains("':'")), "{p:?}");
        }
    }
    // Two entries of one name: neither silently wins.
    let (m, files) = example::tiny();
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default();
    let manifest = serde_json::to_vec(&m).expect("json");
    z.start_file("manifest.json", opts).expect("entry");
    std::io::Write::write_all(&mut z, &manifest).expect("write");
    for (path, bytes) in &files {
        z.start_file(path.as_str(), opts).expect("entry");
        std::io::Write::write_all(&mut z, bytes).expect("write");
    }
    // The writer refuses a second entry of a name: write it under a twin name of
    // the same length, then rename it in the bytes (local header and directory).
    let dup = &files[0].0;
    let mut twin = dup.clone();
    twin.pop();
    twin.push('~');
    z.start_file(twin.as_str(), opts).expect("entry");
    std::io::Write::write_all(&mut z, &files[0].1).expect("write");
    let mut bytes = z.finish().expect("zip").into_inner();
    let (from, to) = (twin.as_bytes(), dup.as_bytes());
    let mut renamed = 0;
    let mut i = 0;
    while i + from.len() <= bytes.len() {
        if &bytes[i..i + from.len()] == from {
            bytes[i..i + from.len()].copy_from_slice(to);
            renamed += 1;
        }
        i += 1;
    }
    assert_eq!(renamed, 2, "the twin's local header and directory entry");
    let p = match Bundle::from_zip_bytes(bytes, Limits::default()) {
        Ok(_) => panic!("a duplicate entry was accepted"),
        Err(e) => named(&e.0),
    };
    assert!(
        p.iter()
            .any(|(f, msg)| f == dup && msg.contains("two entries")),
        "{p:?}"
    );
}

#[test]
fn a_symbolic_link_out_of_a_bundle_folder_is_not_followed() {
    let (m, files) = example::tiny();
    let dir = std::env::temp_dir().join(format!("rogs-symlink-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    rogs::bundle::write_dir(&dir, &m, &files).expect("folder");
    let outside = dir.with_extension("outside.png");
    let target = &m.frames[0].views[0].image;
    std::fs::copy(dir.join(target), &outside).expect("copy");
    std::fs::remove_file(dir.join(target)).expect("remove");
    std::os::unix::fs::symlink(&outside, dir.join(target)).expect("symlink");
    let p = match Bundle::open(&dir, Limits::default(), &mut |_, _| {}) {
        Ok(_) => panic!("a link out of the bundle was followed"),
        Err(e) => e.0,
    };
    assert!(
        p.iter()
            .any(|p| matches!(p, Problem::MissingFile { path, .. } if path == target)),
        "{p:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(&outside);
}

#[test]
fn a_truth_raster_longer_than_a_camera_image_is_accepted_and_read() {
    // A long drive's truth spans it: 9 000 px, past the 8 192 px of a camera image.
    let (mut m, mut files) = example::tiny();
    let gt = m.ground_truth.as_mut().expect("truth");
    let (w, h) = (9000, 2);
    (gt.width, gt.height) = (w, h);
    let gt = gt.clone();
    replace(&mut files, &gt.rgb, png_rgb(&image::RgbImage::new(w, h)));
    replace(
        &mut files,
        &gt.class_ids,
        png_gray(&image::GrayImage::new(w, h)),
    );
    replace(
        &mut files,
        &gt.valid,
        png_gray(&image::GrayImage::new(w, h)),
    );
    replace(&mut files, &gt.elevation, vec![0; 4 * (w * h) as usize]);
    let b = open(&m, &files).expect("a long truth is valid");
    let r = rogs::eval::BevRaster::from_bundle(&b)
        .expect("readable")
        .expect("truth");
    assert_eq!((r.width, r.height), (w, h));
    // A camera image of that size is still refused.
    let (mut m, files) = example::tiny();
    m.cameras[0].width = 9000;
    let p = named(&problems(&m, &files));
    assert!(p.iter().any(|(f, _)| f.starts_with("cameras[0]")), "{p:?}");
}

#[test]
fn unknown_fields_are_warned_about_with_the_nearest_known_name() {
    let (m, files) = example::tiny();
    let mut v = serde_json::to_value(&m).expect("json");
    v["corridor_half_width"] = 6.0.into();
    v["frames"][1]["views"][0]["vehicle_to_wrld"] = serde_json::Value::Null;
    v["cameras"][0]["colour"] = "red".into();
    let mut files = files;
    files.retain(|(p, _)| p != "manifest.json");
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default();
    z.start_file("manifest.json", opts).expect("entry");
    std::io::Write::write_all(&mut z, &serde_json::to_vec(&v).expect("json")).expect("write");
    for (path, bytes) in &files {
        z.start_file(path.as_str(), opts).expect("entry");
        std::io::Write::write_all(&mut z, bytes).expect("write");
    }
    let bytes = z.finish().expect("zip").into_inner();
    let b = Bundle::from_zip_bytes(bytes, Limits::default()).expect("still valid");
    let w = &b.warnings;
    assert_eq!(w.len(), 3, "{w:?}");
    assert!(
        w.iter().any(|w| w.starts_with("corridor_half_width:")
            && w.contains("did you mean corridor_half_width_m?")),
        "{w:?}"
    );
    assert!(
        w.iter()
            .any(|w| w.starts_with("frames[1].views[0].vehicle_to_wrld:")
                && w.contains("did you mean vehicle_to_world?")),
        "{w:?}"
    );
    assert!(
        w.iter()
            .any(|w| w.starts_with("cameras[0].colour: unknown field, ignored")),
        "{w:?}"
    );
    assert!(b
        .summary()
        .to_text()
        .contains("warning     corridor_half_width"));
    // A bundle as written by rogs has none.
    let (m, files) = example::tiny();
    assert!(open(&m, &files).expect("valid").warnings.is_empty());
}

#[test]
fn a_truncated_image_is_named_when_images_are_decoded_as_inspect_does() {
    let (m, mut files) = example::tiny();
    let path = "images/front/000001.png";
    let whole = files
        .iter()
        .find(|(p, _)| p == path)
        .expect("image")
        .1
        .clone();
    // The header (and so the size) is intact; the pixels are cut off.
    replace(&mut files, path, whole[..whole.len() * 2 / 3].to_vec());
    assert!(
        open(&m, &files).is_ok(),
        "headers only: the run names it when it decodes it"
    );
    let limits = Limits {
        decode_images: true,
        ..Limits::default()
    };
    let p = Bundle::from_zip_bytes(zip(&m, &files), limits)
        .err()
        .expect("refused when decoded")
        .0;
    assert!(matches!(&p[..], [Problem::ImageDecode { .. }]), "{p:?}");
    assert_eq!(p[0].location(), path);
}

#[test]
fn legal_but_useless_bundles_are_warned_with_advice() {
    let warnings = |m: &Manifest, files: &[BundleFile]| -> Vec<String> {
        open(m, files).expect("a legal bundle").warnings
    };
    let (m, files) = example::tiny();
    let w = warnings(&m, &files);
    assert!(w.is_empty(), "the example is useful: {w:?}");

    // A vehicle standing still.
    let mut still = m.clone();
    let first = still.frames[0].vehicle_to_world;
    for f in &mut still.frames {
        f.vehicle_to_world = first;
    }
    let w = warnings(&still, &files);
    assert!(
        w.iter()
            .any(|s| s.contains("moves 0.00 m") && s.contains("poses")),
        "{w:?}"
    );

    // Every label pixel of an ignored class (sky, id 10).
    let mut sky = files.clone();
    for (p, bytes) in &mut sky {
        if p.starts_with("labels/") {
            *bytes = png_gray(&image::GrayImage::from_pixel(64, 48, image::Luma([10])));
        }
    }
    let w = warnings(&m, &sky);
    assert!(
        w.iter()
            .any(|s| s.contains("no label pixel is of a road class (road, lane_marking)")),
        "{w:?}"
    );

    // A second camera whose labels never show the road.
    let mut two = m.clone();
    let mut files2 = files.clone();
    let mut rear = two.cameras[0].clone();
    rear.name = "rear".into();
    two.cameras.push(rear);
    for (i, f) in two.frames.iter_mut().enumerate() {
        let mut v = f.views[0].clone();
        v.camera = "rear".into();
        v.image = format!("images/rear/{i:06}.png");
        let label = format!("labels/rear/{i:06}.png");
        v.label = Some(label.clone());
        let img = files
            .iter()
            .find(|(p, _)| *p == f.views[0].image)
            .expect("image");
        files2.push((v.image.clone(), img.1.clone()));
        files2.push((
            label,
            png_gray(&image::GrayImage::from_pixel(64, 48, image::Luma([10]))),
        ));
        f.views.push(v);
    }
    let w = warnings(&two, &files2);
    assert!(
        w.iter()
            .any(|s| s.contains("camera rear never sees the road")),
        "{w:?}"
    );
    assert!(!w.iter().any(|s| s.contains("camera front")), "{w:?}");
}

/// A drive without masks: no view has a label and the class table may be empty; a
/// camera's body mask is read and checked like a label; a bundle where only some
/// views have labels is refused by the first view without one.
#[test]
fn a_drive_without_labels_is_valid_and_partial_labels_are_refused_by_view() {
    let (mut m, mut files) = example::tiny();
    let labels: Vec<String> = m
        .frames
        .iter()
        .flat_map(|f| &f.views)
        .filter_map(|v| v.label.clone())
        .collect();
    // Some views without a label: refused, naming the first.
    let mut partial = m.clone();
    partial.frames[1].views[0].label = None;
    let p = named(&problems(&partial, &files));
    assert!(
        p.iter().any(|(f, msg)| f == "frames[1].views[0].label"
            && msg.contains("other views have one")),
        "{p:?}"
    );
    // No labels at all, no class table (and so no truth, whose classes it names).
    for f in &mut m.frames {
        for v in &mut f.views {
            v.label = None;
        }
    }
    files.retain(|(p, _)| !labels.contains(p));
    let b = open(&m, &files).expect("valid without labels");
    assert!(!b.manifest.labelled() && !b.summary().labelled);
    assert!(b.summary().to_text().contains("labels      none"));
    // Its labels are the road plane the camera sees: the bottom row, not the top.
    let l = b.read_view_label(0, 0).expect("surface label");
    assert_eq!(l.get_pixel(10, 47).0[0], rogs::bundle::SURFACE_ID);
    assert_eq!(l.get_pixel(10, 0).0[0], 0);
    let mut bare = m.clone();
    bare.semantic_classes.clear();
    bare.ground_truth = None;
    open(&bare, &files).expect("valid without a class table");
    // A body mask of the camera's size covers the bottom rows; of another size, named.
    m.cameras[0].mask = Some("masks/front.png".into());
    let body = image::GrayImage::from_fn(64, 48, |_, y| image::Luma([(y >= 40) as u8 * 255]));
    files.push(("masks/front.png".into(), png_gray(&body)));
    let b = open(&m, &files).expect("valid with a body mask");
    assert!(b.view_files(0, 0).contains(&"masks/front.png"));
    let l = b.read_view_label(0, 0).expect("surface label");
    assert_eq!(l.get_pixel(10, 47).0[0], 0, "the body is never supervised");
    assert_eq!(l.get_pixel(10, 39).0[0], rogs::bundle::SURFACE_ID);
    replace(
        &mut files,
        "masks/front.png",
        png_gray(&image::GrayImage::new(32, 48)),
    );
    only_width_problem(&problems(&m, &files), "masks/front.png");
}
