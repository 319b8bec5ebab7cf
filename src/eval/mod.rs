//! Evaluation: BEV rasters, the paper's metrics, and the LiDAR pseudo-ground-truth.

pub mod metrics;
pub mod pseudo_gt;
pub mod raster;

pub use metrics::{
    class_iou, elevation_vs_points, elevation_vs_raster, error_stats, miou, psnr, ErrorStats,
    Metrics, Tally,
};
pub use raster::BevRaster;

use crate::bundle::{Bundle, ClassRole, Manifest, Problem};

/// Ids of the classes with role `road`.
pub fn road_classes(m: &Manifest) -> Vec<u8> {
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
    Ok(Some(m))
}
