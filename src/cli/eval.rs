//! `rogs eval BUNDLE`: scores a predicted BEV map against the bundle's truth (or, when
//! it has none, against the LiDAR pseudo-ground-truth).

use super::EXIT_INVALID_INPUT;
use crate::bundle::{Bundle, Limits};
use crate::eval::pseudo_gt::{lidar_cloud, rasterise};
use crate::eval::{evaluate, road_classes, BevRaster, Metrics};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct Args {
    /// The scene bundle (.zip or folder).
    bundle: PathBuf,
    /// Prediction folder: bev.json ({"origin":[x_west,y_north],"resolution":m,
    /// "width":w,"height":h}), rgb.png, semantic_ids.png, elevation.f32 (raw
    /// little-endian float32), optional valid.png and surfel_centres.f32 (x,y,z float32
    /// triples; without it the elevation raster's valid pixel centres are used).
    #[arg(long)]
    pred: Option<PathBuf>,
    /// Score the LiDAR pseudo-ground-truth itself against the BEV truth (a check of
    /// the reference used for bundles without truth).
    #[arg(long)]
    pseudo_gt: bool,
    /// Resolution of the pseudo-ground-truth raster when the bundle has no truth.
    #[arg(long, default_value_t = 0.05)]
    resolution: f64,
    /// `paper`: also score the map against the paper's reference, the LiDAR
    /// pseudo-ground-truth through the bundle's own poses (even where the bundle has
    /// truth), rasterised on the map's grid, as the paper's evaluation code scores
    /// it and corrected:
    /// `metrics.paper_protocol` (docs/QUALITY.md says how the two differ). Needs LiDAR.
    #[arg(long, value_parser = ["paper"])]
    protocol: Option<String>,
}

#[derive(Deserialize)]
struct Geometry {
    origin: [f64; 2],
    resolution: f64,
    width: u32,
    height: u32,
}

fn load_pred(dir: &Path) -> Result<(BevRaster, Vec<[f64; 3]>), String> {
    let read = |name: &str| {
        std::fs::read(dir.join(name)).map_err(|e| format!("{}: {e}", dir.join(name).display()))
    };
    let g: Geometry =
        serde_json::from_slice(&read("bev.json")?).map_err(|e| format!("bev.json: {e}"))?;
    let mut r = BevRaster::empty(g.origin, g.resolution, g.width, g.height);
    let img = |name: &str| -> Result<image::DynamicImage, String> {
        let im = image::load_from_memory(&read(name)?).map_err(|e| format!("{name}: {e}"))?;
        if (im.width(), im.height()) != (g.width, g.height) {
            return Err(format!(
                "{name}: {}×{}, expected {}×{} from bev.json",
                im.width(),
                im.height(),
                g.width,
                g.height
            ));
        }
        Ok(im)
    };
    r.rgb = img("rgb.png")?.to_rgb8();
    r.class_ids = img("semantic_ids.png")?.to_luma8();
    let z = read("elevation.f32")?;
    if z.len() != 4 * (g.width * g.height) as usize {
        return Err(format!(
            "elevation.f32: {} bytes, expected {}",
            z.len(),
            4 * g.width * g.height
        ));
    }
    r.elevation = bytemuck::pod_collect_to_vec(&z);
    r.valid = if dir.join("valid.png").exists() {
        img("valid.png")?.to_luma8()
    } else {
        image::GrayImage::from_pixel(g.width, g.height, image::Luma([255]))
    };
    let points = if dir.join("surfel_centres.f32").exists() {
        let f: Vec<f32> = bytemuck::pod_collect_to_vec(&read("surfel_centres.f32")?);
        f.chunks_exact(3)
            .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
            .collect()
    } else {
        let mut pts = Vec::new();
        for row in 0..r.height {
            for col in 0..r.width {
                if r.is_valid(col, row) {
                    let (x, y) = r.centre(col, row);
                    pts.push([x, y, r.elevation_at(col, row) as f64]);
                }
            }
        }
        pts
    };
    Ok((r, points))
}

pub fn run(a: Args) -> Result<ExitCode, String> {
    let bundle = match Bundle::open(&a.bundle, Limits::default(), &mut |_, _| {}) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("{}: invalid bundle: {e}", a.bundle.display());
            return Ok(ExitCode::from(EXIT_INVALID_INPUT));
        }
    };
    let road = road_classes(&bundle.manifest);
    let truth = BevRaster::from_bundle(&bundle).map_err(|e| e.to_string())?;
    let metrics: Metrics = if a.pseudo_gt {
        let truth = truth.ok_or("--pseudo-gt needs a bundle with ground_truth to compare with")?;
        let cloud = lidar_cloud(&bundle).map_err(|e| e.to_string())?;
        if cloud.points.is_empty() {
            return Err(
                "the bundle has no LiDAR: the pseudo-ground-truth needs LiDAR sweeps".into(),
            );
        }
        let pseudo = rasterise(&cloud, &truth);
        let mut m = evaluate(&pseudo, &cloud.points, &truth, &road);
        m.psnr_db = crate::eval::psnr(&pseudo, &truth);
        m
    } else {
        let dir = a
            .pred
            .as_ref()
            .ok_or("give --pred DIR (a predicted BEV map) or --pseudo-gt")?;
        let (pred, points) = load_pred(dir)?;
        let mut m = crate::eval::score(&bundle, truth.as_ref(), &pred, &points, a.resolution)
            .map_err(|e| e.to_string())?
            .ok_or("the bundle has neither ground truth nor LiDAR: nothing to evaluate against")?;
        if let Some(t) = &truth {
            m.vs_reference =
                crate::eval::vs_reference(&bundle, t, &pred).map_err(|e| e.to_string())?;
        }
        if a.protocol.is_some() {
            m.paper_protocol = Some(
                crate::eval::paper_protocol(&bundle, &pred, &points)
                    .map_err(|e| e.to_string())?
                    .ok_or(
                        "--protocol paper scores against LiDAR, and the bundle has no LiDAR points",
                    )?,
            );
        }
        m
    };
    println!(
        "{}",
        serde_json::to_string_pretty(&serde_json::json!({ "metrics": metrics }))
            .map_err(|e| e.to_string())?
    );
    Ok(ExitCode::SUCCESS)
}
