//! Small deterministic test scenes for the rasteriser: a patch of road surfels in
//! front of a car-height camera, with tilts, colours and logits varied so that every
//! gradient path is exercised (grazing angles, partial tiles, low-pass floor).

use super::{Params, ViewCamera};
use crate::synth::rng::Rng;

/// Camera 1.5 m above z = 0 looking along +y, pitched down `pitch_deg`.
pub fn road_camera(width: u32, height: u32, pitch_deg: f64) -> ViewCamera {
    let p = pitch_deg.to_radians();
    // Rows of world-to-camera: camera x = world +x, camera z = forward-down, y = down.
    let fwd = [0.0, p.cos(), -p.sin()];
    let right = [1.0, 0.0, 0.0];
    let down = [
        fwd[1] * right[2] - fwd[2] * right[1],
        fwd[2] * right[0] - fwd[0] * right[2],
        fwd[0] * right[1] - fwd[1] * right[0],
    ];
    let c = [0.0, 0.0, 1.5];
    let row = |a: [f64; 3]| {
        let t = -(a[0] * c[0] + a[1] * c[1] + a[2] * c[2]);
        [a[0] as f32, a[1] as f32, a[2] as f32, t as f32]
    };
    let f = 0.8 * width as f64;
    ViewCamera {
        world_to_cam: [row(right), row(down), row(fwd)],
        fx: f as f32,
        fy: f as f32,
        cx: width as f32 / 2.0,
        cy: height as f32 * 0.35,
        width,
        height,
        exposure: [0.1, -0.02],
    }
}

/// `nx × ny` surfels at `spacing` from (x0, y0), with random tilts and attributes.
pub fn road_patch(
    nx: usize,
    ny: usize,
    spacing: f64,
    x0: f64,
    y0: f64,
    channels: usize,
    seed: u64,
) -> Params<f64> {
    let mut r = Rng::new(seed);
    let mut p = Params {
        channels,
        ..Default::default()
    };
    for j in 0..ny {
        for i in 0..nx {
            p.pos.push([
                x0 + i as f64 * spacing,
                y0 + j as f64 * spacing,
                0.05 * r.normal(),
            ]);
            p.rgb.push([r.uniform(), r.uniform(), r.uniform()]);
            let s = (0.6 * spacing).ln();
            p.log_scale
                .push([s + 0.2 * r.normal(), s + 0.2 * r.normal()]);
            p.opacity.push(0.5 + r.normal());
            // Small random tilt about a horizontal axis, random yaw.
            let (a, b, c) = (0.15 * r.normal(), 0.15 * r.normal(), r.uniform() * 3.0);
            p.rotation.push([1.0, a, b, c]);
            for _ in 0..channels {
                p.logits.push(r.normal());
            }
        }
    }
    p
}
