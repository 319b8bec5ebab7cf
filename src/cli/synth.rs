//! `rogs synth`: writes a synthetic scene bundle with exact truth.

use super::progress::Progress;
use crate::bundle::write_zip;
use crate::synth::rig::PoseNoise;
use crate::synth::{generate, truth, world_and_poses, Preset, SynthConfig};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Mutex;

#[derive(clap::Args)]
pub struct Args {
    /// tiny (unit tests, 1 camera 64×48), demo (3 cameras, ~25 m), nuscenes-like
    /// (6 cameras at 800×225, 240 frames, ~200 m), highway (3.7 km of gently curving
    /// road, one 1241×376 camera; see --length-m), long (KITTI 00's size: 3.7 km in
    /// 4 541 frames of one 1241×376 camera, out along highway's road and back, so
    /// that it revisits every street; see --length-m) or revisit (demo's rig, several
    /// drives of one road: see --drive).
    #[arg(long, default_value = "tiny")]
    preset: Preset,
    /// Random seed: the same seed and settings give the same bundle, byte for byte.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output bundle (.zip). Optional with --truth-map: then no image is rendered.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also (or only) write the scene's truth as a map file (docs/MAP.md), at the
    /// truth resolution: a reference to compare a reconstruction with in the page.
    /// Written tile by tile, so a drive of any length fits in memory.
    #[arg(long)]
    truth_map: Option<PathBuf>,
    /// Trajectory length in metres (sets the number of frames at the preset's spacing).
    #[arg(long, conflicts_with = "frames")]
    length_m: Option<f64>,
    /// Standard deviation of the translation noise added to the written poses, metres per axis.
    #[arg(long, default_value_t = 0.0)]
    pose_noise_m: f64,
    /// Standard deviation of the rotation noise added to the written poses, degrees per axis.
    #[arg(long, default_value_t = 0.0)]
    pose_noise_deg: f64,
    /// Drift of the written poses at the last frame, metres (grows linearly from 0).
    #[arg(long)]
    drift_m: Option<f64>,
    /// Add a 32-beam spinning LiDAR sweep per frame.
    #[arg(long)]
    lidar: bool,
    /// Number of cameras, 1 to 6 (front, front_left, front_right, back, back_left, back_right).
    #[arg(long)]
    cameras: Option<usize>,
    /// Number of frames.
    #[arg(long)]
    frames: Option<usize>,
    /// Which drive of the revisit preset (1, 2, …): later drives start further on,
    /// a day later, with other exposures, parked cars and pose noise, in the same
    /// world frame; `rogs reconstruct d1.zip d2.zip` merges them.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=16))]
    drive: u64,
    /// Camera k fires k × this many milliseconds after the frame's pose (as nuScenes
    /// cameras fire along the LiDAR sweep); each view then carries its own pose.
    #[arg(long, default_value_t = 0.0)]
    camera_stagger_ms: f64,
    /// With --camera-stagger-ms, write only the frames' poses (every camera placed as
    /// if it fired with the first), to measure what per-view poses are worth.
    #[arg(long)]
    no_view_poses: bool,
    /// Image width in pixels.
    #[arg(long)]
    width: Option<u32>,
    /// Image height in pixels.
    #[arg(long)]
    height: Option<u32>,
    /// BEV truth resolution, metres per pixel.
    #[arg(long)]
    truth_resolution: Option<f64>,
    /// Rays per pixel along each axis (default 2, i.e. 4 rays per pixel; 1 is faster
    /// but aliased).
    #[arg(long)]
    rays_per_axis: Option<u32>,
    /// Leave the label images out: a drive without masks (the class table stays, to
    /// describe the truth), to measure what masks are worth.
    #[arg(long)]
    no_labels: bool,
    /// Also write a PNG contact sheet of some frames (images left, labels right).
    #[arg(long)]
    contact_sheet: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let mut cfg = SynthConfig::preset(a.preset, a.seed);
    cfg.lidar = a.lidar;
    cfg.noise = PoseNoise {
        translation_m: a.pose_noise_m,
        rotation_deg: a.pose_noise_deg,
        drift_m: a.drift_m.unwrap_or(a.pose_noise_m),
    };
    cfg.cameras = a.cameras.unwrap_or(cfg.cameras);
    cfg.frames = a.frames.unwrap_or(cfg.frames);
    cfg.camera_stagger_s = a.camera_stagger_ms / 1000.0;
    cfg.drive = a.drive as usize;
    if cfg.drive > 1 && cfg.preset != Preset::Revisit {
        return Err("--drive is for --preset revisit (other presets have one drive)".into());
    }
    cfg.view_poses = !a.no_view_poses;
    cfg.labels = !a.no_labels;
    if let Some(m) = a.length_m {
        if !(m.is_finite() && m > 0.0) {
            return Err(format!(
                "--length-m {m}: expected a positive length in metres"
            ));
        }
        cfg.set_length_m(m);
    }
    if a.out.is_none() && a.truth_map.is_none() {
        return Err(
            "nothing to write: give --out BUNDLE.zip and/or --truth-map MAP.rogsmap".into(),
        );
    }
    cfg.width = a.width.unwrap_or(cfg.width);
    cfg.height = a.height.unwrap_or(cfg.height);
    cfg.truth_resolution = a.truth_resolution.unwrap_or(cfg.truth_resolution);
    cfg.rays_per_axis = a.rays_per_axis.unwrap_or(cfg.rays_per_axis).max(1);
    let t0 = std::time::Instant::now();
    let bar = Mutex::new(Progress::new("rendering"));
    let report = |stage: &str, done: usize, total: usize| {
        if let Ok(mut b) = bar.lock() {
            b.set_message(stage);
            b.update(done, total);
        }
    };
    let name = format!("synthetic {:?} (seed {})", cfg.preset, cfg.seed);
    let scene = match &a.out {
        Some(out) => {
            let s = generate(&cfg, &report)?;
            if let Some(p) = &a.contact_sheet {
                contact_sheet(&s, 4)?
                    .save(p)
                    .map_err(|e| format!("{}: {e}", p.display()))?;
            }
            let bytes = write_zip(&s.manifest, &s.files)?;
            std::fs::write(out, &bytes).map_err(|e| format!("{}: {e}", out.display()))?;
            eprintln!(
                "wrote {} ({:.1} MiB, {} frames × {} cameras, {:.1} m) in {:.1} s",
                out.display(),
                bytes.len() as f64 / 1048576.0,
                cfg.frames,
                cfg.cameras,
                s.manifest.trajectory_length_m(),
                t0.elapsed().as_secs_f64()
            );
            (s.world, s.true_poses)
        }
        None => world_and_poses(&cfg, &report),
    };
    if let Some(p) = &a.truth_map {
        let t1 = std::time::Instant::now();
        let map = truth::map_file(
            &scene.0,
            &scene.1,
            &format!("{name}, truth"),
            cfg.corridor_half_width,
            cfg.truth_resolution,
            &mut |done, total| report("truth map tiles", done, total),
        )?;
        std::fs::write(p, &map).map_err(|e| format!("{}: {e}", p.display()))?;
        eprintln!(
            "wrote {} ({:.1} MiB, the truth at {} m per pixel over {:.1} m) in {:.1} s",
            p.display(),
            map.len() as f64 / 1048576.0,
            cfg.truth_resolution,
            cfg.trajectory_length(),
            t1.elapsed().as_secs_f64()
        );
    }
    if let Ok(b) = bar.into_inner() {
        b.finish();
    }
    Ok(ExitCode::SUCCESS)
}

/// Tiles every `step`-th frame's camera images (rows: frames, columns: cameras) and the
/// label images beside them, for a person to look at.
pub fn contact_sheet(
    out: &crate::synth::SynthOutput,
    rows: usize,
) -> Result<image::RgbImage, String> {
    let m = &out.manifest;
    let cam = &m.cameras[0];
    let (w, h) = (cam.width, cam.height);
    let cols = m.cameras.len() as u32;
    let step = (m.frames.len() / rows.max(1)).max(1);
    let picked: Vec<_> = m.frames.iter().step_by(step).take(rows).collect();
    let mut sheet = image::RgbImage::new(2 * cols * w, picked.len() as u32 * h);
    let colors: std::collections::HashMap<u8, [u8; 3]> =
        m.semantic_classes.iter().map(|c| (c.id, c.color)).collect();
    let find = |p: &str| {
        out.files
            .iter()
            .find(|(n, _)| n == p)
            .map(|f| f.1.as_slice())
    };
    for (r, f) in picked.iter().enumerate() {
        for (c, v) in f.views.iter().enumerate() {
            let rgb = image::load_from_memory(find(&v.image).ok_or("image missing")?)
                .map_err(|e| e.to_string())?
                .to_rgb8();
            // A drive without labels shows black beside its images.
            let lab = match v.label.as_deref() {
                Some(l) => image::load_from_memory(find(l).ok_or("label missing")?)
                    .map_err(|e| e.to_string())?
                    .to_luma8(),
                None => image::GrayImage::new(w, h),
            };
            let (x, y) = (c as u32 * w, r as u32 * h);
            image::imageops::replace(&mut sheet, &rgb, x as i64, y as i64);
            let col = image::RgbImage::from_fn(w, h, |i, j| {
                image::Rgb(
                    colors
                        .get(&lab.get_pixel(i, j).0[0])
                        .copied()
                        .unwrap_or([0, 0, 0]),
                )
            });
            image::imageops::replace(&mut sheet, &col, (x + cols * w) as i64, y as i64);
        }
    }
    Ok(sheet)
}
