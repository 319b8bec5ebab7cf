//! Stage 5: the loss. Per view, a masked L1 on RGB and a cross-entropy on the
//! semantic logits (`photometric`, kernel `shaders/loss.wgsl`); per surfel, the
//! smoothness, trajectory-prior and LiDAR terms (`regularise`, kernel
//! `shaders/regularise.wgsl`). `targets` turns a bundle's image and label into the
//! packed per-pixel target with the loss mask.

pub mod photometric;
pub mod regularise;
pub mod targets;

use serde::Serialize;

/// Loss weights. Defaults follow the official RoGS configuration for nuScenes
/// (segmentation 0.06, smoothness 0.003, LiDAR z 0.02); the trajectory prior, which
/// the official code does not have, is weighted so that a surfel seen by no camera
/// stays near the pose prior.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LossConfig {
    /// Masked L1 on RGB (mean over masked pixels and channels).
    pub rgb: f32,
    /// Cross-entropy on the semantic logits (mean over masked pixels).
    pub ce: f32,
    /// Squared height difference to grid neighbours (sum over edges).
    pub smooth: f32,
    /// Confidence-weighted Huber distance to the pose prior ẑ (sum over surfels).
    pub traj: f32,
    /// Huber width of the trajectory term, metres.
    pub huber_m: f32,
    /// Squared distance to the LiDAR elevation under the surfel (the median of the
    /// points within `lidar_radius_m` in xy; sum over surfels with one); 0 disables it.
    pub lidar: f32,
    /// LiDAR points within this xy distance of a surfel count for it, metres.
    pub lidar_radius_m: f32,
    /// LiDAR points farther than this from the pose prior ẑ are not road (walls,
    /// roofs), metres.
    pub lidar_gate_m: f32,
    /// Of the points left, those farther than this from the surfel's lowest layer
    /// (their lower quartile) are not road either (the sides of cars), metres.
    pub lidar_band_m: f32,
    /// Pixels with rendered alpha below this are left out (nothing covers them).
    pub min_alpha: f32,
    /// The road mask is opened with a square of this side (pixels).
    pub open_px: u32,
    /// Ignore classes are dilated by a square of this side (pixels).
    pub dilate_px: u32,
    /// Robust weighting of the RGB term: a pixel with mean residual r weighs
    /// 1 / (1 + (r/c)²) (cars, people and moving shadows inside the mask of a drive
    /// without labels); 0 (the default) disables it. Measured on parked cars it
    /// costs 0.2–0.3 dB (docs/QUALITY.md): it pays only where things move.
    pub robust_c: f32,
}

impl Default for LossConfig {
    fn default() -> Self {
        Self {
            rgb: 1.0,
            ce: 0.06,
            smooth: 0.003,
            traj: 0.01,
            huber_m: 0.05,
            lidar: 0.02,
            lidar_radius_m: 0.2,
            lidar_gate_m: 0.5,
            lidar_band_m: 0.2,
            min_alpha: 0.5,
            open_px: 5,
            dilate_px: 10,
            robust_c: 0.0,
        }
    }
}
