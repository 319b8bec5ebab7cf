//! Stage 7: the bird's-eye-view map, rendered through the same rasteriser kernels as
//! the camera views, in square chunks that are stitched into one raster.
//!
//! Each chunk is seen by a pinhole camera looking straight down from `HEIGHT_M` above
//! the chunk's mean surfel elevation, with a focal length that makes one pixel one
//! BEV cell at that distance: orthographic up to parallax. A surfel δz from the mean,
//! r from the chunk centre, moves by r·δz/H: at most 9 mm for δz = 1 m in a 256-pixel
//! chunk of 5 cm cells, a fifth of a cell. The view's depth gives the elevation.

use crate::eval::BevRaster;
use crate::gpu::{GpuContext, GpuError};
use crate::render::candidates::Footprints;
use crate::render::gpu::{GpuParams, GpuRasterizer};
use crate::render::{CullConfig, Params, ViewCamera, EXTENT_SIGMA};

/// Height of the BEV cameras above the surface, metres.
pub const HEIGHT_M: f64 = 1000.0;
/// Chunk side, pixels.
pub const CHUNK: u32 = 256;

/// Where the BEV raster lies: west x and north y of its edges (world), metres per
/// pixel, size. Row 0 is the north edge.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct BevGeometry {
    pub origin: [f64; 2],
    pub resolution: f64,
    pub width: u32,
    pub height: u32,
}

impl BevGeometry {
    /// The bounding box of world points `xy`, padded by `pad` metres.
    pub fn around(xy: impl Iterator<Item = [f64; 2]>, resolution: f64, pad: f64) -> Self {
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for p in xy {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if lo[0] > hi[0] {
            (lo, hi) = ([0.0; 2], [0.0; 2]);
        }
        let w = ((hi[0] - lo[0] + 2.0 * pad) / resolution).ceil().max(1.0) as u32;
        let h = ((hi[1] - lo[1] + 2.0 * pad) / resolution).ceil().max(1.0) as u32;
        Self {
            origin: [lo[0] - pad, hi[1] + pad],
            resolution,
            width: w,
            height: h,
        }
    }

    /// This geometry grown, on its own pixel grid, to cover `other` too (unchanged
    /// when it already does): the truth of one drive extended to a merged map's
    /// corridor, so that the map covers every drive and is still scored pixel for
    /// pixel where the truth is.
    pub fn covering(&self, other: &BevGeometry) -> Self {
        let r = self.resolution;
        let (x0, y1) = (self.origin[0], self.origin[1]);
        let (x1, y0) = (x0 + self.width as f64 * r, y1 - self.height as f64 * r);
        let (ox0, oy1) = (other.origin[0], other.origin[1]);
        let (ox1, oy0) = (
            ox0 + other.width as f64 * other.resolution,
            oy1 - other.height as f64 * other.resolution,
        );
        // Whole pixels added on each side.
        let grow = |d: f64| if d > 1e-9 { (d / r).ceil() } else { 0.0 };
        let (west, east) = (grow(x0 - ox0), grow(ox1 - x1));
        let (north, south) = (grow(oy1 - y1), grow(y0 - oy0));
        Self {
            origin: [x0 - west * r, y1 + north * r],
            resolution: r,
            width: self.width + (west + east) as u32,
            height: self.height + (north + south) as u32,
        }
    }

    pub fn of_raster(r: &BevRaster) -> Self {
        Self {
            origin: r.origin,
            resolution: r.resolution,
            width: r.width,
            height: r.height,
        }
    }
}

/// The stitched BEV image: per pixel colour 3 (normalised by alpha), logits
/// (`channels`, normalised by alpha), elevation (world) and alpha.
#[derive(Clone, Debug, Default)]
pub struct BevImage {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    pub rgb: Vec<f32>,
    pub logits: Vec<f32>,
    pub elevation: Vec<f32>,
    pub alpha: Vec<f32>,
}

impl BevImage {
    /// Nothing rendered: black, zero logits and alpha, NaN elevation.
    pub fn blank(width: u32, height: u32, channels: usize) -> Self {
        let n = (width * height) as usize;
        Self {
            width,
            height,
            channels,
            rgb: vec![0.0; 3 * n],
            logits: vec![0.0; channels * n],
            elevation: vec![f32::NAN; n],
            alpha: vec![0.0; n],
        }
    }
}

/// The downward camera of the chunk whose top-left pixel is (c0, r0), for a model in
/// the local frame (world − `origin`), hovering over elevation `z_mean` (local).
fn chunk_camera(
    g: &BevGeometry,
    origin: [f64; 3],
    chunk: u32,
    (c0, r0): (u32, u32),
    z_mean: f64,
) -> ViewCamera {
    let half = chunk as f64 / 2.0;
    let xc = g.origin[0] + (c0 as f64 + half) * g.resolution - origin[0];
    let yc = g.origin[1] - (r0 as f64 + half) * g.resolution - origin[1];
    let zc = z_mean + HEIGHT_M;
    // Camera x = world x, camera y = −world y (north up), camera z = −world z.
    let f = (HEIGHT_M / g.resolution) as f32;
    ViewCamera {
        world_to_cam: [
            [1.0, 0.0, 0.0, -xc as f32],
            [0.0, -1.0, 0.0, yc as f32],
            [0.0, 0.0, -1.0, zc as f32],
        ],
        fx: f,
        fy: f,
        cx: half as f32,
        cy: half as f32,
        width: chunk,
        height: chunk,
        exposure: [0.0, 0.0],
    }
}

/// Renders the BEV of the GPU model `gp` (whose host copy `p` gives the surfel
/// positions, local frame) over geometry `g`, chunk by chunk. `progress(done, total)`
/// is called after each chunk. With `per_chunk` (what the product uses), each chunk
/// lists only the surfels that can reach it; without, every surfel for every chunk
/// (tests compare the two).
#[allow(clippy::too_many_arguments)]
pub async fn render(
    ctx: &GpuContext,
    raster: &GpuRasterizer,
    gp: &GpuParams,
    p: &Params<f32>,
    g: &BevGeometry,
    origin: [f64; 3],
    progress: &mut dyn FnMut(usize, usize),
    per_chunk: bool,
) -> Result<BevImage, GpuError> {
    let ch = p.channels;
    let mut out = BevImage::blank(g.width, g.height, ch);
    // Mean elevation of the surfels in each chunk (chunks without any are skipped).
    // A chunk is CHUNK pixels a side unless its surfels would not fit one GPU binding
    // (a map coarser than the surfel grid: 256 px of 25 cm over a 3 cm grid held
    // 1.76 M surfels): then halved until the densest one fits in half the binding.
    let limit = ctx.limits.max_storage_buffer_binding_size as f64;
    let per = crate::render::gpu::candidate_bytes(ch) as f64;
    let mut chunk = CHUNK;
    let (cw, sums) = loop {
        let (cw, chh) = (g.width.div_ceil(chunk), g.height.div_ceil(chunk));
        let mut sums = vec![(0.0f64, 0usize); (cw * chh) as usize];
        for q in &p.pos {
            let col = ((q[0] as f64 + origin[0] - g.origin[0]) / g.resolution).floor();
            let row = ((g.origin[1] - q[1] as f64 - origin[1]) / g.resolution).floor();
            if col < 0.0 || row < 0.0 || col >= g.width as f64 || row >= g.height as f64 {
                continue;
            }
            let k = (row as u32 / chunk * cw + col as u32 / chunk) as usize;
            sums[k].0 += q[2] as f64;
            sums[k].1 += 1;
        }
        let densest = sums.iter().map(|s| s.1).max().unwrap_or(0) as f64;
        let side = chunk as f64 * g.resolution;
        let widened = ((side + 2.0 * (3.0 * g.resolution + 1.0)) / side).powi(2);
        if !per_chunk || chunk <= 8 || densest * widened * per <= 0.5 * limit {
            break (cw, sums);
        }
        chunk /= 2;
    };
    // A chunk lists only the surfels that can reach it: those whose own ±3σ
    // footprint (both axes) reaches its square widened by the low-pass floor's
    // pixels and a metre for the parallax of relief seen from HEIGHT_M. Listing every
    // surfel for every chunk needed a per-view buffer the size of the model (183 MiB
    // at 5 cm on `nuscenes-like`, beyond lavapipe's 128 MiB binding); widening the
    // square by the largest surfel's reach did too on a model with a few surfels
    // metres wide (a corridor far wider than the views see).
    let reach: Vec<f32> = p
        .log_scale
        .iter()
        .map(|s| {
            let r = 2.0
                * EXTENT_SIGMA as f32
                * s.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v)).exp();
            if r.is_finite() {
                r
            } else {
                1e6
            }
        })
        .collect();
    let fp = Footprints {
        reach: &reach,
        half: (chunk as f64 / 2.0 * g.resolution + 3.0 * g.resolution + 1.0) as f32,
    };
    // The box `project` applies on the GPU: depth only (the candidates did x and y).
    let cull = CullConfig {
        near: (HEIGHT_M - 200.0) as f32,
        far: (HEIGHT_M + 200.0) as f32,
        half_width: 1e6,
        half_height: f32::INFINITY,
    };
    let total = sums.iter().filter(|s| s.1 > 0).count();
    let mut done = 0;
    for (k, &(sum, count)) in sums.iter().enumerate() {
        if count == 0 {
            continue;
        }
        let (c0, r0) = ((k as u32 % cw) * chunk, (k as u32 / cw) * chunk);
        let z_mean = sum / count as f64;
        let cam = chunk_camera(g, origin, chunk, (c0, r0), z_mean);
        let f = raster
            .forward_map(ctx, gp, &cam, &cull, per_chunk.then_some(&fp))
            .await?;
        let img = GpuRasterizer::read_image(ctx, &f).await?;
        let zc = z_mean + HEIGHT_M;
        for y in 0..chunk.min(g.height - r0) {
            for x in 0..chunk.min(g.width - c0) {
                let s = (y * chunk + x) as usize;
                let d = ((r0 + y) * g.width + c0 + x) as usize;
                let a = img.alpha[s];
                out.alpha[d] = a;
                if a <= 1e-3 {
                    continue;
                }
                for c in 0..3 {
                    out.rgb[3 * d + c] = img.rgb[3 * s + c] / a;
                }
                for c in 0..ch {
                    out.logits[ch * d + c] = img.logits[ch * s + c] / a;
                }
                out.elevation[d] = (origin[2] + zc - (img.depth[s] / a) as f64) as f32;
            }
        }
        done += 1;
        progress(done, total);
    }
    Ok(out)
}

/// The BEV raster of an image: pixels with alpha ≥ `min_alpha` are valid; the class is
/// the most likely among `road_channels` (dense channel → class id).
pub fn to_raster(
    img: &BevImage,
    g: &BevGeometry,
    road_channels: &[(usize, u8)],
    min_alpha: f32,
) -> BevRaster {
    let mut r = BevRaster::empty(g.origin, g.resolution, g.width, g.height);
    let ch = img.channels;
    for i in 0..(g.width * g.height) as usize {
        let (x, y) = (i as u32 % g.width, i as u32 / g.width);
        if img.alpha[i] < min_alpha {
            continue;
        }
        let px = [0, 1, 2].map(|c| (img.rgb[3 * i + c].clamp(0.0, 1.0) * 255.0).round() as u8);
        r.rgb.put_pixel(x, y, image::Rgb(px));
        let best = road_channels
            .iter()
            .max_by(|a, b| img.logits[ch * i + a.0].total_cmp(&img.logits[ch * i + b.0]));
        if let Some(&(_, id)) = best {
            r.class_ids.put_pixel(x, y, image::Luma([id]));
        }
        r.elevation[i] = img.elevation[i];
        r.valid.put_pixel(x, y, image::Luma([255]));
    }
    r
}
