//! A georeferenced BEV raster (truth, pseudo-truth or prediction): colour, class ids,
//! float elevation and validity on one grid. Row 0 is the north edge.

use crate::bundle::{Bundle, Problem};
use image::{GrayImage, RgbImage};

#[derive(Clone, Debug)]
pub struct BevRaster {
    /// World x of the west edge, world y of the north edge.
    pub origin: [f64; 2],
    pub resolution: f64,
    pub width: u32,
    pub height: u32,
    pub rgb: RgbImage,
    pub class_ids: GrayImage,
    pub elevation: Vec<f32>,
    pub valid: GrayImage,
}

impl BevRaster {
    pub fn empty(origin: [f64; 2], resolution: f64, width: u32, height: u32) -> Self {
        Self {
            origin,
            resolution,
            width,
            height,
            rgb: RgbImage::new(width, height),
            class_ids: GrayImage::new(width, height),
            elevation: vec![0.0; (width * height) as usize],
            valid: GrayImage::new(width, height),
        }
    }

    /// This raster over the grid of `like` (each pixel from the pixel at its
    /// centre; invalid outside this raster): a block of a map cut out of the truth.
    pub fn crop_to(&self, like: &BevRaster) -> Self {
        let mut out = Self::empty(like.origin, like.resolution, like.width, like.height);
        for r in 0..like.height {
            for c in 0..like.width {
                let (x, y) = out.centre(c, r);
                let Some((sc, sr)) = self.pixel_of(x, y) else {
                    continue;
                };
                out.rgb.put_pixel(c, r, *self.rgb.get_pixel(sc, sr));
                out.class_ids
                    .put_pixel(c, r, *self.class_ids.get_pixel(sc, sr));
                out.valid.put_pixel(c, r, *self.valid.get_pixel(sc, sr));
                out.elevation[(r * like.width + c) as usize] = self.elevation_at(sc, sr);
            }
        }
        out
    }

    /// The bundle's ground-truth rasters, if it has them.
    pub fn from_bundle(b: &Bundle) -> Result<Option<Self>, Problem> {
        let Some(gt) = &b.manifest.ground_truth else {
            return Ok(None);
        };
        let limits = b.limits.for_truth();
        let read = |p: &str| b.source().read(p, &limits);
        let bytes = read(&gt.elevation)?;
        Ok(Some(Self {
            origin: gt.origin,
            resolution: gt.resolution,
            width: gt.width,
            height: gt.height,
            rgb: crate::bundle::decode_rgb(&gt.rgb, &read(&gt.rgb)?, &limits)?,
            class_ids: crate::bundle::decode_label(&gt.class_ids, &read(&gt.class_ids)?, &limits)?,
            elevation: bytemuck::pod_collect_to_vec(&bytes),
            valid: crate::bundle::decode_label(&gt.valid, &read(&gt.valid)?, &limits)?,
        }))
    }

    /// Column and row of the pixel containing world (x, y).
    pub fn pixel_of(&self, x: f64, y: f64) -> Option<(u32, u32)> {
        let c = ((x - self.origin[0]) / self.resolution).floor();
        let r = ((self.origin[1] - y) / self.resolution).floor();
        (c >= 0.0 && r >= 0.0 && c < self.width as f64 && r < self.height as f64)
            .then_some((c as u32, r as u32))
    }

    /// World xy of a pixel centre.
    pub fn centre(&self, col: u32, row: u32) -> (f64, f64) {
        (
            self.origin[0] + (col as f64 + 0.5) * self.resolution,
            self.origin[1] - (row as f64 + 0.5) * self.resolution,
        )
    }

    pub fn is_valid(&self, col: u32, row: u32) -> bool {
        self.valid.get_pixel(col, row).0[0] != 0
    }

    pub fn elevation_at(&self, col: u32, row: u32) -> f32 {
        self.elevation[(row * self.width + col) as usize]
    }

    /// Elevation at world (x, y) by bilinear interpolation of the valid pixel centres
    /// around it (nearest valid pixel at the edge of validity).
    pub fn elevation_xy(&self, x: f64, y: f64) -> Option<f64> {
        let (c, r) = self.pixel_of(x, y)?;
        if !self.is_valid(c, r) {
            return None;
        }
        let fx = (x - self.origin[0]) / self.resolution - 0.5;
        let fy = (self.origin[1] - y) / self.resolution - 0.5;
        let (c0, r0) = (fx.floor(), fy.floor());
        let (wx, wy) = (fx - c0, fy - r0);
        let mut sum = 0.0;
        let mut wsum = 0.0;
        for (dc, dr, w) in [
            (0, 0, (1.0 - wx) * (1.0 - wy)),
            (1, 0, wx * (1.0 - wy)),
            (0, 1, (1.0 - wx) * wy),
            (1, 1, wx * wy),
        ] {
            let (cc, rr) = (c0 as i64 + dc, r0 as i64 + dr);
            if cc < 0
                || rr < 0
                || cc >= self.width as i64
                || rr >= self.height as i64
                || !self.is_valid(cc as u32, rr as u32)
            {
                continue;
            }
            sum += w * self.elevation_at(cc as u32, rr as u32) as f64;
            wsum += w;
        }
        if wsum < 1e-9 {
            return Some(self.elevation_at(c, r) as f64);
        }
        Some(sum / wsum)
    }
}
