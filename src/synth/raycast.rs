//! The independent CPU ray caster that makes the synthetic images. It never uses the
//! engine's rasteriser: rays from each pixel meet the true surface (or an occluder,
//! or the sky), and the pixel averages a regular n×n grid of rays (anti-aliased
//! edges); the label is the majority class of the same rays, so label edges and
//! colour edges fall in the same place.

use image::{GrayImage, Luma, Rgb, RgbImage};

/// Direction towards the sun (unit), for simple Lambert shading.
pub const SUN: [f64; 3] = [0.3213938, 0.3830222, 0.8660254];
pub const AMBIENT: f64 = 0.55;
pub const DIFFUSE: f64 = 0.45;

/// What a ray met.
#[derive(Clone, Copy, Debug)]
pub enum Hit {
    Surface {
        tau: f64,
        albedo: [f64; 3],
        class: u8,
        normal: [f64; 3],
    },
    Sky {
        color: [f64; 3],
        class: u8,
    },
}

pub trait Scene: Sync {
    fn hit(&self, o: [f64; 3], d: [f64; 3]) -> Hit;
}

/// Lambert shading with ambient light.
pub fn shade(albedo: [f64; 3], n: [f64; 3]) -> [f64; 3] {
    let k = AMBIENT + DIFFUSE * (n[0] * SUN[0] + n[1] * SUN[1] + n[2] * SUN[2]).max(0.0);
    albedo.map(|a| a * k)
}

/// Linear radiance and class of a ray.
pub fn radiance(h: &Hit) -> ([f64; 3], u8) {
    match *h {
        Hit::Surface {
            albedo,
            class,
            normal,
            ..
        } => (shade(albedo, normal), class),
        Hit::Sky { color, class } => (color, class),
    }
}

/// A pinhole camera placed in the world.
#[derive(Clone, Debug)]
pub struct View {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Camera-to-world, row-major 4×4 (camera x right, y down, z forward).
    pub cam_to_world: [[f64; 4]; 4],
}

impl View {
    /// World ray (origin, unit direction) through image point (u, v) in pixels.
    pub fn ray(&self, u: f64, v: f64) -> ([f64; 3], [f64; 3]) {
        let c = [(u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0];
        let m = &self.cam_to_world;
        let mut d = [0.0; 3];
        for (r, dr) in d.iter_mut().enumerate() {
            *dr = m[r][0] * c[0] + m[r][1] * c[1] + m[r][2] * c[2];
        }
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        ([m[0][3], m[1][3], m[2][3]], d.map(|v| v / n))
    }
}

/// Camera response: `gain · radiance + offset`, clamped, to 8 bits.
#[derive(Clone, Copy, Debug)]
pub struct Exposure {
    pub gain: f64,
    pub offset: f64,
}

pub fn to_u8(v: f64) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Renders colour and label images with `n × n` rays per pixel.
pub fn render(scene: &dyn Scene, view: &View, n: u32, exposure: Exposure) -> (RgbImage, GrayImage) {
    let mut rgb = RgbImage::new(view.width, view.height);
    let mut lab = GrayImage::new(view.width, view.height);
    for y in 0..view.height {
        for x in 0..view.width {
            let (c, class) = pixel(scene, view, x, y, n);
            rgb.put_pixel(
                x,
                y,
                Rgb(c.map(|v| to_u8(exposure.gain * v + exposure.offset))),
            );
            lab.put_pixel(x, y, Luma([class]));
        }
    }
    (rgb, lab)
}

/// Mean radiance and majority class of the n×n rays of pixel (x, y).
pub fn pixel(scene: &dyn Scene, view: &View, x: u32, y: u32, n: u32) -> ([f64; 3], u8) {
    let mut sum = [0.0; 3];
    let mut votes = [0u16; 256];
    for j in 0..n {
        for i in 0..n {
            let u = x as f64 + (i as f64 + 0.5) / n as f64;
            let v = y as f64 + (j as f64 + 0.5) / n as f64;
            let (o, d) = view.ray(u, v);
            let (c, class) = radiance(&scene.hit(o, d));
            for k in 0..3 {
                sum[k] += c[k];
            }
            votes[class as usize] += 1;
        }
    }
    let mut best = 0;
    for (k, &v) in votes.iter().enumerate() {
        if v > votes[best] {
            best = k;
        }
    }
    let m = (n * n) as f64;
    (sum.map(|s| s / m), best as u8)
}
