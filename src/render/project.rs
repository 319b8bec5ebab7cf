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
    /// Tile rectangle [x0, y0, x1, y1) it overlaps.
    pub tiles: [u32; 4],
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
    for (a, b) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        let c = [0, 1, 2].map(|k| pc[k] + R::of(a) * e * su * tu[k] + R::of(b) * e * sv * tv[k]);
        let z = c[2].max(R::of(0.1 * cull.near as f64));
        let (u, v) = (fx * c[0] / z + cx, fy * c[1] / z + cy);
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
        for ty in pr.tiles[1]..pr.tiles[3] {
            for tx in pr.tiles[0]..pr.tiles[2] {
                let tile = ty * cam.tiles_x() + tx;
                pairs.push((
                    sort_key(cam, cull, tile, pr.pc[2].to_f64() as f32),
                    i as u32,
                ));
            }
        }
    }
    pairs.sort_by_key(|&(k, _)| k);
    (projected, pairs)
}
