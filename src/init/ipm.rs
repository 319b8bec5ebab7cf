//! Inverse perspective mapping: world points on the initial surface projected into
//! the camera views that see them best (the nearest frames' cameras, smallest depth,
//! not covered by an ignore class). Used by adaptive refinement, and as the baseline
//! map (an RGB/label mosaic of the images draped on the initial surface) that the
//! optimiser's result is compared with.

use super::PoseIndex;
use crate::bundle::transform::{inverse as rigid_inverse, mul};
use crate::bundle::{Bundle, ClassRole, Manifest, Mat4Rows, Problem};
use crate::eval::BevRaster;
use crate::grid::Grid;
use image::{GrayImage, RgbImage};
use std::collections::HashMap;

/// One camera image of one frame, ready to project into.
pub struct CamView {
    pub frame: usize,
    pub view: usize,
    world_to_cam: Mat4Rows,
    pub fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    w: f64,
    h: f64,
}

/// Where a world point lands in a view.
#[derive(Clone, Copy, Debug, Default)]
pub struct Projection {
    pub cam: u32,
    pub u: f32,
    pub v: f32,
    pub depth: f32,
}

/// Most views kept of one point: the nearest, and the next ones to fall back on
/// where the nearest's label ignores the pixel.
pub const MAX_VIEWS: usize = 3;

/// Up to `MAX_VIEWS` views of one point, nearest first, held inline. Every surfel
/// of a tile keeps its views until the images are sampled; a heap allocation
/// apiece (millions at 5 cm, made on worker threads between a tile's larger
/// buffers) left the allocator's pages fragmented and resident memory creeping up
/// tile after tile.
#[derive(Clone, Copy, Debug, Default)]
pub struct Views {
    len: u8,
    list: [Projection; MAX_VIEWS],
}

impl Views {
    /// The first `MAX_VIEWS` of `v`.
    pub fn new(v: &[Projection]) -> Self {
        let mut out = Views::default();
        for (slot, p) in out.list.iter_mut().zip(v) {
            *slot = *p;
            out.len += 1;
        }
        out
    }
}

impl std::ops::Deref for Views {
    type Target = [Projection];
    fn deref(&self) -> &[Projection] {
        &self.list[..self.len as usize]
    }
}

/// All views of a bundle, by frame.
pub struct Cams {
    pub list: Vec<CamView>,
    by_frame: Vec<Vec<usize>>,
}

/// Frames searched for a view of a point: forward cameras see the road from a few
/// metres ahead, so the nearest frames alone often do not see it.
pub const CANDIDATE_FRAMES: usize = 16;

/// Frames searched for a point's views: `CANDIDATE_FRAMES` per drive, so that where
/// several drives pass, each drive's nearest frames are among them.
pub fn candidate_frames(b: &Bundle) -> usize {
    CANDIDATE_FRAMES * b.drives.len().max(1)
}

/// Views decoded at once (each 800×225 view is ~0.7 MB decoded).
const DECODE_CHUNK: usize = 32;

/// Nearer than this a point is behind the lens or distorted beyond use.
const MIN_DEPTH: f64 = 0.5;
/// Farther than this a road point is a few pixels wide at best.
const MAX_DEPTH: f64 = 35.0;
/// Farthest a camera stands from its frame's pose in xy (the rig's offsets), metres.
const RIG_REACH: f64 = 5.0;
/// Most frames searched for the views of one point (`Cams::views_near`).
const MAX_FRAMES: usize = 1024;

impl Cams {
    pub fn new(m: &Manifest) -> Self {
        let mut list = Vec::new();
        let mut by_frame = Vec::new();
        for (fi, f) in m.frames.iter().enumerate() {
            let mut ids = Vec::new();
            for (vi, v) in f.views.iter().enumerate() {
                let Some(c) = m.camera(&v.camera) else {
                    continue;
                };
                ids.push(list.len());
                list.push(CamView {
                    frame: fi,
                    view: vi,
                    world_to_cam: rigid_inverse(&mul(f.view_pose(v), &c.camera_to_vehicle)),
                    fx: c.fx,
                    fy: c.fy,
                    cx: c.cx,
                    cy: c.cy,
                    w: c.width as f64,
                    h: c.height as f64,
                });
            }
            by_frame.push(ids);
        }
        Self { list, by_frame }
    }

    /// Pixel position and depth of world point `p` in camera `c`, if inside the image.
    pub fn project(&self, c: usize, p: [f64; 3]) -> Option<Projection> {
        let v = &self.list[c];
        let m = &v.world_to_cam;
        let q = [0, 1, 2].map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3]);
        if !(MIN_DEPTH..MAX_DEPTH).contains(&q[2]) {
            return None;
        }
        let u = v.fx * q[0] / q[2] + v.cx;
        let vv = v.fy * q[1] / q[2] + v.cy;
        (u >= 1.0 && vv >= 1.0 && u < v.w - 1.0 && vv < v.h - 1.0).then_some(Projection {
            cam: c as u32,
            u: u as f32,
            v: vv as f32,
            depth: q[2] as f32,
        })
    }

    /// Up to `n` views of `p`, nearest in depth first, among the frames nearest to
    /// it in xy that `use_frame` accepts, and the frames searched: the nearest
    /// `frames`, then four times as many while fewer than `n` of their views see `p`,
    /// until the frames searched reach past `MAX_DEPTH` (or `MAX_FRAMES`). A forward
    /// camera sees the road only from metres ahead: where a drive passes a place
    /// twice (out and back, a loop, a second drive), its nearest frames are both
    /// passes' frames beside the place and none of them sees it; a fixed count of
    /// nearest frames left the middle of an out-and-back drive unseen, so unmapped.
    pub fn views_near(
        &self,
        poses: &PoseIndex,
        p: [f64; 3],
        frames: usize,
        n: usize,
        use_frame: &(dyn Fn(usize) -> bool + Sync),
    ) -> (Vec<usize>, Views) {
        let mut k = frames.max(1);
        loop {
            let near = poses.nearest(p[0], p[1], k);
            let reached = near.len() < k
                || k >= MAX_FRAMES
                || near.last().is_some_and(|l| l.0 > MAX_DEPTH + RIG_REACH);
            let ids: Vec<usize> = near
                .into_iter()
                .map(|(_, f)| f)
                .filter(|&f| use_frame(f))
                .collect();
            let out = self.candidates_in(&ids, p, n);
            if out.len() >= n || reached {
                return (ids, out);
            }
            k *= 4;
        }
    }

    /// Up to `n` (at most `MAX_VIEWS`) views of `p` among the cameras of `frames`,
    /// nearest first.
    pub fn candidates_in(&self, frames: &[usize], p: [f64; 3], n: usize) -> Views {
        let mut out: Vec<Projection> = frames
            .iter()
            .flat_map(|&f| {
                self.by_frame[f]
                    .iter()
                    .filter_map(|&c| self.project(c, p))
                    .collect::<Vec<_>>()
            })
            .collect();
        out.sort_by(|a, b| a.depth.total_cmp(&b.depth));
        Views::new(&out[..n.min(out.len())])
    }
}

/// Decoded images of one view.
pub struct ViewImages {
    pub rgb: RgbImage,
    pub label: GrayImage,
}

/// For every point, calls `f(point, images, projection)` with the best candidate view
/// whose pixel is not an ignore class (trying the next candidate otherwise). Each view
/// is decoded once per pass; returns how many points found a usable view.
pub fn sample_best<F>(
    b: &Bundle,
    cams: &Cams,
    candidates: &[Views],
    mut f: F,
) -> Result<usize, Problem>
where
    F: FnMut(usize, &ViewImages, &Projection),
{
    let m = &b.manifest;
    // Ids outside the table (a drive without labels' 0) are never sampled either.
    let classes = m.classes();
    let ignore: Vec<bool> = (0..=255u8)
        .map(|id| {
            !classes
                .iter()
                .any(|c| c.id == id && c.role == ClassRole::Road)
        })
        .collect();
    let mut pending: Vec<(usize, usize)> = (0..candidates.len())
        .filter(|&i| !candidates[i].is_empty())
        .map(|i| (i, 0))
        .collect();
    let mut found = 0;
    while !pending.is_empty() {
        let mut by_cam: HashMap<u32, Vec<(usize, usize)>> = HashMap::new();
        for &(i, r) in &pending {
            by_cam.entry(candidates[i][r].cam).or_default().push((i, r));
        }
        let mut keys: Vec<u32> = by_cam.keys().copied().collect();
        keys.sort_unstable();
        let mut next = Vec::new();
        // Decoding dominates: decode a chunk of views in parallel, then sample them.
        for chunk in keys.chunks(DECODE_CHUNK) {
            let decoded = crate::par::par_map(chunk.len(), |k| {
                let cv = &cams.list[chunk[k] as usize];
                let view = &m.frames[cv.frame].views[cv.view];
                Some(b.read_rgb(&view.image).and_then(|rgb| {
                    Ok(ViewImages {
                        rgb,
                        label: b.read_view_label(cv.frame, cv.view)?,
                    })
                }))
            });
            for (&c, imgs) in chunk.iter().zip(decoded) {
                let Some(imgs) = imgs else { continue };
                let imgs = imgs?;
                for &(i, r) in &by_cam[&c] {
                    let p = &candidates[i][r];
                    let class = imgs.label.get_pixel(p.u as u32, p.v as u32).0[0];
                    if ignore[class as usize] {
                        if r + 1 < candidates[i].len() {
                            next.push((i, r + 1));
                        }
                        continue;
                    }
                    f(i, &imgs, p);
                    found += 1;
                }
            }
        }
        pending = next;
    }
    Ok(found)
}

/// The IPM baseline map: for every base vertex of the grid, the colour and label of
/// its best view, on a raster whose pixel centres are the base vertices.
pub fn mosaic(b: &Bundle, grid: &Grid, z: &[f32], poses: &PoseIndex) -> Result<BevRaster, Problem> {
    let cams = Cams::new(&b.manifest);
    let res = grid.resolution;
    let (mut i1, mut j1) = (0, 0);
    for c in &grid.coords {
        i1 = i1.max(c[0] / 2);
        j1 = j1.max(c[1] / 2);
    }
    let (w, h) = (i1 as u32 + 1, j1 as u32 + 1);
    let origin = [
        grid.origin[0] - 0.5 * res,
        grid.origin[1] + (j1 as f64 + 0.5) * res,
    ];
    let mut out = BevRaster::empty(origin, res, w, h);
    let base: Vec<usize> = (0..grid.len()).filter(|&k| grid.level[k] == 0).collect();
    let candidates: Vec<Views> = crate::par::par_map(base.len(), |i| {
        let k = base[i];
        let [x, y] = grid.xy(k);
        let p = [x, y, z[k] as f64];
        cams.views_near(poses, p, candidate_frames(b), 3, &|_| true)
            .1
    });
    sample_best(b, &cams, &candidates, |i, imgs, p| {
        let k = base[i];
        let [ci, cj] = grid.coords[k];
        let (col, row) = ((ci / 2) as u32, (j1 - cj / 2) as u32);
        out.rgb
            .put_pixel(col, row, *imgs.rgb.get_pixel(p.u as u32, p.v as u32));
        out.class_ids
            .put_pixel(col, row, *imgs.label.get_pixel(p.u as u32, p.v as u32));
        out.elevation[(row * w + col) as usize] = z[k];
        out.valid.put_pixel(col, row, image::Luma([255]));
    })?;
    Ok(out)
}

/// A surfel's colour (0..1) and class id from its best view.
pub type SurfelColour = ([f32; 3], u8);

/// Colour (0..1) and class id of every surfel from its best view among the frames
/// `use_frame` accepts: the starting point of optimisation, and the IPM baseline
/// model when nothing else changes. Surfels no accepted view sees get `None`.
pub fn surfel_colours(
    b: &Bundle,
    grid: &Grid,
    z: &[f32],
    poses: &PoseIndex,
    use_frame: &(dyn Fn(usize) -> bool + Sync),
) -> Result<Vec<Option<SurfelColour>>, Problem> {
    let cams = Cams::new(&b.manifest);
    let candidates: Vec<Views> = crate::par::par_map(grid.len(), |k| {
        let [x, y] = grid.xy(k);
        let p = [x, y, z[k] as f64];
        cams.views_near(poses, p, candidate_frames(b), 3, use_frame)
            .1
    });
    let mut out = vec![None; grid.len()];
    sample_best(b, &cams, &candidates, |k, imgs, p| {
        let c = imgs.rgb.get_pixel(p.u as u32, p.v as u32).0;
        let id = imgs.label.get_pixel(p.u as u32, p.v as u32).0[0];
        out[k] = Some((c.map(|v| v as f32 / 255.0), id));
    })?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_keep_the_nearest_first_up_to_their_capacity() {
        let p = |d: f32| Projection {
            cam: d as u32,
            depth: d,
            ..Default::default()
        };
        let all: Vec<Projection> = (1..=5).map(|d| p(d as f32)).collect();
        let cams = |v: &Views| v.iter().map(|q| q.cam).collect::<Vec<_>>();
        assert_eq!(cams(&Views::new(&all)), [1, 2, 3]);
        assert_eq!(cams(&Views::new(&all[..2])), [1, 2]);
        assert!(Views::new(&[]).is_empty());
    }
}
