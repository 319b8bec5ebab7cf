//! Oracle of `shaders/project.wgsl`: cull, transform to the camera, screen bounds in
//! tiles, and the sort key (tile, quantised depth) of every surfel–tile pair.

use super::real::{quat_columns, sigmoid, Real, V3};
use super::{CullConfig, Params, ViewCamera, EXTENT_SIGMA, TILE};

/// A surfel in camera space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Projected<R> {
    pub pc: V3<R>,
    /// Unit tangent axes and normal, camera space.
    pub tu: V3<R>,
    pub tv: V3<R>,
    pub n: V3<R>,
    pub su: R,
    pub sv: R,
    /// Projected centre, pixels.
    pub mu: [R; 2],
    pub opacity: R,
    /// Tile rectangle [x0, y0, x1, y1) its screen bounds overlap.
    pub tiles: [u32; 4],
    /// Which tiles of that rectangle it touches (`footprint_mask`): bit j is the
    /// rectangle's j-th tile in row-major order.
    pub mask: u32,
}

impl<R> Projected<R> {
    /// The tiles it is listed in, in row-major order (`tiles` filtered by `mask`).
    pub fn listed_tiles(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        let [x0, y0, x1, y1] = self.tiles;
        (y0..y1)
            .flat_map(move |ty| (x0..x1).map(move |tx| (tx, ty)))
            .enumerate()
            .filter(|&(j, _)| j >= 32 || self.mask & (1 << j) != 0)
            .map(|(_, t)| t)
    }
}

/// Boxes of more tiles than this keep them all (the mask has 32 bits).
pub const MASK_TILES: u32 = 32;

/// Which tiles of the box `tiles` = [x0, y0, x1, y1) the footprint touches: the
/// projected ±3σ parallelogram `q` (its corners in order around it, pixels) or the
/// ±2 px square around the centre `mu` (the low-pass floor). Bit j is the box's j-th
/// tile in row-major order. A tile is dropped when one edge of the parallelogram has
/// all four of its corners strictly outside (a separating axis; the box's own axes
/// are the box). Boxes of more than `MASK_TILES` tiles, and a parallelogram reaching
/// behind the camera (`whole`), keep every tile. A thin oblique footprint (a road
/// surfel seen at a grazing angle, a side camera's diagonal) touches far fewer tiles
/// than its box: 3–14 % fewer pairs per view (docs/PERFORMANCE.md).
pub fn footprint_mask<R: Real>(tiles: [u32; 4], q: [[R; 2]; 4], mu: [R; 2], whole: bool) -> u32 {
    let [x0, y0, x1, y1] = tiles;
    let n = (x1 - x0) * (y1 - y0);
    if whole || n > MASK_TILES {
        return u32::MAX;
    }
    let cross = |a: [R; 2], b: [R; 2]| a[0] * b[1] - a[1] * b[0];
    let sub = |a: [R; 2], b: [R; 2]| [a[0] - b[0], a[1] - b[1]];
    let area = cross(sub(q[1], q[0]), sub(q[2], q[0])) + cross(sub(q[2], q[0]), sub(q[3], q[0]));
    let sgn = if area >= R::of(0.0) {
        R::of(1.0)
    } else {
        R::of(-1.0)
    };
    let (t, lp) = (R::of(TILE as f64), R::of(2.0));
    let mut mask = 0;
    let mut j = 0;
    for ty in y0..y1 {
        for tx in x0..x1 {
            let lo = [R::of(tx as f64) * t, R::of(ty as f64) * t];
            let hi = [lo[0] + t, lo[1] + t];
            let square = mu[0] + lp >= lo[0]
                && mu[0] - lp <= hi[0]
                && mu[1] + lp >= lo[1]
                && mu[1] - lp <= hi[1];
            let separated = (0..4).any(|e| {
                let (p, d) = (q[e], sub(q[(e + 1) % 4], q[e]));
                let nrm = [-d[1] * sgn, d[0] * sgn];
                let side = |x: R, y: R| nrm[0] * (x - p[0]) + nrm[1] * (y - p[1]);
                side(lo[0], lo[1])
                    .max(side(hi[0], lo[1]))
                    .max(side(lo[0], hi[1]).max(side(hi[0], hi[1])))
                    < R::of(0.0)
            });
            if square || !separated {
                mask |= 1 << j;
            }
            j += 1;
        }
    }
    mask
}

pub fn to_cam<R: Real>(cam: &ViewCamera, p: V3<R>) -> V3<R> {
    let m = &cam.world_to_cam;
    [0, 1, 2].map(|i| {
        R::of(m[i][0] as f64) * p[0]
            + R::of(m[i][1] as f64) * p[1]
            + R::of(m[i][2] as f64) * p[2]
            + R::of(m[i][3] as f64)
    })
}

pub fn rot_to_cam<R: Real>(cam: &ViewCamera, v: V3<R>) -> V3<R> {
    let m = &cam.world_to_cam;
    [0, 1, 2].map(|i| {
        R::of(m[i][0] as f64) * v[0] + R::of(m[i][1] as f64) * v[1] + R::of(m[i][2] as f64) * v[2]
    })
}

/// Projects surfel `i`, or `None` when it is culled or covers no tile.
pub fn project<R: Real>(
    p: &Params<R>,
    i: usize,
    cam: &ViewCamera,
    cull: &CullConfig,
) -> Option<Projected<R>> {
    let pc = to_cam(cam, p.pos[i]);
    if pc[2] < R::of(cull.near as f64)
        || pc[2] > R::of(cull.far as f64)
        || pc[0].abs() > R::of(cull.half_width as f64)
    {
        return None;
    }
    let [tu_w, tv_w, n_w] = quat_columns(p.rotation[i]);
    let (tu, tv, n) = (
        rot_to_cam(cam, tu_w),
        rot_to_cam(cam, tv_w),
        rot_to_cam(cam, n_w),
    );
    let su = p.log_scale[i][0].exp();
    let sv = p.log_scale[i][1].exp();
    let (fx, fy, cx, cy) = (
        R::of(cam.fx as f64),
        R::of(cam.fy as f64),
        R::of(cam.cx as f64),
        R::of(cam.cy as f64),
    );
    let mu = [fx * pc[0] / pc[2] + cx, fy * pc[1] / pc[2] + cy];
    // Screen bounds: the projected corners of the ±3σ parallelogram, and at least
    // ±2 px around the centre for the low-pass floor.
    let e = R::of(EXTENT_SIGMA);
    let lp = R::of(2.0);
    let (mut x0, mut y0, mut x1, mut y1) = (mu[0] - lp, mu[1] - lp, mu[0] + lp, mu[1] + lp);
    // The corners in order around the parallelogram.
    let mut q = [[R::of(0.0); 2]; 4];
    let mut whole = false;
    for (j, (a, b)) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .into_iter()
        .enumerate()
    {
        let c = [0, 1, 2].map(|k| pc[k] + R::of(a) * e * su * tu[k] + R::of(b) * e * sv * tv[k]);
        let near = R::of(0.1 * cull.near as f64);
        whole |= c[2] < near;
        let z = c[2].max(near);
        let (u, v) = (fx * c[0] / z + cx, fy * c[1] / z + cy);
        q[j] = [u, v];
        x0 = x0.min(u);
        x1 = x1.max(u);
        y0 = y0.min(v);
        y1 = y1.max(v);
    }
    let (w, h) = (R::of(cam.width as f64), R::of(cam.height as f64));
    if x1 < R::of(0.0) || y1 < R::of(0.0) || x0 >= w || y0 >= h {
        return None;
    }
    let t = R::of(TILE as f64);
    let clampt = |v: R, max: u32| {
        (v / t)
            .floor()
            .max(R::of(0.0))
            .min(R::of(max as f64))
            .to_f64() as u32
    };
    let tiles = [
        clampt(x0, cam.tiles_x()),
        clampt(y0, cam.tiles_y()),
        clampt(x1, cam.tiles_x() - 1) + 1,
        clampt(y1, cam.tiles_y() - 1) + 1,
    ];
    let mask = footprint_mask(tiles, q, mu, whole);
    Some(Projected {
        pc,
        tu,
        tv,
        n,
        su,
        sv,
        mu,
        opacity: sigmoid(p.opacity[i]),
        tiles,
        mask,
    })
}

/// Bits of the sort key given to the tile index: the rest quantise depth.
pub fn tile_bits(cam: &ViewCamera) -> u32 {
    let tiles = cam.tiles_x() * cam.tiles_y();
    32 - (tiles.max(2) - 1).leading_zeros()
}

/// Sort key of a surfel in a tile: tile index in the high bits, depth (quantised
/// over [near, far], computed in f32 exactly as the GPU does) in the low bits.
pub fn sort_key(cam: &ViewCamera, cull: &CullConfig, tile: u32, depth: f32) -> u32 {
    let bits = 32 - tile_bits(cam);
    let levels = ((1u64 << bits) - 1) as f32;
    let d = ((depth - cull.near) / (cull.far - cull.near)).clamp(0.0, 1.0);
    let q = (d * levels) as u32;
    (tile << bits) | q.min(((1u64 << bits) - 1) as u32)
}

/// The projected surfels and the (sort key, surfel) pairs of a view.
pub type TileLists<R> = (Vec<Option<Projected<R>>>, Vec<(u32, u32)>);

/// Every (key, surfel) pair of the view, in the order the GPU sorts them to: by key,
/// ties by surfel index (the sort is stable and pairs are emitted in surfel order).
pub fn tile_lists<R: Real>(p: &Params<R>, cam: &ViewCamera, cull: &CullConfig) -> TileLists<R> {
    let projected: Vec<Option<Projected<R>>> =
        (0..p.len()).map(|i| project(p, i, cam, cull)).collect();
    let mut pairs = Vec::new();
    for (i, pr) in projected.iter().enumerate() {
        let Some(pr) = pr else { continue };
        for (tx, ty) in pr.listed_tiles() {
            let tile = ty * cam.tiles_x() + tx;
            pairs.push((
                sort_key(cam, cull, tile, pr.pc[2].to_f64() as f32),
                i as u32,
            ));
        }
    }
    pairs.sort_by_key(|&(k, _)| k);
    (projected, pairs)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether (x, y) lies inside the convex quadrilateral `q` (either orientation).
    fn inside(q: &[[f64; 2]; 4], x: f64, y: f64) -> bool {
        let s: Vec<f64> = (0..4)
            .map(|e| {
                let (p, r) = (q[e], q[(e + 1) % 4]);
                (r[0] - p[0]) * (y - p[1]) - (r[1] - p[1]) * (x - p[0])
            })
            .collect();
        s.iter().all(|&v| v >= 0.0) || s.iter().all(|&v| v <= 0.0)
    }

    #[test]
    fn the_footprint_mask_drops_only_tiles_the_footprint_misses() {
        let t = TILE as f64;
        let mut dropped = 0;
        // Thin oblique parallelograms at several angles and lengths, both orientations.
        for k in 0..40 {
            let a = 0.3 + 0.07 * k as f64;
            let (len, wid) = (10.0 + 2.0 * k as f64, 1.0 + (k % 5) as f64);
            let c = [30.0 + k as f64, 25.0];
            let (u, v) = (
                [a.cos() * len, a.sin() * len],
                [-a.sin() * wid, a.cos() * wid],
            );
            let mut q = [
                [c[0] - u[0] - v[0], c[1] - u[1] - v[1]],
                [c[0] + u[0] - v[0], c[1] + u[1] - v[1]],
                [c[0] + u[0] + v[0], c[1] + u[1] + v[1]],
                [c[0] - u[0] + v[0], c[1] - u[1] + v[1]],
            ];
            if k % 2 == 1 {
                q.reverse();
            }
            let lo = q
                .iter()
                .fold([f64::MAX; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
            let hi = q
                .iter()
                .fold([f64::MIN; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
            let tiles = [
                (lo[0] / t).floor() as u32,
                (lo[1] / t).floor() as u32,
                (hi[0] / t).floor() as u32 + 1,
                (hi[1] / t).floor() as u32 + 1,
            ];
            let mask = footprint_mask(tiles, q, c, false);
            let p = Projected {
                pc: [0.0; 3],
                tu: [0.0; 3],
                tv: [0.0; 3],
                n: [0.0; 3],
                su: 0.0,
                sv: 0.0,
                mu: c,
                opacity: 0.0,
                tiles,
                mask,
            };
            let listed: Vec<(u32, u32)> = p.listed_tiles().collect();
            for ty in tiles[1]..tiles[3] {
                for tx in tiles[0]..tiles[2] {
                    // Points of the tile on a fine grid, its edges included.
                    let hit = (0..=16).any(|i| {
                        (0..=16).any(|j| {
                            let (x, y) = (
                                (tx as f64 + i as f64 / 16.0) * t,
                                (ty as f64 + j as f64 / 16.0) * t,
                            );
                            inside(&q, x, y)
                        })
                    });
                    let kept = listed.contains(&(tx, ty));
                    assert!(
                        kept || !hit,
                        "shape {k}: tile ({tx}, {ty}) is touched but dropped"
                    );
                    dropped += usize::from(!kept);
                }
            }
        }
        assert!(
            dropped > 50,
            "oblique footprints should drop tiles of their box: {dropped}"
        );
        // Too many tiles, or behind the camera: every tile.
        let q = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        assert_eq!(footprint_mask([0, 0, 4, 4], q, [0.5, 0.5], true), u32::MAX);
        assert_eq!(footprint_mask([0, 0, 8, 5], q, [0.5, 0.5], false), u32::MAX);
    }
}
