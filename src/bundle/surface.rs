//! The supervision of a drive without labels: the pixels where a camera sees the road
//! plane (below its horizon, within `SURFACE_RANGE_M`), less the vehicle's own body
//! where the camera's `mask` marks it. Written as a label image of `SURFACE_ID` (0
//! elsewhere) so that the loss mask, the IPM and the trainer treat it as they treat
//! a label; moving things on the road (cars, people, shadows) are left to the
//! loss's robust weighting (loss.wgsl).
//!
//! The plane is the vehicle frame's ground (z = −`vehicle_height_m`), so the mask
//! depends on the camera alone, not on the pose: one per camera.

use super::{transform, Camera, Manifest, SURFACE_ID};
use image::GrayImage;

/// The farthest road point supervised, metres from the camera in the ground plane:
/// beyond it a pixel spans more road than the map's cells and blurs them.
pub const SURFACE_RANGE_M: f64 = 40.0;

/// The camera's surface label: `SURFACE_ID` where its pixel's ray meets the ground
/// plane within `SURFACE_RANGE_M` and `body` (the camera's mask) is zero.
pub fn surface_label(m: &Manifest, cam: &Camera, body: Option<&GrayImage>) -> GrayImage {
    let c2v = &cam.camera_to_vehicle;
    let origin = transform::apply(c2v, [0.0; 3]);
    let ground = -m.vehicle_height_m;
    GrayImage::from_fn(cam.width, cam.height, |u, v| {
        if body.is_some_and(|b| b.get_pixel(u, v).0[0] != 0) {
            return image::Luma([0]);
        }
        let d = [
            (u as f64 + 0.5 - cam.cx) / cam.fx,
            (v as f64 + 0.5 - cam.cy) / cam.fy,
            1.0,
        ];
        // The ray's direction in the vehicle frame (rotation only).
        let dv = [0, 1, 2].map(|i| c2v[i][0] * d[0] + c2v[i][1] * d[1] + c2v[i][2] * d[2]);
        let t = (ground - origin[2]) / dv[2];
        let hit = dv[2] < 0.0 && t.is_finite() && t > 0.0;
        let reach = (t * dv[0]).hypot(t * dv[1]);
        image::Luma([if hit && reach <= SURFACE_RANGE_M {
            SURFACE_ID
        } else {
            0
        }])
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bundle::example;

    /// A level forward camera 1.5 m above the ground: the horizon is the principal
    /// row; the row of a pixel that sees the ground at distance r is cy + fy·1.5/r.
    #[test]
    fn horizon_and_range_of_a_level_camera() {
        let mut m = example::tiny().0;
        m.vehicle_height_m = 0.0;
        let mut cam = example::front_camera();
        (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) =
            (64, 480, 100.0, 100.0, 32.0, 240.0);
        // Camera z forward = vehicle x, camera x right = −vehicle y, y down = −z.
        cam.camera_to_vehicle = [
            [0.0, 0.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0, 0.0],
            [0.0, -1.0, 0.0, 1.5],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let l = surface_label(&m, &cam, None);
        let col = |v: u32| l.get_pixel(32, v).0[0];
        // Rows above the horizon never see the ground.
        assert_eq!(col(100), 0);
        assert_eq!(col(239), 0);
        // 40 m away is row 240 + 150/40 = 243.75: rows below it are on the surface.
        assert_eq!(col(243), 0);
        assert_eq!(col(244), SURFACE_ID);
        assert_eq!(col(479), SURFACE_ID);
        // The body mask removes what it marks.
        let body = GrayImage::from_fn(64, 480, |_, v| image::Luma([(v >= 400) as u8 * 255]));
        let l = surface_label(&m, &cam, Some(&body));
        assert_eq!(l.get_pixel(10, 399).0[0], SURFACE_ID);
        assert_eq!(l.get_pixel(10, 400).0[0], 0);
    }
}
