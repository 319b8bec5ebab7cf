//! The paper's LiDAR pseudo-ground-truth for bundles without BEV truth: every LiDAR
//! point in the world frame (through the bundle's poses), coloured and labelled by
//! projecting it into the nearest frame's cameras (SPEC: the nearest camera images;
//! the first of the three nearest frames that sees it: a forward camera sees little
//! beside its own frame, so on a drive with only one the reference covers little);
//! points that land on an ignore
//! class (cars, sky) are dropped. Rasterised per BEV cell: mean elevation, mean
//! colour, majority label.

use super::raster::BevRaster;
use crate::bundle::transform::{apply, inverse as invert, mul};
use crate::bundle::{Bundle, ClassRole, Mat4Rows, Problem};
use std::collections::HashMap;

/// Accumulated, coloured, labelled LiDAR points in the world frame.
#[derive(Clone, Debug, Default)]
pub struct LidarCloud {
    pub points: Vec<[f64; 3]>,
    pub colors: Vec<[u8; 3]>,
    pub labels: Vec<u8>,
}

/// Frames searched around a sweep's own frame for the nearest camera position.
const WINDOW: usize = 20;

pub fn lidar_cloud(b: &Bundle) -> Result<LidarCloud, Problem> {
    lidar_cloud_in(b, &b.manifest)
}

/// As `lidar_cloud`, through the poses of `m` (the bundle's manifest with other
/// poses: the exact ones of a synthetic drive) and the files of `b`.
pub fn lidar_cloud_in(b: &Bundle, m: &crate::bundle::Manifest) -> Result<LidarCloud, Problem> {
    let Some(sensor) = &m.lidar else {
        return Ok(LidarCloud::default());
    };
    // Ids outside the table (a drive without labels' 0) are never sampled either.
    let classes = m.classes();
    let ignore: Vec<bool> = (0..=255u8)
        .map(|id| {
            !classes
                .iter()
                .any(|c| c.id == id && c.role == ClassRole::Road)
        })
        .collect();
    let mut cache: HashMap<String, (image::RgbImage, image::GrayImage)> = HashMap::new();
    let mut cloud = LidarCloud::default();
    // World to camera of every view, once.
    let to_cam: Vec<Vec<Option<Mat4Rows>>> = m
        .frames
        .iter()
        .map(|f| {
            f.views
                .iter()
                .map(|v| {
                    let cam = m.camera(&v.camera)?;
                    Some(invert(&mul(f.view_pose(v), &cam.camera_to_vehicle)))
                })
                .collect()
        })
        .collect();
    for (k, f) in m.frames.iter().enumerate() {
        let Some(path) = &f.lidar else { continue };
        let to_world = mul(&f.vehicle_to_world, &sensor.lidar_to_vehicle);
        for p in b.read_lidar(path)? {
            let w = apply(&to_world, p.map(|v| v as f64));
            // Nearest frame (vehicle position in xy) within the window around k.
            let lo = k.saturating_sub(WINDOW);
            let hi = (k + WINDOW + 1).min(m.frames.len());
            let mut order: Vec<usize> = (lo..hi).collect();
            let dist = |j: usize| {
                let t = &m.frames[j].vehicle_to_world;
                (t[0][3] - w[0]).hypot(t[1][3] - w[1])
            };
            order.sort_by(|a, b| dist(*a).total_cmp(&dist(*b)));
            if let Some((rgb, label)) = colour_point(
                b,
                m,
                &to_cam,
                &order[..order.len().min(3)],
                w,
                &ignore,
                &mut cache,
            )? {
                if label != IGNORED {
                    cloud.points.push(w);
                    cloud.colors.push(rgb);
                    cloud.labels.push(label);
                }
            }
        }
    }
    Ok(cloud)
}

/// Label returned for points near an ignore class.
const IGNORED: u8 = 255;
/// Ignore classes are dilated by this many pixels (as the official code dilates
/// movable objects): a LiDAR point on a car's edge projects onto road pixels beside it.
const IGNORE_DILATION: i64 = 2;

/// Colour and label of world point `w` from the closest camera (smallest depth) of the
/// first frame in `frames` that sees it (`to_cam`: world to camera per frame and
/// view); `IGNORED` near ignore-class pixels.
fn colour_point(
    b: &Bundle,
    m: &crate::bundle::Manifest,
    to_cam: &[Vec<Option<Mat4Rows>>],
    frames: &[usize],
    w: [f64; 3],
    ignore: &[bool],
    cache: &mut HashMap<String, (image::RgbImage, image::GrayImage)>,
) -> Result<Option<([u8; 3], u8)>, Problem> {
    for &j in frames {
        let f = &m.frames[j];
        let mut best: Option<(f64, usize, u32, u32)> = None;
        for (vi, v) in f.views.iter().enumerate() {
            let (Some(cam), Some(t)) = (m.camera(&v.camera), &to_cam[j][vi]) else {
                continue;
            };
            let c = apply(t, w);
            if c[2] < 0.5 {
                continue;
            }
            let u = cam.fx * c[0] / c[2] + cam.cx;
            let vv = cam.fy * c[1] / c[2] + cam.cy;
            if u < 0.0 || vv < 0.0 || u >= cam.width as f64 || vv >= cam.height as f64 {
                continue;
            }
            if best.is_none_or(|bb| c[2] < bb.0) {
                best = Some((c[2], vi, u as u32, vv as u32));
            }
        }
        if let Some((_, vi, u, v)) = best {
            let view = &f.views[vi];
            if !cache.contains_key(&view.image) {
                if cache.len() > 256 {
                    cache.clear();
                }
                cache.insert(
                    view.image.clone(),
                    (b.read_rgb(&view.image)?, b.read_view_label(j, vi)?),
                );
            }
            if let Some((rgb, lab)) = cache.get(&view.image) {
                let r = IGNORE_DILATION;
                let near_ignore = (-r..=r).any(|dy| {
                    (-r..=r).any(|dx| {
                        let (x, y) = (u as i64 + dx, v as i64 + dy);
                        x >= 0
                            && y >= 0
                            && x < lab.width() as i64
                            && y < lab.height() as i64
                            && ignore[lab.get_pixel(x as u32, y as u32).0[0] as usize]
                    })
                });
                let label = if near_ignore {
                    IGNORED
                } else {
                    lab.get_pixel(u, v).0[0]
                };
                return Ok(Some((rgb.get_pixel(u, v).0, label)));
            }
        }
    }
    Ok(None)
}

/// Rasterises the cloud on `grid`'s geometry: mean elevation and colour, majority label.
pub fn rasterise(cloud: &LidarCloud, grid: &BevRaster) -> BevRaster {
    let mut out = BevRaster::empty(grid.origin, grid.resolution, grid.width, grid.height);
    let n = (grid.width * grid.height) as usize;
    let mut sum = vec![[0.0f64; 4]; n];
    let mut count = vec![0u32; n];
    let mut votes: HashMap<(usize, u8), u32> = HashMap::new();
    for (i, p) in cloud.points.iter().enumerate() {
        let Some((c, r)) = grid.pixel_of(p[0], p[1]) else {
            continue;
        };
        let k = (r * grid.width + c) as usize;
        let col = cloud.colors[i];
        let s = &mut sum[k];
        s[0] += p[2];
        for ch in 0..3 {
            s[ch + 1] += col[ch] as f64;
        }
        count[k] += 1;
        *votes.entry((k, cloud.labels[i])).or_default() += 1;
    }
    let mut best: HashMap<usize, (u32, u8)> = HashMap::new();
    for ((k, label), v) in votes {
        let e = best.entry(k).or_insert((0, label));
        if v > e.0 || (v == e.0 && label < e.1) {
            *e = (v, label);
        }
    }
    for k in 0..n {
        if count[k] == 0 {
            continue;
        }
        let (c, r) = ((k as u32) % grid.width, (k as u32) / grid.width);
        let s = sum[k];
        let cnt = count[k] as f64;
        out.elevation[k] = (s[0] / cnt) as f32;
        out.rgb.put_pixel(
            c,
            r,
            image::Rgb([1, 2, 3].map(|i| (s[i] / cnt).round() as u8)),
        );
        out.class_ids
            .put_pixel(c, r, image::Luma([best.get(&k).map_or(0, |b| b.1)]));
        out.valid.put_pixel(c, r, image::Luma([255]));
    }
    out
}

/// A raster geometry covering the cloud, for bundles without BEV truth.
pub fn cloud_grid(cloud: &LidarCloud, resolution: f64) -> Option<BevRaster> {
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in &cloud.points {
        x0 = x0.min(p[0]);
        y0 = y0.min(p[1]);
        x1 = x1.max(p[0]);
        y1 = y1.max(p[1]);
    }
    if cloud.points.is_empty() {
        return None;
    }
    let w = ((x1 - x0) / resolution).floor() as u32 + 1;
    let h = ((y1 - y0) / resolution).floor() as u32 + 1;
    Some(BevRaster::empty(
        [x0, y1 + resolution * 0.5],
        resolution,
        w,
        h,
    ))
}
