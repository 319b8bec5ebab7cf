//! `rogs synth`: synthetic road scenes with exact truth.
//!
//! A procedural road (`road.rs`) is sampled into a true heightfield (`field.rs`);
//! parked cars and the sky complete the world (`world.rs`); an independent CPU ray
//! caster (`raycast.rs`) renders each camera of a rig (`rig.rs`) from the *true*
//! poses, while the bundle receives the poses with the configured noise. The bundle
//! carries BEV truth rasters (`truth.rs`) so that reconstructions can be scored.

pub mod classes;
pub mod field;

pub mod raycast;
pub mod rig;
pub mod rng;
pub mod road;
pub mod truth;
pub mod world;

use crate::bundle::example::{png_gray, png_rgb};
use crate::bundle::{
    BundleFile, Camera, Frame, GroundTruth, LidarSensor, Manifest, Mat4Rows, View, FORMAT, VERSION,
};
use raycast::{render, Exposure};
use rig::{camera_to_vehicle, lidar_sweep, mul, noisy_poses, PoseNoise};
use rng::Rng;
use road::RoadSpec;
use world::World;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// Unit tests: one 64×48 camera, 8 frames; generates in well under a second.
    Tiny,
    /// The page's embedded demo: 3 cameras, ~25 m of road (~300 m² of corridor).
    Demo,
    /// The performance reference: 6 cameras at 800×225, 240 frames, ~200 m of road.
    NuscenesLike,
    /// 3.7 km of two-lane road with gentle curves (no turn: a slim bounding box), one
    /// forward camera at KITTI's 1241×376, a frame every metre, 10 cm height field.
    /// For scaling runs (`--length-m` shortens it) and map-viewer benchmarks.
    Highway,
    /// KITTI odometry 00's size: a 3.7 km drive of 4 541 frames, one forward camera
    /// at 1241×376, that revisits its own streets: it drives `highway`'s road out
    /// and back (a U-turn at the far end, then the opposite lane home), so every
    /// place is seen on two passes, in opposite directions, 1.85 km of drive apart.
    /// `--length-m` shortens it.
    Long,
    /// `demo`'s rig on a road twice as long, driven several times (`drive` 1, 2, …):
    /// each drive starts 40 % of a trajectory further on, at another time, with
    /// other camera exposures, other parked cars and other pose noise, in one world
    /// frame: several drives of the same streets for one map.
    Revisit,
}

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "tiny" => Ok(Preset::Tiny),
            "demo" => Ok(Preset::Demo),
            "nuscenes-like" => Ok(Preset::NuscenesLike),
            "highway" => Ok(Preset::Highway),
            "long" => Ok(Preset::Long),
            "revisit" => Ok(Preset::Revisit),
            _ => Err(format!(
                "unknown preset {s:?}; expected tiny, demo, nuscenes-like, highway, long or revisit"
            )),
        }
    }
}

/// Everything that defines a synthetic scene. Start from `SynthConfig::preset`.
#[derive(Clone, Debug)]
pub struct SynthConfig {
    pub preset: Preset,
    pub seed: u64,
    pub frames: usize,
    /// Distance between frames along the road (m); at `speed_mps` this sets the rate.
    pub frame_spacing_m: f64,
    pub speed_mps: f64,
    pub cameras: usize,
    pub width: u32,
    pub height: u32,
    /// Rays per pixel along each axis (2 → 4 rays per pixel).
    pub rays_per_axis: u32,
    pub lidar: bool,
    pub noise: PoseNoise,
    /// BEV truth resolution (m/pixel) and corridor half-width around the trajectory.
    pub truth_resolution: f64,
    pub corridor_half_width: f64,
    /// Cell of the true heightfield raster (m).
    pub field_cell: f64,
    /// Camera c fires `c · camera_stagger_s` seconds after the frame's pose (as
    /// nuScenes cameras fire along the LiDAR sweep); 0: all at once.
    pub camera_stagger_s: f64,
    /// With a stagger, write each view's own pose (`views[].vehicle_to_world`); false
    /// writes only the frames' poses, as if every camera fired with the first.
    pub view_poses: bool,
    /// Which drive of a `revisit` scene (1, 2, …); other presets have one.
    pub drive: usize,
    /// Write the views' label images; false makes a drive without masks (the
    /// class table stays, for the truth).
    pub labels: bool,
}

impl SynthConfig {
    pub fn preset(preset: Preset, seed: u64) -> Self {
        let base = SynthConfig {
            preset,
            seed,
            frames: 8,
            frame_spacing_m: 1.0,
            speed_mps: 10.0,
            cameras: 1,
            width: 64,
            height: 48,
            rays_per_axis: 2,
            lidar: false,
            noise: PoseNoise::default(),
            truth_resolution: 0.1,
            corridor_half_width: 6.0,
            field_cell: 0.04,
            camera_stagger_s: 0.0,
            view_poses: true,
            drive: 1,
            labels: true,
        };
        match preset {
            Preset::Tiny => base,
            // `revisit` drives `demo`'s rig (on a longer road, see `road_spec`).
            Preset::Demo | Preset::Revisit => SynthConfig {
                frames: 26,
                cameras: 3,
                width: 192,
                height: 108,
                truth_resolution: 0.05,
                ..base
            },
            Preset::NuscenesLike => SynthConfig {
                frames: 240,
                frame_spacing_m: 0.84,
                cameras: 6,
                width: 800,
                height: 225,
                truth_resolution: 0.05,
                corridor_half_width: 8.0,
                field_cell: 0.05,
                ..base
            },
            Preset::Long => SynthConfig {
                preset,
                frames: 4541,
                frame_spacing_m: 3700.0 / 4540.0,
                ..Self::preset(Preset::Highway, seed)
            },
            Preset::Highway => SynthConfig {
                frames: 3701,
                width: 1241,
                height: 376,
                truth_resolution: 0.05,
                field_cell: 0.1,
                ..base
            },
        }
    }

    /// Sets the frame count for a trajectory of `m` metres.
    pub fn set_length_m(&mut self, m: f64) {
        self.frames = ((m / self.frame_spacing_m).round() as usize + 1).max(2);
    }

    pub fn trajectory_length(&self) -> f64 {
        (self.frames.max(2) - 1) as f64 * self.frame_spacing_m
    }

    /// Arc length where the trajectory starts (room behind for rear cameras); later
    /// drives of `revisit` start 40 % of a trajectory further on each.
    fn start_s(&self) -> f64 {
        ROAD_START + self.drive.saturating_sub(1) as f64 * 0.4 * self.trajectory_length()
    }

    /// The trajectory length the road is built for: `revisit`'s holds three drives.
    fn road_trajectory_length(&self) -> f64 {
        match self.preset {
            Preset::Revisit => 2.0 * self.trajectory_length(),
            // Out and back: the road is half the drive.
            Preset::Long => 0.5 * self.trajectory_length(),
            _ => self.trajectory_length(),
        }
    }

    /// Where the vehicle is after `d` metres of drive: the arc length on the road and
    /// whether it drives back (`long` turns round halfway, into the other lane).
    pub fn arc_of(&self, d: f64) -> (f64, bool) {
        let s0 = self.start_s();
        match self.preset {
            Preset::Long if d > self.road_trajectory_length() => {
                (s0 + self.trajectory_length() - d, true)
            }
            _ => (s0 + d, false),
        }
    }

    /// A random stream of this drive (the first drive's are the preset's own).
    fn drive_rng(&self, rng: &Rng, key: u64) -> Rng {
        rng.fork(key + 0x1000 * self.drive.saturating_sub(1) as u64)
    }
}

/// A generated scene: the bundle plus the truth a test may want beyond it.
pub struct SynthOutput {
    pub manifest: Manifest,
    pub files: Vec<BundleFile>,
    /// The poses the images were rendered from (the manifest has the noisy ones).
    pub true_poses: Vec<Mat4Rows>,
    pub world: World,
}

/// The camera rig, in the nuScenes order; a config with n cameras takes the first n.
/// (name, yaw°, position in the vehicle frame, horizontal field of view°)
const RIG: [(&str, f64, [f64; 3], f64); 6] = [
    ("front", 0.0, [1.7, 0.0, 1.5], 64.0),
    ("front_left", 55.0, [1.5, 0.5, 1.5], 64.0),
    ("front_right", -55.0, [1.5, -0.5, 1.5], 64.0),
    ("back", 180.0, [-0.5, 0.0, 1.5], 90.0),
    ("back_left", 110.0, [1.0, 0.6, 1.5], 64.0),
    ("back_right", -110.0, [1.0, -0.6, 1.5], 64.0),
];

/// Arc length of the first drive's first pose.
const ROAD_START: f64 = 20.0;

/// The road for a config: straights and arcs (and a 90° turn on long scenes), a speed
/// table, a crosswalk with stop line and a manhole where the cameras see them.
pub fn road_spec(cfg: &SynthConfig) -> RoadSpec {
    let s0 = ROAD_START;
    let lt = cfg.road_trajectory_length();
    let total = s0 + lt + 45.0;
    let pieces = if matches!(cfg.preset, Preset::Highway | Preset::Long) {
        // Curves of 12 km radius: over 3.7 km the road drifts about 100 m sideways,
        // so its bounding box, and the height field over it, stay slim.
        let p = total / 5.0;
        vec![
            (p, 0.0),
            (p, 1.0 / 12000.0),
            (p, 0.0),
            (p, -1.0 / 12000.0),
            (p, 0.0),
        ]
    } else if total >= 150.0 {
        let turn = 20.0 * std::f64::consts::FRAC_PI_2;
        let a = 0.22 * total;
        let b = 0.15 * total;
        let c = 0.12 * total;
        vec![
            (a, 0.0),
            (b, 1.0 / 60.0),
            (c, 0.0),
            (turn, -1.0 / 20.0),
            (total - a - b - c - turn, 0.0),
        ]
    } else {
        vec![
            (0.35 * total, 0.0),
            (0.35 * total, 1.0 / 40.0),
            (0.3 * total, 0.0),
        ]
    };
    RoadSpec {
        seed: cfg.seed,
        pieces,
        slope: 0.02,
        crossfall: 0.02,
        vertical_curve_m: 0.25,
        curb_height: 0.12,
        bump: Some((s0 + 0.3 * lt + 4.0, 0.08)),
        crosswalk: Some(s0 + 0.6 * lt + 6.0),
        manhole: Some((s0 + 0.45 * lt + 3.0, 1.6)),
    }
}

/// Progress callback: (stage, done, total).
pub type Progress<'a> = &'a (dyn Fn(&str, usize, usize) + Sync);

/// The world (road, parked cars) and the true vehicle pose of every frame.
pub fn world_and_poses(cfg: &SynthConfig, progress: Progress) -> (World, Vec<Mat4Rows>) {
    let rng = Rng::new(cfg.seed);
    let road = road_spec(cfg);
    let s0 = cfg.start_s();
    let lt = cfg.trajectory_length();
    let mut cars = Vec::new();
    // Parked cars along the trajectory (`revisit`: along the whole road, other cars
    // on every drive).
    let (c0, lc) = match cfg.preset {
        Preset::Revisit => (ROAD_START, cfg.road_trajectory_length()),
        Preset::Long => (s0, cfg.road_trajectory_length()),
        _ => (s0, lt),
    };
    let mut crng = cfg.drive_rng(&rng, 0xca5);
    let mut s = c0 + 0.5 * lc.min(30.0) + 4.0;
    let mut side = 1.0;
    while s < c0 + lc + 30.0 {
        let albedo = [
            0.1 + 0.7 * crng.uniform(),
            0.1 + 0.5 * crng.uniform(),
            0.1 + 0.6 * crng.uniform(),
        ];
        cars.push((s, side * 2.45, 4.4, albedo));
        s += 22.0 + 20.0 * crng.uniform();
        side = -side;
    }
    progress("world", 0, 1);
    let world = World::new(road, cfg.field_cell, &cars);
    progress("world", 1, 1);

    let true_poses: Vec<Mat4Rows> = (0..cfg.frames)
        .map(|k| drive_pose(&world, cfg, k as f64 * cfg.frame_spacing_m))
        .collect();
    (world, true_poses)
}

/// The true vehicle pose after `d` metres of the drive.
fn drive_pose(world: &World, cfg: &SynthConfig, d: f64) -> Mat4Rows {
    let (s, back) = cfg.arc_of(d);
    rig::vehicle_pose_on(world, s, back)
}

/// Generates the scene. Deterministic for a config (and independent of thread count).
pub fn generate(cfg: &SynthConfig, progress: Progress) -> Result<SynthOutput, String> {
    if cfg.frames < 2
        || cfg.cameras == 0
        || cfg.cameras > RIG.len()
        || cfg.width == 0
        || cfg.height == 0
    {
        return Err(format!(
            "need at least 2 frames, 1 to {} cameras and a non-empty image size (got {} frames, {} cameras, {}×{})",
            RIG.len(),
            cfg.frames,
            cfg.cameras,
            cfg.width,
            cfg.height
        ));
    }
    let rng = Rng::new(cfg.seed);
    let (world, true_poses) = world_and_poses(cfg, progress);
    // Each drive's own pose noise (the first drive's is the preset's).
    let nrng = if cfg.drive > 1 {
        cfg.drive_rng(&rng, 0xd0)
    } else {
        rng.clone()
    };
    let poses = noisy_poses(&true_poses, cfg.noise, &nrng);
    let cameras: Vec<Camera> = RIG[..cfg.cameras]
        .iter()
        .map(|&(name, yaw, pos, hfov)| {
            let fx = cfg.width as f64 / 2.0 / (hfov.to_radians() / 2.0).tan();
            // nuScenes-like crops the top half: the horizon sits on the top edge.
            let (pitch, cy) = match cfg.preset {
                Preset::NuscenesLike => (0.0, 0.0),
                _ => (6.0, 0.3 * cfg.height as f64),
            };
            Camera {
                name: name.into(),
                width: cfg.width,
                height: cfg.height,
                fx,
                fy: fx,
                cx: cfg.width as f64 / 2.0,
                cy,
                camera_to_vehicle: camera_to_vehicle(yaw, pitch, pos),
                mask: None,
            }
        })
        .collect();
    let mut erng = cfg.drive_rng(&rng, 0xe0);
    let exposures: Vec<Exposure> = (0..cfg.cameras)
        .map(|c| {
            let (g, o) = (erng.uniform(), erng.uniform());
            if c == 0 && cfg.drive <= 1 {
                Exposure {
                    gain: 1.0,
                    offset: 0.0,
                }
            } else {
                Exposure {
                    gain: 0.85 + 0.3 * g,
                    offset: 0.06 * o - 0.03,
                }
            }
        })
        .collect();

    // Where each camera fired: its own true vehicle pose (and the frame's noise).
    let fired = |k: usize, c: usize| -> Mat4Rows {
        if cfg.camera_stagger_s == 0.0 || c == 0 {
            return true_poses[k];
        }
        let d = k as f64 * cfg.frame_spacing_m + c as f64 * cfg.camera_stagger_s * cfg.speed_mps;
        drive_pose(&world, cfg, d)
    };
    let views = cfg.frames * cfg.cameras;
    let done = std::sync::atomic::AtomicUsize::new(0);
    let images: Vec<(Vec<u8>, Vec<u8>)> = crate::par::par_map(views, |i| {
        let (k, c) = (i / cfg.cameras, i % cfg.cameras);
        let cam = &cameras[c];
        let view = raycast::View {
            width: cam.width,
            height: cam.height,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            cam_to_world: mul(&fired(k, c), &cam.camera_to_vehicle),
        };
        let (rgb, lab) = render(&world, &view, cfg.rays_per_axis, exposures[c]);
        let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        progress("images", n, views);
        (png_rgb(&rgb), png_gray(&lab))
    });

    let lidar_to_vehicle = rig::mat(
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0, 0.0, 1.8],
    );
    let sweeps: Vec<Vec<u8>> = if cfg.lidar {
        crate::par::par_map(cfg.frames, |k| {
            let pts = lidar_sweep(&world, &mul(&true_poses[k], &lidar_to_vehicle), 32, 0.6);
            pts.iter()
                .flat_map(|p| p.iter().flat_map(|v| v.to_le_bytes()))
                .collect()
        })
    } else {
        Vec::new()
    };

    let mut files = Vec::new();
    let mut frames = Vec::new();
    for (k, pose) in poses.iter().enumerate() {
        let mut fviews = Vec::new();
        for (c, cam) in cameras.iter().enumerate() {
            let image = format!("images/{}/{k:06}.png", cam.name);
            let label = format!("labels/{}/{k:06}.png", cam.name);
            // The view's own pose with the frame's noise: noisy · true⁻¹ · fired.
            let own = (cfg.view_poses && cfg.camera_stagger_s != 0.0 && c > 0)
                .then(|| mul(&mul(pose, &rig::inverse(&true_poses[k])), &fired(k, c)));
            fviews.push(View {
                camera: cam.name.clone(),
                image,
                label: cfg.labels.then_some(label),
                vehicle_to_world: own,
            });
        }
        let lidar = cfg.lidar.then(|| format!("lidar/{k:06}.bin"));
        frames.push(Frame {
            // Later drives of `revisit` are a day apart each.
            timestamp: k as f64 * cfg.frame_spacing_m / cfg.speed_mps
                + 86_400.0 * cfg.drive.saturating_sub(1) as f64,
            vehicle_to_world: *pose,
            views: fviews,
            lidar,
        });
    }
    for (i, (rgb, lab)) in images.into_iter().enumerate() {
        let v = &frames[i / cfg.cameras].views[i % cfg.cameras];
        files.push((v.image.clone(), rgb));
        if let Some(l) = &v.label {
            files.push((l.clone(), lab));
        }
    }
    for (k, bytes) in sweeps.into_iter().enumerate() {
        files.push((format!("lidar/{k:06}.bin"), bytes));
    }

    progress("truth", 0, 1);
    let gt = truth::rasters(
        &world,
        &true_poses,
        cfg.corridor_half_width,
        cfg.truth_resolution,
    );
    progress("truth", 1, 1);
    let ground_truth = GroundTruth {
        origin: gt.origin,
        resolution: cfg.truth_resolution,
        width: gt.width,
        height: gt.height,
        rgb: "truth/rgb.png".into(),
        class_ids: "truth/class_ids.png".into(),
        elevation: "truth/elevation.f32".into(),
        valid: "truth/valid.png".into(),
        poses: Some("truth/poses.json".into()),
    };
    // The exact poses: the bundle's frames carry them with the configured noise.
    files.push((
        "truth/poses.json".into(),
        serde_json::to_vec(&true_poses).unwrap_or_default(),
    ));
    files.push((ground_truth.rgb.clone(), png_rgb(&gt.rgb)));
    files.push((ground_truth.class_ids.clone(), png_gray(&gt.class_ids)));
    files.push((
        ground_truth.elevation.clone(),
        gt.elevation.iter().flat_map(|v| v.to_le_bytes()).collect(),
    ));
    files.push((ground_truth.valid.clone(), png_gray(&gt.valid)));

    let manifest = Manifest {
        format: FORMAT.into(),
        version: VERSION,
        name: match cfg.preset {
            Preset::Revisit => {
                format!("synthetic Revisit (seed {}), drive {}", cfg.seed, cfg.drive)
            }
            _ => format!("synthetic {:?} (seed {})", cfg.preset, cfg.seed),
        },
        vehicle_height_m: 0.0,
        semantic_classes: classes::table(),
        cameras,
        frames,
        lidar: cfg.lidar.then_some(LidarSensor {
            floats_per_point: 4,
            lidar_to_vehicle,
        }),
        ground_truth: Some(ground_truth),
        world_frame: None,
        corridor_half_width_m: None,
    };
    Ok(SynthOutput {
        manifest,
        files,
        true_poses,
        world,
    })
}

/// The page's embedded demo: `rogs synth --preset demo --seed 1 --lidar
/// --pose-noise-m 0.05 --pose-noise-deg 0.5 --truth-map …`, as the bundle's zip bytes
/// and the truth's map file. `npm start` makes it with the wasm engine in Node, so
/// that no native build is needed.
pub fn demo_scene() -> Result<(Vec<u8>, Vec<u8>), String> {
    let mut cfg = SynthConfig::preset(Preset::Demo, 1);
    cfg.lidar = true;
    cfg.noise = PoseNoise {
        translation_m: 0.05,
        rotation_deg: 0.5,
        drift_m: 0.05,
    };
    let out = generate(&cfg, &|_, _, _| {})?;
    let bundle = crate::bundle::write_zip(&out.manifest, &out.files)?;
    let map = truth::map_file(
        &out.world,
        &out.true_poses,
        &format!("synthetic {:?} (seed {}), truth", cfg.preset, cfg.seed),
        cfg.corridor_half_width,
        cfg.truth_resolution,
        &mut |_, _| {},
    )?;
    Ok((bundle, map))
}
