//! Stage 6: optimisation. Adam on the GPU (`adam`, kernel `shaders/adam.wgsl`), one
//! step per training image (`train`), epochs that visit every training image once in
//! a seeded shuffled order.

pub mod adam;
pub mod bench;
pub mod check;
pub mod gain;
pub mod pose;
pub mod train;

use crate::bundle::Manifest;
use crate::loss::LossConfig;
use crate::render::CullConfig;
use adam::LearningRates;
use serde::Serialize;

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrainConfig {
    /// Passes over the training images (the paper's "Ep.1" is one).
    pub epochs: usize,
    /// Seed of the image order.
    pub seed: u64,
    pub lr: LearningRates,
    pub loss: LossConfig,
    #[serde(skip)]
    pub cull: CullConfig,
    /// Use the LiDAR elevation term when the bundle has LiDAR.
    pub use_lidar: bool,
    /// Start the colours and classes from the best view's pixel where a surfel's
    /// LiDAR elevation puts it, rather than where the pose plane does (when the
    /// LiDAR term is on): a few centimetres of height move the pixel a surfel
    /// samples by decimetres. The IPM baseline keeps the pose plane's, and so does
    /// a run that refines its poses (such a start bakes each view's pose error in).
    pub lidar_colours: bool,
    /// Leave every K-th frame out of training (for held-out evaluation).
    pub holdout_every: Option<usize>,
    /// Stop after this many steps (benchmarks: time a part of an epoch).
    pub max_steps: Option<usize>,
    /// At most this many blocks of 256 surfels' Adam moments and logits per storage
    /// binding (tests and benchmarks of the windowed passes, `adam` and `gather`;
    /// `None`: as many as the adapter binds).
    #[serde(skip)]
    pub moment_window: Option<usize>,
    /// A view's pair buffers hold the most pairs its camera's views have had × this,
    /// so that a step needs no read-back of its pair count (train.rs); a view with
    /// more runs again with the exact count. Below 1 only in tests, to force that.
    pub pair_margin: f64,
    /// Which surfels' parameters a step updates (shaders/adam.wgsl).
    pub adam: AdamScope,
    /// A gain per frame on top of the camera's exposure, measured at each view's
    /// first step from its own forward pass (`optim::gain`); held-out views take
    /// their neighbours'.
    pub frame_exposure: bool,
}

/// Which surfels' parameters an optimisation step updates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum AdamScope {
    /// Every parameter of every surfel, every step (the paper's Adam): a surfel out
    /// of view moves by its regularisers' z gradient and its momentum.
    Dense,
    /// The view's candidates alone (selective Adam, as gsplat's SelectiveAdam): a
    /// step's cost follows the view; a surfel catches up what the steps it missed
    /// would have done to its moments and momentum, but the regularisers act on it
    /// only in its views.
    Selective,
}

impl AdamScope {
    /// `selective` of shaders/adam.wgsl.
    pub fn code(self) -> u32 {
        match self {
            Self::Dense => 0,
            Self::Selective => 1,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Dense => "dense",
            Self::Selective => "selective",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        [Self::Dense, Self::Selective]
            .into_iter()
            .find(|m| m.name() == s)
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            epochs: 1,
            seed: 0,
            lr: LearningRates::default(),
            loss: LossConfig::default(),
            cull: CullConfig::default(),
            use_lidar: true,
            lidar_colours: true,
            holdout_every: None,
            max_steps: None,
            moment_window: None,
            pair_margin: 1.25,
            adam: AdamScope::Dense,
            frame_exposure: true,
        }
    }
}

/// One camera image of one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct ViewRef {
    pub frame: usize,
    pub view: usize,
    /// Index of its camera in the manifest's camera list.
    pub camera: usize,
}

/// Whether frame `k` is held out with `holdout_every` = K: frames K−1, 2K−1, … (so
/// that frame 0, which anchors the start of the map, is always trained on).
pub fn is_holdout(k: usize, holdout_every: Option<usize>) -> bool {
    holdout_every.is_some_and(|h| h > 0 && (k + 1).is_multiple_of(h))
}

/// Training and held-out views of a bundle.
pub fn split_views(m: &Manifest, holdout_every: Option<usize>) -> (Vec<ViewRef>, Vec<ViewRef>) {
    let (mut train, mut held) = (Vec::new(), Vec::new());
    for (fi, f) in m.frames.iter().enumerate() {
        for (vi, v) in f.views.iter().enumerate() {
            let Some(camera) = m.cameras.iter().position(|c| c.name == v.camera) else {
                continue;
            };
            let r = ViewRef {
                frame: fi,
                view: vi,
                camera,
            };
            if is_holdout(fi, holdout_every) {
                held.push(r);
            } else {
                train.push(r);
            }
        }
    }
    (train, held)
}

/// The order of `n` images in `epoch`: a Fisher–Yates shuffle seeded by (seed, epoch).
pub fn epoch_order(n: usize, seed: u64, epoch: usize) -> Vec<usize> {
    let mut rng = crate::synth::rng::Rng::new(seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9));
    let mut order: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        order.swap(i, j);
    }
    order
}

/// Scene extent that scales the z learning rate (as 3D Gaussian splatting does): 1.1 ×
/// the largest distance of a vehicle position from their centroid, at least 1 m.
pub fn scene_extent(m: &Manifest) -> f32 {
    let pts: Vec<[f64; 2]> = m
        .frames
        .iter()
        .map(|f| [f.vehicle_to_world[0][3], f.vehicle_to_world[1][3]])
        .collect();
    extent_of(&pts)
}

/// The scene extent of vehicle positions `pts` (a tile's frames, say).
pub fn extent_of(pts: &[[f64; 2]]) -> f32 {
    let n = pts.len().max(1) as f64;
    let c = pts
        .iter()
        .fold([0.0, 0.0], |a, p| [a[0] + p[0] / n, a[1] + p[1] / n]);
    let r = pts
        .iter()
        .map(|p| (p[0] - c[0]).hypot(p[1] - c[1]))
        .fold(0.0, f64::max);
    (1.1 * r).max(1.0) as f32
}
