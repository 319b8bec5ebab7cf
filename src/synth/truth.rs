//! Bird's-eye-view truth rasters of a synthetic world over the corridor around the
//! true trajectory: shaded albedo as seen by a unit-exposure camera (2×2 samples per
//! pixel, like the images), majority class, elevation at the pixel centre, validity.

use super::raycast::{shade, to_u8};
use super::rig::LANE_T;
use super::world::World;
use crate::bev::BevGeometry;
use crate::bundle::Mat4Rows;
use crate::eval::BevRaster;
use crate::export::map_file::{self, MapSource, Region};
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

/// The truth's georeference (the corridor's bounding box) and the arc-length range of
/// the trajectory.
fn extent(
    world: &World,
    poses: &[Mat4Rows],
    half_width: f64,
    res: f64,
) -> (BevGeometry, (f64, f64)) {
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
    let g = BevGeometry {
        origin: [x0 - half_width, y1 + half_width],
        resolution: res,
        width: ((x1 - x0 + 2.0 * half_width) / res).ceil() as u32,
        height: ((y1 - y0 + 2.0 * half_width) / res).ceil() as u32,
    };
    (g, s_range)
}

/// Pixels `[x0, x0 + w) × [y0, y0 + h)` of the truth over `g`, row by row in parallel.
fn block(
    world: &World,
    g: &BevGeometry,
    s_range: (f64, f64),
    half_width: f64,
    (x0, y0, w, h): (u32, u32, u32, u32),
) -> Vec<Vec<Option<TruthPixel>>> {
    let res = g.resolution;
    par_map(h as usize, |j| {
        let mut out = Vec::with_capacity(w as usize);
        for i in 0..w {
            let x = g.origin[0] + ((x0 + i) as f64 + 0.5) * res;
            let y = g.origin[1] - ((y0 + j as u32) as f64 + 0.5) * res;
            out.push(pixel(world, x, y, res, s_range, half_width));
        }
        out
    })
}

/// The truth rasters, as the same `BevRaster` that evaluation reads them back into.
pub fn rasters(world: &World, poses: &[Mat4Rows], half_width: f64, res: f64) -> BevRaster {
    let (g, s_range) = extent(world, poses, half_width, res);
    let (width, height) = (g.width, g.height);
    let rows = block(world, &g, s_range, half_width, (0, 0, width, height));
    let mut truth = BevRaster::empty(g.origin, res, width, height);
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

/// The truth as a map source: tiles are ray-traced when they are written, so the
/// truth of a drive of any length becomes a map file in bounded memory. Layers
/// `rgb`, `semantic`, `elevation`; values `elevation`, `class`.
struct TruthSource<'a> {
    world: &'a World,
    g: BevGeometry,
    s_range: (f64, f64),
    half_width: f64,
    /// Trajectory positions, for skipping tiles far from the corridor.
    xy: Vec<[f64; 2]>,
    lut: [[u8; 3]; 256],
    z_range: [f32; 2],
}

impl MapSource for TruthSource<'_> {
    fn region(&self, x0: u32, y0: u32, w: u32, h: u32) -> Result<Option<Region>, String> {
        let g = &self.g;
        let (cx, cy) = (
            g.origin[0] + (x0 as f64 + w as f64 / 2.0) * g.resolution,
            g.origin[1] - (y0 as f64 + h as f64 / 2.0) * g.resolution,
        );
        let reach = self.half_width + 0.5 * (w as f64).hypot(h as f64) * g.resolution + 1.0;
        if !self.xy.iter().any(|p| (p[0] - cx).hypot(p[1] - cy) < reach) {
            return Ok(None);
        }
        let rows = block(self.world, g, self.s_range, self.half_width, (x0, y0, w, h));
        let n = (w * h) as usize;
        let mut reg = Region::empty(3, 2, w, h);
        let mut z = vec![f32::NAN; n];
        for (i, p) in rows.into_iter().flatten().enumerate() {
            let Some((rgb, class, e)) = p else { continue };
            reg.rgba[0][4 * i..4 * i + 4].copy_from_slice(&[rgb[0], rgb[1], rgb[2], 255]);
            let c = self.lut[class as usize];
            reg.rgba[1][4 * i..4 * i + 4].copy_from_slice(&[c[0], c[1], c[2], 255]);
            z[i] = e as f32;
            reg.values[1][i] = class as f32;
        }
        reg.rgba[2] = crate::export::ramp_rgba(&z, self.z_range[0], self.z_range[1]);
        reg.values[0] = z;
        Ok(Some(reg))
    }
}

/// The truth of a scene as a map file at `res` metres per pixel, written tile by
/// tile; named `name`, with the synthetic class table.
pub fn map_file(
    world: &World,
    true_poses: &[Mat4Rows],
    name: &str,
    half_width: f64,
    res: f64,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<u8>, String> {
    let (g, s_range) = extent(world, true_poses, half_width, res);
    let xy: Vec<[f64; 2]> = true_poses.iter().map(|p| [p[0][3], p[1][3]]).collect();
    // The ramp spans the heights along the trajectory, with the curbs' reach.
    let (lo, hi) = xy
        .iter()
        .filter_map(|p| world.field.height(p[0], p[1]))
        .fold((f64::MAX, f64::MIN), |(a, b), z| (a.min(z), b.max(z)));
    let z_range = if lo <= hi {
        [(lo - 0.3) as f32, (hi + 0.3) as f32]
    } else {
        [0.0, 1.0]
    };
    let classes = super::classes::table();
    let mut lut = [[0u8; 3]; 256];
    for c in &classes {
        lut[c.id as usize] = c.color;
    }
    let mut index = map_file::new_index(
        name,
        &classes,
        xy.clone(),
        &g,
        &["rgb", "semantic", "elevation"],
        &["elevation", "class"],
    );
    index.elevation_range = Some(z_range);
    let src = TruthSource {
        world,
        g,
        s_range,
        half_width,
        xy,
        lut,
        z_range,
    };
    let report =
        serde_json::json!({ "truth": true, "resolution_m": res, "half_width_m": half_width });
    map_file::write_from(index, &src, report.to_string().as_bytes(), &[], progress)
}

/// One truth pixel: colour, class, elevation.
type TruthPixel = ([u8; 3], u8, f64);

/// Colour, class and elevation of one BEV pixel, or `None` where it is not valid.
fn pixel(
    w: &World,
    x: f64,
    y: f64,
    res: f64,
    s_range: (f64, f64),
    half_width: f64,
) -> Option<TruthPixel> {
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
