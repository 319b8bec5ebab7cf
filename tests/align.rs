//! Pose alignment from the LiDAR and the LiDAR elevation prior's gate, on scenes built
//! here with known truth: a rolling, cambered road seen by a drive of sweeps whose
//! poses carry known height, roll and pitch errors, with a parked car beside it.
#![cfg(not(target_arch = "wasm32"))]

use rogs::bundle::{Frame, Manifest, Mat4Rows};
use rogs::grid::{Grid, GridConfig};
use rogs::init::align::{align, apply_to_poses, AlignConfig, Alignment, GroundReturns};
use rogs::loss::regularise::RegData;
use rogs::loss::LossConfig;
use rogs::synth::rng::Rng;

/// The true road: rolling along x, cambered across y.
fn ground(x: f64, y: f64) -> f64 {
    0.3 * (x / 25.0).sin() + 0.02 * y + 0.01 * (y * 1.3).cos()
}

/// A parked car: footprint x in [40, 44.5], y in [3, 4.8], 1.5 m tall.
fn in_car(x: f64, y: f64) -> bool {
    (40.0..=44.5).contains(&x) && (3.0..=4.8).contains(&y)
}

const FRAMES: usize = 40;

/// The true vehicle origin of frame k (on the ground, no rotation).
fn origin(k: usize) -> [f64; 3] {
    let (x, y) = (3.0 * k as f64, 0.3 * (k as f64 / 5.0).sin());
    [x, y, ground(x, y)]
}

/// One sweep in the vehicle frame: ground returns on rings, and the car's side
/// facing the road as a wall of returns from 5 cm to 1.5 m.
fn sweep(k: usize) -> Vec<[f64; 3]> {
    let o = origin(k);
    let mut pts = Vec::new();
    for ring in 0..40 {
        let r = 3.0 + 0.7 * ring as f64;
        for a in 0..120 {
            let t = (a as f64 * 3.0).to_radians();
            let (x, y) = (o[0] + r * t.cos(), o[1] + r * t.sin());
            if !in_car(x, y) {
                pts.push([x - o[0], y - o[1], ground(x, y) - o[2]]);
            }
        }
    }
    if (42.0 - o[0]).abs() < 30.0 {
        for s in 0..30 {
            for h in 1..=30 {
                let (x, y) = (40.0 + 0.15 * s as f64, 3.0);
                pts.push([x - o[0], y - o[1], ground(x, y) + 0.05 * h as f64 - o[2]]);
            }
        }
    }
    pts
}

/// Per frame, the pose error as the plane (a, b, c) it adds to the world heights of
/// the sweep's returns, and the noisy pose that does it.
fn noisy(k: usize, sigma_m: f64, sigma_deg: f64, rng: &mut Rng) -> ([f64; 3], Mat4Rows) {
    let e = [
        sigma_m * rng.normal(),
        sigma_deg.to_radians() * rng.normal(),
        sigma_deg.to_radians() * rng.normal(),
    ];
    let mut f = frame(k);
    // Exactly the correction model, inverted: the noise is what the fix must undo.
    apply_to_poses(
        &Alignment {
            corrections: vec![e],
            ..Default::default()
        },
        &mut f,
    );
    (e, f.frames[0].vehicle_to_world)
}

/// A manifest holding frame k's true pose alone.
fn frame(k: usize) -> Manifest {
    let o = origin(k);
    let mut t = [[0.0; 4]; 4];
    for (i, row) in t.iter_mut().enumerate() {
        row[i] = 1.0;
        if i < 3 {
            row[3] = o[i];
        }
    }
    Manifest {
        format: "rogs-bundle".into(),
        version: 1,
        name: String::new(),
        vehicle_height_m: 0.0,
        semantic_classes: Vec::new(),
        cameras: Vec::new(),
        frames: vec![Frame {
            timestamp: k as f64,
            vehicle_to_world: t,
            views: Vec::new(),
            lidar: None,
        }],
        lidar: None,
        ground_truth: None,
        world_frame: None,
        corridor_half_width_m: None,
    }
}

/// RMS over frames of the height error the poses leave at 15 m around the vehicle,
/// given each frame's error plane and correction.
fn residual_rms(errors: &[[f64; 3]], corrections: &[[f64; 3]]) -> f64 {
    let mut sq = 0.0;
    let mut n = 0.0;
    for (e, c) in errors.iter().zip(corrections) {
        for a in 0..8 {
            let t = (a as f64 * 45.0).to_radians();
            let (dx, dy) = (15.0 * t.cos(), 15.0 * t.sin());
            let h = (e[0] + c[0]) + (e[1] + c[1]) * dx + (e[2] + c[2]) * dy;
            sq += h * h;
            n += 1.0;
        }
    }
    (sq / n).sqrt()
}

fn drive(sigma_m: f64, sigma_deg: f64) -> (Vec<[f64; 3]>, Alignment) {
    drive_thinned(sigma_m, sigma_deg, 1)
}

/// `drive` with the returns of one consensus cell in `stride` kept.
fn drive_thinned(sigma_m: f64, sigma_deg: f64, stride: u32) -> (Vec<[f64; 3]>, Alignment) {
    let cfg = AlignConfig::default();
    let mut rng = Rng::new(7);
    let mut errors = Vec::new();
    let mut returns = GroundReturns::new(FRAMES);
    for k in 0..FRAMES {
        let (e, pose) = noisy(k, sigma_m, sigma_deg, &mut rng);
        errors.push(e);
        returns.add_sweep(&sweep(k), &pose, k as u32, &cfg, stride);
    }
    (errors, align(&returns, FRAMES, &cfg))
}

#[test]
fn alignment_undoes_height_roll_and_pitch_errors_of_the_poses() {
    let (errors, a) = drive(0.05, 0.5);
    assert_eq!(a.sweeps, FRAMES);
    let before = residual_rms(&errors, &vec![[0.0; 3]; FRAMES]);
    let after = residual_rms(&errors, &a.corrections);
    eprintln!("height error at 15 m: {before:.4} m -> {after:.4} m; {a:?}");
    // What is left is the one plane no agreement can see, chosen from the mean of
    // the frames' errors: on this straight drive the mean roll of 40 frames,
    // 0.5°/√40 ≈ 0.08°, or 1.4 cm at 15 m.
    assert!(before > 0.1, "the drive's error is {before}");
    assert!(after < 0.02 && after < 0.15 * before, "{before} -> {after}");
    assert!(a.rms_after_m < 0.5 * a.rms_before_m, "{a:?}");
}

/// A long drive's returns are thinned to one consensus cell in k (`cell_stride`):
/// the same sweeps are corrected nearly as well from a sixth of the returns (one in
/// 18 is too few here: 6.7 cm left at 15 m, against 1.3 cm).
#[test]
fn thinned_returns_align_as_well_as_all_of_them() {
    let (errors, all) = drive(0.05, 0.5);
    let (_, thin) = drive_thinned(0.05, 0.5, 6);
    let (ra, rt) = (
        residual_rms(&errors, &all.corrections),
        residual_rms(&errors, &thin.corrections),
    );
    eprintln!(
        "returns {} -> {}, height error at 15 m {ra:.4} -> {rt:.4} m",
        all.returns, thin.returns
    );
    assert_eq!(thin.sweeps, FRAMES);
    assert!(
        thin.returns * 4 < all.returns && thin.returns * 8 > all.returns,
        "{} of {} returns kept",
        thin.returns,
        all.returns
    );
    assert!(
        rt < 0.02 && rt < ra + 0.005,
        "{ra} with all returns, {rt} thinned"
    );
}

#[test]
fn alignment_leaves_a_noise_free_drive_alone_despite_the_car() {
    let (_, a) = drive(0.0, 0.0);
    for (k, c) in a.corrections.iter().enumerate() {
        assert!(c[0].abs() < 2e-3, "frame {k} moved {c:?}");
        assert!(
            c[1].hypot(c[2]).to_degrees() < 0.01,
            "frame {k} tilted {c:?}"
        );
    }
}

#[test]
fn a_correction_moves_world_heights_by_its_plane() {
    let c = [0.04, 0.006, -0.009];
    let mut m = frame(3);
    let before = m.frames[0].vehicle_to_world;
    apply_to_poses(
        &Alignment {
            corrections: vec![c],
            ..Default::default()
        },
        &mut m,
    );
    let after = m.frames[0].vehicle_to_world;
    let world = |t: &Mat4Rows, p: [f64; 3]| -> [f64; 3] {
        [0, 1, 2].map(|i| t[i][0] * p[0] + t[i][1] * p[1] + t[i][2] * p[2] + t[i][3])
    };
    for p in [[10.0, 0.0, 0.0], [0.0, -8.0, 0.1], [-5.0, 6.0, -0.2]] {
        let (a, b) = (world(&before, p), world(&after, p));
        let dz = c[0] + c[1] * (a[0] - before[0][3]) + c[2] * (a[1] - before[1][3]);
        // Second order in the angles: ~1e-4 m at 10 m.
        assert!(
            (b[2] - a[2] - dz).abs() < 1e-3,
            "{p:?}: {} vs {dz}",
            b[2] - a[2]
        );
        // Horizontally a point moves by the tilt times its height over the origin.
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        assert!(
            dx.abs() < 3e-3 && dy.abs() < 3e-3,
            "{p:?}: moved {dx}, {dy}"
        );
    }
}

/// Surfel priors over a 10 m × 6 m patch whose pose plane ẑ is 0 everywhere: the
/// verge (y > 1.5) truly lies 0.4 m higher, and a car's side stands at y = −1.
#[test]
fn the_lidar_prior_follows_a_raised_verge_and_ignores_a_car_side() {
    let path: Vec<[f64; 2]> = (0..=10).map(|i| [i as f64, 0.0]).collect();
    let cfg = GridConfig {
        resolution: 0.5,
        half_width: 3.0,
        memory_budget: 1 << 30,
    };
    let grid = Grid::corridor(&path, &cfg, 64).expect("grid");
    let truth = |y: f64| if y > 1.5 { 0.4 } else { 0.0 };
    let mut lidar = Vec::new();
    for i in 0..400 {
        for j in 0..240 {
            let (x, y) = (-2.0 + 0.035 * i as f64, -3.5 + 0.03 * j as f64);
            if y >= -1.0 {
                lidar.push([x, y, truth(y)]);
            }
        }
    }
    // The car's side: four rings of returns up to 0.56 m (beams 1° apart at 10 m),
    // as many per metre along it as the road has.
    for i in 0..400 {
        for h in 0..4 {
            lidar.push([-2.0 + 0.035 * i as f64, -1.01, 0.05 + 0.17 * h as f64]);
        }
    }
    let n = grid.len();
    let reg = RegData::new(
        &grid,
        &vec![0.0; n],
        &vec![1.0; n],
        &lidar,
        0.0,
        &LossConfig::default(),
    );
    let (mut verge, mut kerb) = (0, 0);
    for (i, p) in reg.priors.iter().enumerate() {
        let [x, y] = grid.xy(i);
        if !(0.0..=10.0).contains(&x) || (y - 1.5).abs() < 0.3 {
            continue;
        }
        if y > 1.8 {
            verge += 1;
            assert_eq!(p[3], 1.0, "verge surfel at {x},{y} has no prior");
            assert!((p[2] - 0.4).abs() < 0.01, "verge at {x},{y}: {}", p[2]);
        }
        if (-1.0..=-0.8).contains(&y) {
            kerb += 1;
            assert!(p[2].abs() < 0.01, "beside the car at {x},{y}: {}", p[2]);
        }
    }
    assert!(
        verge > 20 && kerb > 10,
        "{verge} verge and {kerb} kerb surfels"
    );
}
