//! Evaluation: BEV rasters, the paper's metrics, and the LiDAR pseudo-ground-truth.

pub mod metrics;
pub mod pseudo_gt;
pub mod raster;

pub use metrics::{
    class_iou, elevation_datum, elevation_vs_points, elevation_vs_raster, error_stats, miou,
    paper_psnr, psnr, ElevationDatum, ErrorStats, Metrics, PaperProtocol, Tally, VsReference,
};
pub use raster::BevRaster;

use crate::bundle::{Bundle, ClassRole, Manifest, Problem};

/// Ids of the classes with role `road`: none for a drive without labels, whose map
/// has no semantic layer to score (its mIoU is null).
pub fn road_classes(m: &Manifest) -> Vec<u8> {
    if !m.labelled() {
        return Vec::new();
    }
    m.semantic_classes
        .iter()
        .filter(|c| c.role == ClassRole::Road)
        .map(|c| c.id)
        .collect()
}

/// All metrics of a predicted raster (and surfel centres) against a reference raster.
pub fn evaluate(
    pred: &BevRaster,
    points: &[[f64; 3]],
    reference: &BevRaster,
    road: &[u8],
) -> Metrics {
    let e = elevation_vs_raster(points, reference);
    metrics::Tally::of(pred, reference).metrics(road, e)
}

/// Scores a prediction against the bundle's truth raster, or, without one, against
/// the LiDAR pseudo-ground-truth at `resolution` (elevation at surfel centres against
/// the nearest LiDAR point within 0.1 m). `None` when the bundle has neither.
pub fn score(
    b: &Bundle,
    truth: Option<&BevRaster>,
    pred: &BevRaster,
    points: &[[f64; 3]],
    resolution: f64,
) -> Result<Option<Metrics>, Problem> {
    let road = road_classes(&b.manifest);
    if let Some(t) = truth {
        return Ok(Some(evaluate(pred, points, t, &road)));
    }
    let cloud = match pseudo_gt::lidar_cloud(b) {
        // A lazily read bundle holds one tile's files, not every sweep and image.
        Err(Problem::NotLoaded { .. }) => return Ok(None),
        r => r?,
    };
    let Some(grid) = pseudo_gt::cloud_grid(&cloud, resolution) else {
        return Ok(None);
    };
    let reference = pseudo_gt::rasterise(&cloud, &grid);
    let mut m = evaluate(pred, &[], &reference, &road);
    let e = elevation_vs_points(points, &cloud.points, 0.1);
    m.elevation_rmse_m = e.map(|e| e.rmse);
    m.elevation_mae_m = e.map(|e| e.mae);
    m.elevation_p95_m = e.map(|e| e.p95);
    m.paper_protocol = Some(paper_scores(&cloud, pred, m.elevation_rmse_m, &road));
    Ok(Some(m))
}

/// The map against the paper's LiDAR pseudo-ground-truth through the bundle's own
/// poses, rasterised on the map's own grid (`PaperProtocol`), whether or not the
/// bundle has BEV truth; `None` without LiDAR points, or when a lazily read bundle
/// does not hold every sweep and image.
pub fn paper_protocol(
    b: &Bundle,
    pred: &BevRaster,
    points: &[[f64; 3]],
) -> Result<Option<PaperProtocol>, Problem> {
    let cloud = match pseudo_gt::lidar_cloud(b) {
        Err(Problem::NotLoaded { .. }) => return Ok(None),
        r => r?,
    };
    if cloud.points.is_empty() {
        return Ok(None);
    }
    let elevation = elevation_vs_points(points, &cloud.points, 0.1).map(|e| e.rmse);
    Ok(Some(paper_scores(
        &cloud,
        pred,
        elevation,
        &road_classes(&b.manifest),
    )))
}

/// `PaperProtocol`: the cloud rasterised on the map's grid, as the paper renders its
/// reference over the map's extent, and the map scored against it both ways
/// (`elevation_rmse_m`: the surfel centres against the cloud, which the caller may
/// already hold).
fn paper_scores(
    cloud: &pseudo_gt::LidarCloud,
    pred: &BevRaster,
    elevation_rmse_m: Option<f64>,
    road: &[u8],
) -> PaperProtocol {
    let reference = pseudo_gt::rasterise(cloud, pred);
    let shared = Tally::of(pred, &reference);
    PaperProtocol {
        raster_cells: (pred.width * pred.height) as usize,
        cells: shared.covered() as usize,
        paper_psnr_db: paper_psnr(pred, &reference),
        psnr_db: shared.psnr(),
        miou: shared.miou(road),
        elevation_rmse_m,
    }
}

/// The map `pred` against the exact-pose reference (`VsReference`), when the bundle
/// keeps its exact poses (`ground_truth.poses`) and has LiDAR; `None` otherwise, or
/// when a lazily read bundle does not hold every sweep and image. Per-view poses are
/// replaced by their frame's exact pose.
pub fn vs_reference(
    b: &Bundle,
    truth: &BevRaster,
    pred: &BevRaster,
) -> Result<Option<VsReference>, Problem> {
    if b.manifest.lidar.is_none() {
        return Ok(None);
    }
    // A lazily read bundle holds one tile's files, not every sweep and image.
    let poses = match b.read_true_poses() {
        Err(Problem::NotLoaded { .. }) | Ok(None) => return Ok(None),
        r => r?.unwrap_or_default(),
    };
    let mut m = b.manifest.clone();
    for (f, p) in m.frames.iter_mut().zip(&poses) {
        f.vehicle_to_world = *p;
        for v in &mut f.views {
            v.vehicle_to_world = None;
        }
    }
    let cloud = match pseudo_gt::lidar_cloud_in(b, &m) {
        Err(Problem::NotLoaded { .. }) => return Ok(None),
        r => r?,
    };
    let reference = pseudo_gt::rasterise(&cloud, truth);
    // The cells both score: the truth's cells that the reference covers and the
    // map covers too, so the map and the reference are scored over the same cells
    // (a map of a narrower corridor than the LiDAR's reach is not charged with, nor
    // compared against the reference on, the cells it does not map).
    let mut cells = truth.clone();
    let mut reference_cells = 0;
    for r in 0..cells.height {
        for c in 0..cells.width {
            if !cells.is_valid(c, r) {
                continue;
            }
            let in_ref = reference.is_valid(c, r);
            reference_cells += usize::from(in_ref);
            let (x, y) = cells.centre(c, r);
            let in_map = pred.pixel_of(x, y).is_some_and(|p| pred.is_valid(p.0, p.1));
            if !(in_ref && in_map) {
                cells.valid.put_pixel(c, r, image::Luma([0]));
            }
        }
    }
    let road = road_classes(&b.manifest);
    let (map, refr) = (Tally::of(pred, &cells), Tally::of(&reference, &cells));
    Ok(Some(VsReference {
        cells: cells.valid.pixels().filter(|p| p.0[0] != 0).count(),
        reference_cells,
        map_psnr_db: map.psnr(),
        map_miou: map.miou(&road),
        ref_psnr_db: refr.psnr(),
        ref_miou: refr.miou(&road),
        map_iou_per_class: map.class_iou(&road).into_iter().collect(),
        ref_iou_per_class: refr.class_iou(&road).into_iter().collect(),
    }))
}
