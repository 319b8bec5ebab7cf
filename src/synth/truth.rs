//! Bird's-eye-view truth rasters of a synthetic world over the corridor around the
//! true trajectory: shaded albedo as seen by a unit-exposure camera (2×2 samples per
//! pixel, like the images), majority class, elevation at the pixel centre, validity.

use super::raycast::{shade, to_u8};
use super::rig::LANE_T;
use super::world::World;
use crate::bundle::Mat4Rows;
use crate::eval::BevRaster;
use crate::par::par_map;
use image::{Luma, Rgb};

/// Distance of road point (s, t) from the trajectory (the lane line from s_a to s_b).
fn corridor_distance(s: f64, t: f64, s_a: f64, s_b: f64) -> f64 {
    let ds = if s < s_a {
        s_a - s
    } else if s > s_b {
        s - s_b
    } else {
        0.0
    };
    ds.hypot(t - LANE_T)
}

/// The truth rasters, as the same `BevRaster` that evaluation reads them back into.
pub fn rasters(world: &World, poses: &[Mat4Rows], half_width: f64, res: f64) -> BevRaster {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    let mut s_range = (f64::MAX, f64::MIN);
    for p in poses {
        let (x, y) = (p[0][3], p[1][3]);
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
        if let Some(smp) = world.field.sample(x, y) {
            s_range = (s_range.0.min(smp.s), s_range.1.max(smp.s));
        }
    }
    let origin = [x0 - half_width, y1 + half_width];
    let width = ((x1 - x0 + 2.0 * half_width) / res).ceil() as u32;
    let height = ((y1 - y0 + 2.0 * half_width) / res).ceil() as u32;
    let rows = par_map(height as usize, |row| {
        let mut out = Vec::with_capacity(width as usize);
        for col in 0..width {
            let x = origin[0] + (col as f64 + 0.5) * res;
            let y = origin[1] - (row as f64 + 0.5) * res;
            out.push(pixel(world, x, y, res, s_range, half_width));
        }
        out
    });
    let mut truth = BevRaster::empty(origin, res, width, height);
    for (row, pixels) in rows.into_iter().enumerate() {
        for (col, p) in pixels.into_iter().enumerate() {
            let Some((rgb, class, z)) = p else { continue };
            let (c, r) = (col as u32, row as u32);
            truth.rgb.put_pixel(c, r, Rgb(rgb));
            truth.class_ids.put_pixel(c, r, Luma([class]));
            truth.elevation[row * width as usize + col] = z as f32;
            truth.valid.put_pixel(c, r, Luma([255]));
        }
    }
    truth
}

/// Colour, class and elevation of one BEV pixel, or `None` where it is not valid.
fn pixel(
    w: &World,
    x: f64,
    y: f64,
    res: f64,
    s_range: (f64, f64),
    half_width: f64,
) -> Option<([u8; 3], u8, f64)> {
    let centre = w.field.sample(x, y)?;
    if corridor_distance(centre.s, centre.t, s_range.0, s_range.1) > half_width
        || w.occluders.iter().any(|o| o.covers(x, y))
    {
        return None;
    }
    let mut sum = [0.0; 3];
    let mut votes = [0u8; 256];
    for j in 0..2 {
        for i in 0..2 {
            let (sx, sy) = (
                x + (i as f64 - 0.5) * 0.5 * res,
                y + (j as f64 - 0.5) * 0.5 * res,
            );
            let (albedo, class) = w.surface(sx, sy)?;
            let c = shade(albedo, w.field.normal(sx, sy));
            for k in 0..3 {
                sum[k] += c[k];
            }
            votes[class as usize] += 1;
        }
    }
    let class = (0..256)
        .max_by_key(|&k| (votes[k], std::cmp::Reverse(k)))
        .unwrap_or(0) as u8;
    Some((sum.map(|v| to_u8(v / 4.0)), class, centre.h))
}
