//! Synthetic scenes: determinism, the ray caster against an analytic projection,
//! label/colour edge agreement, pose-noise statistics, truth rasters, validation of
//! every preset, and the LiDAR pseudo-ground-truth against the BEV truth.
#![cfg(not(target_arch = "wasm32"))]

use rogs::bundle::{write_zip, Bundle, Limits};
use rogs::eval::pseudo_gt::{lidar_cloud, rasterise};
use rogs::eval::{elevation_vs_raster, BevRaster};
use rogs::synth::classes::{LANE_MARKING, ROAD};
use rogs::synth::raycast::{render, shade, to_u8, Exposure, View};
use rogs::synth::rig::{exp_so3, mat, noisy_poses, PoseNoise};
use rogs::synth::rng::Rng;
use rogs::synth::road::{RoadSpec, CURB_WIDTH, HALF_WIDTH};
use rogs::synth::world::World;
use rogs::synth::{generate, Preset, SynthConfig};

fn quiet(_: &str, _: usize, _: usize) {}

fn bundle_of(cfg: &SynthConfig) -> (rogs::synth::SynthOutput, Bundle) {
    let out = generate(cfg, &quiet).expect("generate");
    let zip = write_zip(&out.manifest, &out.files).expect("zip");
    let b = Bundle::from_zip_bytes(zip, Limits::default())
        .unwrap_or_else(|e| panic!("{:?} invalid: {e}", cfg.preset));
    (out, b)
}

#[test]
fn deterministic_for_a_seed() {
    let mut cfg = SynthConfig::preset(Preset::Tiny, 7);
    cfg.lidar = true;
    cfg.noise = PoseNoise {
        translation_m: 0.05,
        rotation_deg: 0.5,
        drift_m: 0.1,
    };
    let a = generate(&cfg, &quiet).expect("a");
    let b = generate(&cfg, &quiet).expect("b");
    assert_eq!(a.manifest, b.manifest);
    assert_eq!(a.files, b.files);
    cfg.seed = 8;
    let c = generate(&cfg, &quiet).expect("c");
    assert_ne!(a.files, c.files, "another seed must give another scene");
}

fn flat_road() -> RoadSpec {
    RoadSpec {
        seed: 3,
        pieces: vec![(80.0, 0.0)],
        slope: 0.0,
        crossfall: 0.0,
        vertical_curve_m: 0.0,
        curb_height: 0.0,
        bump: None,
        crosswalk: Some(12.0),
        manhole: Some((9.0, 1.0)),
    }
}

/// Camera 2 m above a flat road, looking along +x, pitched down 35°.
fn down_view() -> (View, [[f64; 3]; 3], [f64; 3]) {
    let p = 35f64.to_radians();
    // Columns: camera x (right = -y world), y (down), z (forward, pitched down).
    let r = [
        [0.0, -p.sin(), p.cos()],
        [-1.0, 0.0, 0.0],
        [0.0, -p.cos(), -p.sin()],
    ];
    let t = [4.0, 0.5, 2.0];
    let v = View {
        width: 96,
        height: 64,
        fx: 60.0,
        fy: 60.0,
        cx: 48.0,
        cy: 32.0,
        cam_to_world: mat(r, t),
    };
    (v, r, t)
}

#[test]
fn ray_caster_matches_analytic_projection_of_a_flat_textured_plane() {
    let road = flat_road();
    let world = World::new(road.clone(), 0.04, &[]);
    let (view, r, t) = down_view();
    let (rgb, lab) = render(
        &world,
        &view,
        2,
        Exposure {
            gain: 1.0,
            offset: 0.0,
        },
    );
    // Plane z = 0 seen through K [R | t]: the image point (u, v) back-projects to the
    // plane point where the camera ray's z reaches 0. Solved in closed form here
    // from the intrinsics and extrinsics, independently of the ray caster.
    let plane_point = |u: f64, v: f64| {
        let c = [(u - view.cx) / view.fx, (v - view.cy) / view.fy, 1.0];
        let d: Vec<f64> = (0..3)
            .map(|i| r[i][0] * c[0] + r[i][1] * c[1] + r[i][2] * c[2])
            .collect();
        let lambda = -t[2] / d[2];
        (t[0] + lambda * d[0], t[1] + lambda * d[1])
    };
    let (mut checked, mut colour_ok, mut label_ok) = (0, 0, 0);
    for y in 0..view.height {
        for x in 0..view.width {
            let mut sum = [0.0; 3];
            let mut votes = [0u8; 256];
            let mut on_carriageway = true;
            for j in 0..2 {
                for i in 0..2 {
                    let (px, py) = plane_point(
                        x as f64 + 0.25 + 0.5 * i as f64,
                        y as f64 + 0.25 + 0.5 * j as f64,
                    );
                    // Straight road along +x from the origin: s = x, t = y. Only the
                    // carriageway is exactly flat (sidewalks and terrain rise).
                    on_carriageway &= py.abs() < HALF_WIDTH;
                    let (albedo, class) = road.material(px, py);
                    let c = shade(albedo, [0.0, 0.0, 1.0]);
                    (0..3).for_each(|k| sum[k] += c[k] / 4.0);
                    votes[class as usize] += 1;
                }
            }
            if !on_carriageway {
                continue;
            }
            let class = (0..256)
                .find(|&k| votes[k] == *votes.iter().max().unwrap())
                .unwrap() as u8;
            checked += 1;
            let got = rgb.get_pixel(x, y).0;
            if (0..3).all(|k| (got[k] as i32 - to_u8(sum[k]) as i32).abs() <= 2) {
                colour_ok += 1;
            }
            if lab.get_pixel(x, y).0[0] == class {
                label_ok += 1;
            }
        }
    }
    assert!(checked > 2000, "{checked} carriageway pixels");
    assert!(
        colour_ok as f64 >= 0.99 * checked as f64,
        "colour {colour_ok}/{checked}"
    );
    assert!(
        label_ok as f64 >= 0.995 * checked as f64,
        "label {label_ok}/{checked}"
    );
    // The view must contain markings, or the test proves little.
    assert!(
        lab.pixels()
            .filter(|p| p.0[0] == LANE_MARKING || p.0[0] == 2)
            .count()
            > 100
    );
}

#[test]
fn label_edges_align_with_colour_edges() {
    let mut cfg = SynthConfig::preset(Preset::Demo, 4);
    cfg.frames = 14;
    cfg.cameras = 1;
    let out = generate(&cfg, &quiet).expect("generate");
    let (mut edges, mut aligned) = (0, 0);
    for f in out.manifest.frames.iter() {
        let find = |p: &str| &out.files.iter().find(|(n, _)| n == p).unwrap().1;
        let rgb = image::load_from_memory(find(&f.views[0].image))
            .unwrap()
            .to_rgb8();
        let lab = image::load_from_memory(find(f.views[0].label.as_deref().expect("labelled")))
            .unwrap()
            .to_luma8();
        let lum =
            |x: u32, y: u32| rgb.get_pixel(x, y).0.iter().map(|&v| v as f64).sum::<f64>() / 765.0;
        for y in 0..lab.height() {
            for x in 1..lab.width() - 2 {
                let (a, b) = (lab.get_pixel(x, y).0[0], lab.get_pixel(x + 1, y).0[0]);
                if (a == ROAD && b == LANE_MARKING) || (a == LANE_MARKING && b == ROAD) {
                    edges += 1;
                    // The colour step lies within one pixel of the label step.
                    let step = (lum(x + 2, y) - lum(x - 1, y)).abs();
                    if step > 0.12 {
                        aligned += 1;
                    }
                }
            }
        }
    }
    assert!(edges > 200, "too few marking edges: {edges}");
    assert!(
        aligned as f64 >= 0.95 * edges as f64,
        "{aligned}/{edges} label edges have a colour edge"
    );
}

/// Axis-angle vector of a rotation matrix (log map), small angles.
fn log_so3(r: [[f64; 3]; 3]) -> [f64; 3] {
    let c = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
    let th = c.acos();
    let k = if th < 1e-12 {
        0.5
    } else {
        th / (2.0 * th.sin())
    };
    [
        k * (r[2][1] - r[1][2]),
        k * (r[0][2] - r[2][0]),
        k * (r[1][0] - r[0][1]),
    ]
}

#[test]
fn pose_noise_statistics_match_the_settings() {
    let n = 6000;
    let truth: Vec<_> = (0..n)
        .map(|k| {
            mat(
                exp_so3([0.0, 0.0, k as f64 * 0.001]),
                [k as f64, 0.5 * k as f64, 1.0],
            )
        })
        .collect();
    let noise = PoseNoise {
        translation_m: 0.05,
        rotation_deg: 0.5,
        drift_m: 0.0,
    };
    let noisy = noisy_poses(&truth, noise, &Rng::new(11));
    for axis in 0..3 {
        let d: Vec<f64> = (0..n)
            .map(|k| noisy[k][axis][3] - truth[k][axis][3])
            .collect();
        let mean = d.iter().sum::<f64>() / n as f64;
        let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
        assert!(mean.abs() < 0.005, "axis {axis} mean {mean}");
        assert!((sd / 0.05 - 1.0).abs() < 0.06, "axis {axis} sd {sd}");
        let w: Vec<f64> = (0..n)
            .map(|k| {
                let (a, b) = (&truth[k], &noisy[k]);
                let mut rel = [[0.0; 3]; 3];
                for i in 0..3 {
                    for j in 0..3 {
                        rel[i][j] = (0..3).map(|m| a[m][i] * b[m][j]).sum();
                    }
                }
                log_so3(rel)[axis]
            })
            .collect();
        let sd = (w.iter().map(|v| v * v).sum::<f64>() / n as f64)
            .sqrt()
            .to_degrees();
        assert!(
            (sd / 0.5 - 1.0).abs() < 0.06,
            "rotation axis {axis} sd {sd}°"
        );
    }
    let drift = noisy_poses(
        &truth,
        PoseNoise {
            translation_m: 0.0,
            rotation_deg: 0.0,
            drift_m: 0.3,
        },
        &Rng::new(2),
    );
    let off = |k: usize| {
        (0..3)
            .map(|i| (drift[k][i][3] - truth[k][i][3]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    assert!(off(0) < 1e-12);
    assert!((off(n - 1) - 0.3).abs() < 1e-9);
    assert!((off(n / 2) - 0.15).abs() < 1e-3);
}

#[test]
fn truth_rasters_follow_the_road_model() {
    let (out, b) = bundle_of(&SynthConfig::preset(Preset::Tiny, 5));
    let truth = BevRaster::from_bundle(&b).expect("read").expect("truth");
    let road = &out.world.road;
    let line = &out.world.line;
    // Elevation at a carriageway point equals the road model.
    let s = 22.0;
    let (x, y, _) = line.point(s, -1.0);
    let z = truth.elevation_xy(x, y).expect("valid");
    assert!(
        (z - road.height(s, -1.0)).abs() < 0.003,
        "{z} vs {}",
        road.height(s, -1.0)
    );
    // The curb is a real height step.
    let (xa, ya, _) = line.point(s, -(HALF_WIDTH - 0.1));
    let (xb, yb, _) = line.point(s, -(HALF_WIDTH + CURB_WIDTH + 0.1));
    let step = truth.elevation_xy(xb, yb).unwrap() - truth.elevation_xy(xa, ya).unwrap();
    assert!((step - road.curb_height).abs() < 0.02, "curb step {step}");
    // Classes present in the truth: road, markings, curb, sidewalk.
    let ids: std::collections::HashSet<u8> = truth.class_ids.pixels().map(|p| p.0[0]).collect();
    for c in [0, 1, 3, 4] {
        assert!(
            ids.contains(&c),
            "class {c} missing from the truth raster: {ids:?}"
        );
    }
}

#[test]
fn every_preset_gives_a_valid_bundle() {
    for preset in [Preset::Tiny, Preset::Demo, Preset::NuscenesLike] {
        let mut cfg = SynthConfig::preset(preset, 1);
        // Full-size demo and nuScenes-like images are for `rogs synth`; here the
        // structure is what is checked (cameras, classes, truth, LiDAR).
        cfg.frames = cfg.frames.min(3);
        cfg.width = cfg.width.min(96);
        cfg.height = cfg.height.min(40);
        cfg.lidar = preset != Preset::Tiny;
        cfg.truth_resolution = 0.2;
        let (_, b) = bundle_of(&cfg);
        let s = b.summary();
        assert_eq!(s.cameras.len(), cfg.cameras);
        assert!(s.ground_truth.is_some());
        assert_eq!(s.lidar_sweeps, if cfg.lidar { 3 } else { 0 });
    }
}

#[test]
fn lidar_pseudo_ground_truth_agrees_with_bev_truth() {
    let mut cfg = SynthConfig::preset(Preset::Demo, 9);
    cfg.frames = 12;
    cfg.width = 128;
    cfg.height = 72;
    cfg.lidar = true;
    let (_, b) = bundle_of(&cfg);
    let truth = BevRaster::from_bundle(&b).unwrap().unwrap();
    let cloud = lidar_cloud(&b).expect("cloud");
    assert!(cloud.points.len() > 20_000, "{} points", cloud.points.len());
    let e = elevation_vs_raster(&cloud.points, &truth).expect("overlap");
    assert!(e.count > 10_000);
    assert!(e.rmse < 0.01, "pseudo-GT elevation RMSE {} m", e.rmse);
    let pseudo = rasterise(&cloud, &truth);
    let (mut both, mut agree) = (0, 0);
    for r in 0..truth.height {
        for c in 0..truth.width {
            if truth.is_valid(c, r) && pseudo.is_valid(c, r) {
                both += 1;
                agree +=
                    (truth.class_ids.get_pixel(c, r) == pseudo.class_ids.get_pixel(c, r)) as u32;
            }
        }
    }
    assert!(both > 5_000);
    assert!(
        agree as f64 > 0.95 * both as f64,
        "label agreement {agree}/{both}"
    );
}

/// `revisit`: drive 2 is the same road (one world frame, the same heights), 40 % of a
/// trajectory further on, a day later, with its own pose noise, cars and exposures.
#[test]
fn revisit_drives_share_the_road_and_differ_in_the_rest() {
    use rogs::synth::world_and_poses;
    let drive = |d: usize| {
        let mut c = SynthConfig::preset(Preset::Revisit, 1);
        c.drive = d;
        c.noise = PoseNoise {
            translation_m: 0.05,
            rotation_deg: 0.5,
            drift_m: 0.05,
        };
        c
    };
    let (c1, c2) = (drive(1), drive(2));
    let (w1, p1) = world_and_poses(&c1, &quiet);
    let (w2, p2) = world_and_poses(&c2, &quiet);
    let lt = c1.trajectory_length();
    let dx = p2[0][0][3] - p1[0][0][3];
    assert!((dx - 0.4 * lt).abs() < 0.5, "drive 2 starts {dx} m on");
    // The same road: heights agree wherever neither drive parked a car.
    for p in p2.iter().take(20) {
        let (x, y) = (p[0][3], p[1][3] + 1.0);
        let (a, b) = (w1.field.height(x, y), w2.field.height(x, y));
        assert_eq!(a, b, "height at ({x}, {y})");
    }
    assert_ne!(
        w1.occluders
            .iter()
            .map(|o| format!("{o:?}"))
            .collect::<Vec<_>>(),
        w2.occluders
            .iter()
            .map(|o| format!("{o:?}"))
            .collect::<Vec<_>>(),
        "other parked cars"
    );
    let small = |c: &mut SynthConfig| {
        c.frames = 3;
        c.width = 48;
        c.height = 27;
        c.rays_per_axis = 1;
    };
    let (mut s1, mut s2) = (c1.clone(), c2.clone());
    small(&mut s1);
    small(&mut s2);
    let (o1, o2) = (
        generate(&s1, &quiet).expect("d1"),
        generate(&s2, &quiet).expect("d2"),
    );
    assert!(o2.manifest.frames[0].timestamp - o1.manifest.frames[0].timestamp > 80_000.0);
    assert!(
        o2.manifest.name.ends_with("drive 2"),
        "{}",
        o2.manifest.name
    );
    // Its own pose noise: the written poses' errors differ from drive 1's.
    let err = |o: &rogs::synth::SynthOutput| {
        o.manifest.frames[0].vehicle_to_world[2][3] - o.true_poses[0][2][3]
    };
    assert_ne!(err(&o1), err(&o2));
}

#[test]
fn long_drives_out_and_back_so_every_place_is_seen_on_two_passes() {
    let mut c = SynthConfig::preset(Preset::Long, 1);
    c.set_length_m(80.0);
    (c.width, c.height, c.rays_per_axis) = (160, 48, 1);
    c.truth_resolution = 0.2;
    let out = generate(&c, &|_, _, _| {}).expect("synth");
    let m = &out.manifest;
    let n = m.frames.len();
    // Frame k and frame n-1-k stand at the same place, facing the other way, one
    // lane apart (2 × 1.75 m).
    for k in [0, n / 4, n / 2 - 2] {
        let (a, b) = (
            &m.frames[k].vehicle_to_world,
            &m.frames[n - 1 - k].vehicle_to_world,
        );
        let d = (a[0][3] - b[0][3]).hypot(a[1][3] - b[1][3]);
        assert!(
            (d - 3.5).abs() < 0.3,
            "frames {k} and {}: {d} m apart",
            n - 1 - k
        );
        let dot = a[0][0] * b[0][0] + a[1][0] * b[1][0];
        assert!(dot < -0.99, "frames {k} and {}: headings {dot}", n - 1 - k);
    }
    assert!(
        (m.trajectory_length_m() - 80.0).abs() < 5.0,
        "{} m",
        m.trajectory_length_m()
    );
    // A valid bundle, whose tiles are trained by views of both passes.
    let zip = write_zip(m, &out.files).expect("zip");
    let b = Bundle::from_zip_bytes(zip, Limits::default()).expect("valid bundle");
    let mut cfg = rogs::reconstruct::ReconstructConfig::default();
    cfg.prepare.grid.resolution = 0.2;
    let (_, tiles) = rogs::tiles::plan(
        &b,
        &cfg,
        &rogs::tiles::TileConfig {
            size_m: 16.0,
            overlap_m: 2.0,
            origin_m: None,
        },
    );
    let both = tiles
        .iter()
        .filter(|t| t.views.iter().any(|v| v.0 < n / 2) && t.views.iter().any(|v| v.0 >= n / 2))
        .count();
    assert!(
        both * 2 >= tiles.len(),
        "{both} of {} tiles seen on both passes",
        tiles.len()
    );
}
