//! Stage 4: the differentiable 2D-surfel rasteriser.
//!
//! Per view: cull the surfels to a box in front of the camera, project them, bin them
//! into 8×8 pixel tiles, order each tile's surfels by depth, and composite front to
//! back. Each surfel is evaluated where the pixel ray meets its plane (2DGS), with a
//! screen-space low-pass floor so that far, small surfels stay visible and smooth.
//!
//! This module holds the CPU oracle (plain Rust, generic over f32 and f64) of the WGSL
//! kernels in `shaders/`: `project` ↔ `project.rs`, `rasterize` ↔ `rasterize.rs`,
//! `rasterize_backward` ↔ `rasterize_backward.rs`, `project_backward` ↔
//! `project_backward.rs`. The oracle is written to be read, not to be fast.

pub mod bench;
pub mod candidates;
pub mod check;
pub mod from_bundle;
pub mod gpu;
pub mod probe;
pub mod project;
pub mod project_backward;
pub mod rasterize;
pub mod rasterize_backward;
pub mod real;
pub mod scene;

use real::Real;

/// Tile side in pixels.
pub const TILE: u32 = 8;
/// Contributions below this alpha are skipped (as in 3DGS).
pub const MIN_ALPHA: f64 = 1.0 / 255.0;
/// Alpha is clamped here so that transmittance can be divided back out.
pub const MAX_ALPHA: f64 = 0.99;
/// Compositing stops once transmittance would fall below this.
pub const MIN_TRANSMITTANCE: f64 = 1e-4;
/// Inverse squared width of the screen-space low-pass (2DGS's filter: σ² = 0.5 px²).
pub const LOWPASS_INV_SQ: f64 = 2.0;
/// The surfel footprint extends to this many standard deviations.
pub const EXTENT_SIGMA: f64 = 3.0;

/// How a pixel combines the surfels it meets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Compositing {
    /// Front to back through the depth-sorted list, each surfel weighed by the
    /// transmittance left (3DGS): what a camera sees, and what training renders.
    #[default]
    Occlusion,
    /// The map's view from above: colour, logits and depth are the surfels'
    /// alpha-weighted mean, scaled by the coverage 1 − Π(1 − α) (the alpha a front
    /// to back pass gives too), whatever their order. A road map's surfels are
    /// coplanar neighbours: sorted front to back, whichever centre lies a millimetre
    /// higher would cover its neighbours' overlap, which shifts the map downhill by
    /// half a cell and speckles it where trained heights jitter (docs/QUALITY.md).
    /// Forward only (nothing trains through the map's view).
    Average,
}

/// The box in front of the camera whose surfels are rendered (the official code uses
/// 40 m × 50 m with near/far 1 m / 20 m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CullConfig {
    pub near: f32,
    pub far: f32,
    /// Half the box width across the camera's view, metres.
    pub half_width: f32,
    /// Half the box height (camera y), metres; applied to the host's candidate list
    /// only (`candidates`), not by `project`. Infinite for the driving views; the BEV
    /// chunks use it so that a chunk lists only the surfels that can reach it.
    pub half_height: f32,
}

impl Default for CullConfig {
    fn default() -> Self {
        Self {
            near: 1.0,
            far: 20.0,
            half_width: 20.0,
            half_height: f32::INFINITY,
        }
    }
}

/// A pinhole view: world-to-camera (rows of a 3×4), intrinsics, exposure (a, b):
/// the output colour is `exp(a)·c + b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewCamera {
    pub world_to_cam: [[f32; 4]; 3],
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
    pub exposure: [f32; 2],
}

impl ViewCamera {
    pub fn tiles_x(&self) -> u32 {
        self.width.div_ceil(TILE)
    }
    pub fn tiles_y(&self) -> u32 {
        self.height.div_ceil(TILE)
    }
}

/// Surfel parameters (structure of arrays), generic over the scalar type.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Params<R> {
    /// Centre, in the same (local) world frame as the cameras; x, y fixed, z learnable.
    pub pos: Vec<[R; 3]>,
    pub rgb: Vec<[R; 3]>,
    pub log_scale: Vec<[R; 2]>,
    pub opacity: Vec<R>,
    /// Quaternion (w, x, y, z); need not be normalised.
    pub rotation: Vec<[R; 4]>,
    /// `channels` semantic logits per surfel.
    pub logits: Vec<R>,
    pub channels: usize,
}

impl<R: Real> Params<R> {
    pub fn len(&self) -> usize {
        self.pos.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    pub fn cast<S: Real>(&self) -> Params<S> {
        let c = |v: R| S::of(v.to_f64());
        Params {
            pos: self.pos.iter().map(|p| p.map(c)).collect(),
            rgb: self.rgb.iter().map(|p| p.map(c)).collect(),
            log_scale: self.log_scale.iter().map(|p| p.map(c)).collect(),
            opacity: self.opacity.iter().map(|&p| c(p)).collect(),
            rotation: self.rotation.iter().map(|p| p.map(c)).collect(),
            logits: self.logits.iter().map(|&p| c(p)).collect(),
            channels: self.channels,
        }
    }
}

/// Per-pixel outputs of a view, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image<R> {
    pub width: u32,
    pub height: u32,
    /// Exposure-corrected colour, 3 per pixel.
    pub rgb: Vec<R>,
    /// Composited logits, `channels` per pixel.
    pub logits: Vec<R>,
    pub depth: Vec<R>,
    /// Accumulated opacity, 1 − final transmittance.
    pub alpha: Vec<R>,
    pub channels: usize,
}
