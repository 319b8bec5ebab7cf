//! Evaluation: BEV rasters, the paper's metrics, and the LiDAR pseudo-ground-truth.

pub mod metrics;
pub mod pseudo_gt;
pub mod raster;

pub use metrics::{
    elevation_vs_points, elevation_vs_raster, error_stats, miou, psnr, ErrorStats, Metrics,
};
pub use raster::BevRaster;

use crate::bundle::{ClassRole, Manifest};

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
    Metrics {
        psnr_db: psnr(pred, reference),
        miou: miou(pred, reference, road),
        elevation_rmse_m: e.map(|e| e.rmse),
        elevation_mae_m: e.map(|e| e.mae),
        elevation_p95_m: e.map(|e| e.p95),
    }
}
