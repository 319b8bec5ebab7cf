//! `rogs import kitti|nuscenes`: dataset layouts → validated scene bundles.

use super::progress::Progress;
use super::EXIT_INVALID_INPUT;
use crate::import::kitti::{self, Classes, KittiOptions};
use crate::import::nuscenes::{self, NuScenesOptions};
use crate::import::{ImportError, Imported};
use std::ops::Range;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    dataset: Dataset,
}

#[derive(clap::Subcommand)]
enum Dataset {
    /// KITTI odometry (development-kit layout): one camera, poses, optional velodyne.
    ///
    /// Reads ROOT/poses/NN.txt, ROOT/sequences/NN/calib.txt and image_0 (or image_2).
    /// The vehicle frame is put on the road under camera 0, --camera-height below it;
    /// the world is the vehicle frame of the first imported frame. See docs/IMPORT.md.
    Kitti(KittiArgs),
    /// nuScenes: one scene, six cameras and LIDAR_TOP, from the devkit JSON tables.
    ///
    /// Keyframes (2 Hz) by default, camera sweeps (12 Hz) with --sweeps. All views of a
    /// frame use CAM_FRONT's ego pose (the importer reports how far the other cameras'
    /// poses are from it). See docs/IMPORT.md.
    Nuscenes(NuScenesArgs),
}

#[derive(clap::Args)]
struct KittiArgs {
    /// Dataset root, holding poses/ and sequences/.
    root: PathBuf,
    /// Sequence number, as its folder is named (00 … 21).
    #[arg(long)]
    sequence: String,
    /// Output bundle (.zip).
    #[arg(long)]
    out: PathBuf,
    /// Camera: 0 (left grey) or 2 (left colour).
    #[arg(long, default_value_t = 0)]
    camera: u8,
    /// Frames to import, as pose-file rows: A..B (B excluded), A..=B, A.. or ..B.
    #[arg(long, value_parser = parse_range)]
    frames: Option<Range<usize>>,
    /// Folder with one 8-bit label PNG per frame, named like the images (a relative
    /// path is tried from here, then under ROOT).
    #[arg(long)]
    labels: Option<PathBuf>,
    /// Class table of the labels: a JSON file of bundle semantic classes, or the
    /// preset `twinlitenet` (0 other, 1 road, 2 lane marking).
    #[arg(long)]
    classes: Option<Classes>,
    /// Also import velodyne/*.bin through calib.txt's Tr.
    #[arg(long)]
    velodyne: bool,
    /// Camera 0's height above the road, metres.
    #[arg(long, default_value_t = kitti::DEFAULT_CAMERA_HEIGHT_M)]
    camera_height: f64,
}

#[derive(clap::Args)]
struct NuScenesArgs {
    /// Dataset root, holding samples/, sweeps/ and the VERSION folder of tables.
    root: PathBuf,
    /// Table folder under ROOT.
    #[arg(long, default_value = "v1.0-mini")]
    version: String,
    /// Scene name, e.g. scene-0655.
    #[arg(long)]
    scene: String,
    /// Output bundle (.zip).
    #[arg(long)]
    out: PathBuf,
    /// Mask2Former Mapillary-Vistas masks: DIR/seg_CAM_FRONT/<image stem>.png (or
    /// RoGS's DIR/samples/seg_CAM_FRONT/…), remapped to road, lane marking, curb, …
    #[arg(long)]
    labels: Option<PathBuf>,
    /// Camera channels, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "CAM_FRONT,CAM_FRONT_LEFT,CAM_FRONT_RIGHT,CAM_BACK,CAM_BACK_LEFT,CAM_BACK_RIGHT"
    )]
    cameras: Vec<String>,
    /// Also import the camera sweeps (non-keyframe images, 12 Hz).
    #[arg(long)]
    sweeps: bool,
}

/// `A..B`, `A..=B`, `A..`, `..B`.
fn parse_range(s: &str) -> Result<Range<usize>, String> {
    let bad = || format!("{s:?}: expected A..B (B excluded), A..=B, A.. or ..B");
    let (a, b) = s.split_once("..").ok_or_else(bad)?;
    let num = |t: &str, default: usize| {
        if t.is_empty() {
            Ok(default)
        } else {
            t.parse::<usize>().map_err(|_| bad())
        }
    };
    let start = num(a, 0)?;
    let end = match b.strip_prefix('=') {
        Some(b) => num(b, usize::MAX - 1)? + 1,
        None => num(b, usize::MAX)?,
    };
    Ok(start..end)
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let t0 = std::time::Instant::now();
    let mut bar = Progress::new("importing");
    let mut progress = |stage: &str, done: usize, total: usize| {
        bar.set_message(stage);
        bar.update(done, total);
    };
    let result = match a.dataset {
        Dataset::Kitti(k) => {
            let opts = KittiOptions {
                root: k.root,
                sequence: k.sequence,
                out: k.out,
                camera: k.camera,
                frames: k.frames,
                labels: k.labels,
                classes: k.classes,
                velodyne: k.velodyne,
                camera_height: k.camera_height,
            };
            kitti::import(&opts, &mut progress)
        }
        Dataset::Nuscenes(n) => {
            let opts = NuScenesOptions {
                root: n.root,
                version: n.version,
                scene: n.scene,
                out: n.out,
                labels: n.labels,
                cameras: n.cameras,
                sweeps: n.sweeps,
            };
            nuscenes::import(&opts, &mut progress)
        }
    };
    bar.finish();
    match result {
        Ok(done) => {
            report(&done, t0.elapsed().as_secs_f64());
            Ok(ExitCode::SUCCESS)
        }
        Err(ImportError::Input(e)) => {
            // The dataset is missing or malformed: the user's to fix.
            eprintln!("error: {e}");
            Ok(ExitCode::from(EXIT_INVALID_INPUT))
        }
        Err(ImportError::Invalid { problems, partial }) => {
            eprintln!(
                "error: the imported bundle is invalid (kept as {} for inspection): {problems}",
                partial.display()
            );
            Ok(ExitCode::from(EXIT_INVALID_INPUT))
        }
    }
}

fn report(done: &Imported, seconds: f64) {
    for w in &done.warnings {
        eprintln!("warning: {w}");
    }
    let m = &done.manifest;
    eprintln!(
        "wrote {} ({:.1} MiB, {} frames × {} camera(s){}, {:.1} m) in {:.1} s",
        done.path.display(),
        done.bytes as f64 / 1048576.0,
        m.frames.len(),
        m.cameras.len(),
        if m.lidar.is_some() { ", LiDAR" } else { "" },
        m.trajectory_length_m(),
        seconds
    );
}
