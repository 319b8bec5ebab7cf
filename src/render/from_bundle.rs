//! From bundle and prepared surfels to what the rasteriser takes: views with a local
//! origin (world coordinates of real data run to thousands of metres, which f32 on the
//! GPU cannot resolve to millimetres) and surfel parameters in that local frame.

use super::{Params, ViewCamera};
use crate::bundle::transform::mul;
use crate::bundle::Manifest;
use crate::grid::{Grid, Surfels};

/// The camera of view `view` of frame `frame`, looking at the world shifted by −origin.
pub fn view_camera(
    m: &Manifest,
    frame: usize,
    view: usize,
    origin: [f64; 3],
    exposure: [f32; 2],
) -> Option<ViewCamera> {
    let f = m.frames.get(frame)?;
    let v = f.views.get(view)?;
    let cam = m.camera(&v.camera)?;
    let c2w = mul(f.view_pose(v), &cam.camera_to_vehicle);
    // World-to-camera: Rᵀ (p − t), with p = p_local + origin.
    let mut w2c = [[0.0f32; 4]; 3];
    for (i, row) in w2c.iter_mut().enumerate() {
        let r = [c2w[0][i], c2w[1][i], c2w[2][i]];
        let t: f64 = (0..3).map(|k| r[k] * (origin[k] - c2w[k][3])).sum();
        *row = [r[0] as f32, r[1] as f32, r[2] as f32, t as f32];
    }
    Some(ViewCamera {
        world_to_cam: w2c,
        fx: cam.fx as f32,
        fy: cam.fy as f32,
        cx: cam.cx as f32,
        cy: cam.cy as f32,
        width: cam.width,
        height: cam.height,
        exposure,
    })
}

/// A local origin for a grid: its lower-left corner at the height of the first surfel.
pub fn local_origin(grid: &Grid, surfels: &Surfels) -> [f64; 3] {
    [
        grid.origin[0],
        grid.origin[1],
        surfels.z.first().copied().unwrap_or(0.0) as f64,
    ]
}

/// Rasteriser parameters of prepared surfels, in the frame shifted by −origin.
pub fn params(grid: &Grid, s: &Surfels, origin: [f64; 3]) -> Params<f32> {
    Params {
        pos: (0..grid.len())
            .map(|k| {
                let [x, y] = grid.xy(k);
                [
                    (x - origin[0]) as f32,
                    (y - origin[1]) as f32,
                    (s.z[k] as f64 - origin[2]) as f32,
                ]
            })
            .collect(),
        rgb: s.rgb.clone(),
        log_scale: s.log_scale.clone(),
        opacity: s.opacity.clone(),
        rotation: s.rotation.clone(),
        logits: s.logits.clone(),
        channels: s.classes,
    }
}
