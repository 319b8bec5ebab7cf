//! Grid, initialisation and refinement on synthetic scenes with known truth.
#![cfg(not(target_arch = "wasm32"))]

use rogs::bundle::{write_zip, Bundle, Limits};
use rogs::eval::{elevation_vs_raster, BevRaster};
use rogs::grid::{Grid, GridConfig, GridError};
use rogs::init::prepare::{prepare, PrepareConfig};
use rogs::init::{initialise, InitConfig, InitMethod, PoseIndex, PosePlanes};
use rogs::synth::classes::{CROSSWALK, CURB, LANE_MARKING, MANHOLE};
use rogs::synth::rig::PoseNoise;
use rogs::synth::{generate, Preset, SynthConfig};

fn bundle(cfg: &SynthConfig) -> Bundle {
    let out = generate(cfg, &|_, _, _| {}).expect("generate");
    Bundle::from_zip_bytes(
        write_zip(&out.manifest, &out.files).expect("zip"),
        Limits::default(),
    )
    .expect("valid")
}

#[test]
fn corridor_count_matches_analytic_area() {
    let cfg = GridConfig {
        resolution: 0.05,
        half_width: 4.0,
        memory_budget: 1 << 30,
    };
    // Straight 20 m: a capsule of area 2·w·L + π·w².
    let path: Vec<[f64; 2]> = (0..=20).map(|i| [100.0 + i as f64, 50.0]).collect();
    let g = Grid::corridor(&path, &cfg, 64).expect("grid");
    let area = 2.0 * 4.0 * 20.0 + std::f64::consts::PI * 16.0;
    let expected = area / (0.05 * 0.05);
    assert!(
        (g.len() as f64 / expected - 1.0).abs() < 0.05,
        "{} vs {expected}",
        g.len()
    );
    // An L-shaped path: two capsules sharing a disc at the corner.
    let mut path: Vec<[f64; 2]> = (0..=15).map(|i| [i as f64, 0.0]).collect();
    path.extend((1..=15).map(|i| [15.0, i as f64]));
    let g = Grid::corridor(&path, &cfg, 64).expect("grid");
    let area = 2.0 * (2.0 * 4.0 * 15.0) + std::f64::consts::PI * 16.0 * 0.75 + 16.0;
    let expected = area / (0.05 * 0.05);
    assert!(
        (g.len() as f64 / expected - 1.0).abs() < 0.05,
        "{} vs {expected}",
        g.len()
    );
    // Not the bounding box: a diagonal path's corridor is far smaller than its box.
    let diag: Vec<[f64; 2]> = (0..=100).map(|i| [i as f64, i as f64]).collect();
    let g = Grid::corridor(&diag, &cfg, 64).expect("grid");
    assert!((g.len() as f64) < 0.2 * (108.0 * 108.0 / 0.0025));
}

#[test]
fn memory_budget_is_checked_before_allocation() {
    let path: Vec<[f64; 2]> = (0..=1000).map(|i| [i as f64, 0.0]).collect();
    let cfg = GridConfig {
        resolution: 0.05,
        half_width: 8.0,
        memory_budget: 100 << 20,
    };
    match Grid::corridor(&path, &cfg, 80) {
        Err(GridError::OverBudget { surfels, .. }) => assert!(surfels > 6_000_000),
        other => panic!("expected OverBudget, got {:?}", other.map(|g| g.len())),
    }
    assert_eq!(
        Grid::corridor(&[[0.0, 0.0]], &cfg, 80).err(),
        Some(GridError::NoPath)
    );
}

#[test]
fn index_map_gives_grid_neighbours() {
    let cfg = GridConfig {
        resolution: 0.1,
        half_width: 2.0,
        memory_budget: 1 << 30,
    };
    let path = [[0.0, 0.0], [10.0, 0.0]];
    let mut g = Grid::corridor(&path, &cfg, 64).expect("grid");
    let centre = g.index.get(2 * 50, 2 * 20).expect("vertex at (5, 0)") as usize;
    let [x, y] = g.xy(centre);
    let mut n: Vec<[f64; 2]> = g.neighbours4(centre).map(|k| g.xy(k as usize)).collect();
    n.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let d: Vec<f64> = n.iter().map(|p| (p[0] - x).hypot(p[1] - y)).collect();
    assert_eq!(n.len(), 4);
    assert!(d.iter().all(|&d| (d - 0.1).abs() < 1e-9), "{d:?}");
    assert_eq!(g.neighbours8(centre).count(), 8);
    // After a split the neighbours are at the fine spacing, and shared vertices exist once.
    let before = g.len();
    let [i, j] = g.coords[centre];
    for (di, dj) in [(1, 1), (1, 0), (0, 1), (2, 1), (1, 2)] {
        g.insert(i + di, j + dj, 1);
    }
    for (di, dj) in [(-1, 1), (-1, 0), (0, 1), (-2, 1), (-1, 2)] {
        g.insert(i + di, j + dj, 1);
    }
    assert_eq!(
        g.len() - before,
        9,
        "the shared edge vertex must not be duplicated"
    );
    let d: Vec<f64> = g
        .neighbours4(centre)
        .map(|k| {
            let p = g.xy(k as usize);
            (p[0] - x).hypot(p[1] - y)
        })
        .collect();
    assert!(
        d.iter().filter(|&&d| (d - 0.05).abs() < 1e-9).count() == 3,
        "{d:?}"
    );
}

/// Demo scene, one small camera (initialisation needs poses, not pixels).
fn noisy_scene(seed: u64) -> SynthConfig {
    let mut cfg = SynthConfig::preset(Preset::Demo, seed);
    cfg.cameras = 1;
    cfg.width = 64;
    cfg.height = 36;
    cfg.noise = PoseNoise {
        translation_m: 0.05,
        rotation_deg: 0.5,
        drift_m: 0.05,
    };
    cfg
}

#[test]
fn consensus_beats_nearest_pose_under_pose_noise() {
    // Pose noise: 5 cm and 0.5° per axis per frame, 5 cm drift.
    let mut wins = 0;
    for seed in [1, 2, 3] {
        let b = bundle(&noisy_scene(seed));
        let truth = BevRaster::from_bundle(&b).unwrap().unwrap();
        let planes = PosePlanes::from_manifest(&b.manifest);
        let path: Vec<[f64; 2]> = planes.ground.iter().map(|g| [g[0], g[1]]).collect();
        let grid = Grid::corridor(
            &path,
            &GridConfig {
                half_width: 5.0,
                ..Default::default()
            },
            64,
        )
        .unwrap();
        let poses = PoseIndex::new(&planes);
        let rmse = |method| {
            let r = initialise(
                &grid,
                &poses,
                &InitConfig {
                    method,
                    ..Default::default()
                },
            );
            let pts: Vec<[f64; 3]> = (0..grid.len())
                .map(|k| {
                    let [x, y] = grid.xy(k);
                    [x, y, r.z[k] as f64]
                })
                .collect();
            elevation_vs_raster(&pts, &truth).expect("overlap").rmse
        };
        let (near, cons) = (rmse(InitMethod::Nearest), rmse(InitMethod::Consensus));
        eprintln!("seed {seed}: nearest {near:.4} m, consensus {cons:.4} m");
        if cons < near {
            wins += 1;
        }
    }
    assert_eq!(wins, 3, "consensus must beat nearest on every seed");
}

#[test]
fn confidence_is_low_where_poses_disagree() {
    let mut cfg = noisy_scene(5);
    cfg.noise = PoseNoise::default();
    let out = generate(&cfg, &|_, _, _| {}).unwrap();
    let mut m = out.manifest.clone();
    // Make two neighbouring poses inconsistent with the rest: 30 cm up.
    m.frames[12].vehicle_to_world[2][3] += 0.3;
    m.frames[13].vehicle_to_world[2][3] += 0.3;
    let planes = PosePlanes::from_manifest(&m);
    let poses = PoseIndex::new(&planes);
    let cfg = InitConfig::default();
    let q_at = |f: usize| {
        let g = out.manifest.frames[f].vehicle_to_world;
        poses.prior(g[0][3], g[1][3], &cfg).q
    };
    assert!(
        q_at(12) < 0.3 && q_at(13) < 0.3,
        "q at the bad poses {} {}",
        q_at(12),
        q_at(13)
    );
    for f in [2, 5, 20, 23] {
        assert!(q_at(f) > 0.9, "q at consistent frame {f}: {}", q_at(f));
    }
}

#[test]
fn refinement_adds_surfels_on_markings_and_curbs() {
    let mut cfg = SynthConfig::preset(Preset::Demo, 6);
    cfg.lidar = true;
    cfg.noise = PoseNoise {
        translation_m: 0.02,
        rotation_deg: 0.2,
        drift_m: 0.0,
    };
    let b = bundle(&cfg);
    let truth = BevRaster::from_bundle(&b).unwrap().unwrap();
    // A 4.3 m corridor (the official KITTI setting is 4 m) spans the carriageway and
    // the right curb and sidewalk, but not the sidewalk/terrain border, which is a
    // boundary refinement rightly splits but not a marking or curb edge.
    let grid = rogs::grid::GridConfig {
        half_width: 4.3,
        ..Default::default()
    };
    let p = prepare(
        &b,
        &PrepareConfig {
            use_lidar: true,
            grid,
            ..Default::default()
        },
    )
    .expect("prepare");
    let r = &p.report;
    eprintln!("{r:?}");
    assert!(
        r.added_surfels > 1000,
        "only {} surfels added",
        r.added_surfels
    );
    assert_eq!(r.surfels, r.base_surfels + r.added_surfels);
    // Distance from each added surfel to the nearest marking or curb edge in the truth.
    let structure = |c: u8| matches!(c, LANE_MARKING | CROSSWALK | CURB | MANHOLE);
    let class_at = |c: i64, r: i64| {
        (c >= 0 && r >= 0 && c < truth.width as i64 && r < truth.height as i64)
            .then(|| truth.class_ids.get_pixel(c as u32, r as u32).0[0])
    };
    let mut edge = vec![false; (truth.width * truth.height) as usize];
    for row in 0..truth.height {
        for col in 0..truth.width {
            let c = truth.class_ids.get_pixel(col, row).0[0];
            let (ci, ri) = (col as i64, row as i64);
            let around: Vec<u8> = [(1, 0), (0, 1), (-1, 0), (0, -1)]
                .iter()
                .filter_map(|&(dc, dr)| class_at(ci + dc, ri + dr))
                .collect();
            // A class boundary that involves a marking, crosswalk, curb or manhole.
            let boundary = around
                .iter()
                .any(|&n| n != c && (structure(c) || structure(n)));
            edge[(row * truth.width + col) as usize] = truth.is_valid(col, row) && boundary;
        }
    }
    let reach = (0.2 / truth.resolution).ceil() as i64;
    let (mut inside, mut near) = (0, 0);
    for k in (0..p.grid.len()).filter(|&k| p.grid.level[k] == 1) {
        let [x, y] = p.grid.xy(k);
        let Some((c, r)) = truth.pixel_of(x, y) else {
            continue;
        };
        if !truth.is_valid(c, r) {
            continue;
        }
        inside += 1;
        let hit = (-reach..=reach).any(|dr| {
            (-reach..=reach).any(|dc| {
                let (cc, rr) = (c as i64 + dc, r as i64 + dr);
                cc >= 0
                    && rr >= 0
                    && cc < truth.width as i64
                    && rr < truth.height as i64
                    && (dc * dc + dr * dr) as f64 * truth.resolution.powi(2) <= 0.04 + 1e-9
                    && edge[(rr * truth.width as i64 + cc) as usize]
            })
        });
        near += hit as usize;
    }
    assert!(inside > 500);
    assert!(
        near as f64 >= 0.8 * inside as f64,
        "{near}/{inside} added surfels near markings or curbs"
    );
}
