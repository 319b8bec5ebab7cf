//! Vehicle trajectory, camera rigs, pose noise and LiDAR sweeps of a synthetic scene.

use super::raycast::{Hit, Scene};
use super::rng::Rng;
use super::world::World;
pub use crate::bundle::transform::{apply, exp_so3, inverse, mat, mul};
use crate::bundle::Mat4Rows;

/// Lateral offset of the vehicle from the centreline: the right-hand lane.
pub const LANE_T: f64 = -1.75;

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|x| x / n)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// True vehicle pose at arc length s: on the ground, axes from the road under the
/// wheels (wheelbase 2.8 m, track 1.6 m), so it pitches on the bump and rolls with the
/// cross-fall.
///
/// Driving towards decreasing `s`, in the other lane, when `back`.
pub fn vehicle_pose_on(w: &World, s: f64, back: bool) -> Mat4Rows {
    let p = |s: f64, t: f64| {
        let (x, y, _) = w.line.point(s, t);
        [x, y, w.field.height(x, y).unwrap_or(0.0)]
    };
    let (lane, dir) = if back { (-LANE_T, -1.0) } else { (LANE_T, 1.0) };
    let c = p(s, lane);
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let fwd = normalize(sub(p(s + 1.4 * dir, lane), p(s - 1.4 * dir, lane)));
    let left0 = normalize(sub(p(s, lane + 0.8 * dir), p(s, lane - 0.8 * dir)));
    let up = normalize(cross(fwd, left0));
    let left = cross(up, fwd);
    mat(
        [
            [fwd[0], left[0], up[0]],
            [fwd[1], left[1], up[1]],
            [fwd[2], left[2], up[2]],
        ],
        c,
    )
}

/// Rotation about z by yaw then about the (new) y axis by pitch, composed with the
/// fixed map from camera axes (x right, y down, z forward) to vehicle axes.
pub fn camera_to_vehicle(yaw_deg: f64, pitch_deg: f64, pos: [f64; 3]) -> Mat4Rows {
    let (cy, sy) = (yaw_deg.to_radians().cos(), yaw_deg.to_radians().sin());
    let (cp, sp) = (pitch_deg.to_radians().cos(), pitch_deg.to_radians().sin());
    let rz = mat([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]], [0.0; 3]);
    let ry = mat([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]], [0.0; 3]);
    let base = mat([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], pos);
    let rot = mul(&rz, &ry);
    let mut m = mul(&rot, &base);
    m[0][3] = pos[0];
    m[1][3] = pos[1];
    m[2][3] = pos[2];
    m
}

/// Pose noise settings: per-frame Gaussian translation (m, each axis) and rotation
/// (degrees, each axis) and a drift growing linearly to `drift_m` at the last frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PoseNoise {
    pub translation_m: f64,
    pub rotation_deg: f64,
    pub drift_m: f64,
}

/// The poses written into the bundle: truth perturbed by `noise`.
pub fn noisy_poses(truth: &[Mat4Rows], noise: PoseNoise, rng: &Rng) -> Vec<Mat4Rows> {
    let mut r = rng.fork(0x905e);
    let dir = normalize([r.normal(), r.normal(), 0.5 * r.normal()]);
    let n = truth.len().max(2) - 1;
    truth
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let w = [0; 3].map(|_| r.normal() * noise.rotation_deg.to_radians());
            let dt = [0; 3].map(|_| r.normal() * noise.translation_m);
            let drift = noise.drift_m * k as f64 / n as f64;
            // Rotation noise about the vehicle origin, translation noise in the world.
            let mut out = mul(p, &mat(exp_so3(w), [0.0; 3]));
            for i in 0..3 {
                out[i][3] = p[i][3] + dt[i] + drift * dir[i];
            }
            out
        })
        .collect()
}

/// One LiDAR sweep from the true pose: `beams` rings from -25° to +3°, every `az_step_deg`.
/// Points are in the LiDAR frame, with the hit's albedo as intensity.
pub fn lidar_sweep(
    world: &World,
    lidar_to_world: &Mat4Rows,
    beams: u32,
    az_step_deg: f64,
) -> Vec<[f32; 4]> {
    let o = [
        lidar_to_world[0][3],
        lidar_to_world[1][3],
        lidar_to_world[2][3],
    ];
    let to_lidar = inverse(lidar_to_world);
    let mut pts = Vec::new();
    let steps = (360.0 / az_step_deg).round() as u32;
    for b in 0..beams {
        let el = (-25.0 + 28.0 * b as f64 / (beams - 1).max(1) as f64).to_radians();
        for a in 0..steps {
            let az = (a as f64 * az_step_deg).to_radians();
            let dl = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
            let dw = [0, 1, 2].map(|i| (0..3).map(|k| lidar_to_world[i][k] * dl[k]).sum::<f64>());
            if let Hit::Surface { tau, albedo, .. } = world.hit(o, dw) {
                if tau < 60.0 {
                    let p = apply(
                        &to_lidar,
                        [o[0] + tau * dw[0], o[1] + tau * dw[1], o[2] + tau * dw[2]],
                    );
                    let i = (albedo[0] + albedo[1] + albedo[2]) / 3.0;
                    pts.push([p[0] as f32, p[1] as f32, p[2] as f32, i as f32]);
                }
            }
        }
    }
    pts
}
