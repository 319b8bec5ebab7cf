//! Oracle of `shaders/rasterize.wgsl`: front-to-back compositing per pixel over the
//! depth-ordered surfels of its tile, evaluating each surfel where the pixel ray meets
//! its plane, with a screen-space low-pass floor.

use super::project::{tile_lists, Projected};
use super::real::{dot, scale, sub, Real, V3};
use super::{
    Compositing, CullConfig, Image, Params, ViewCamera, LOWPASS_INV_SQ, MAX_ALPHA, MIN_ALPHA,
    MIN_TRANSMITTANCE, TILE,
};

/// One surfel evaluated at one pixel.
#[derive(Clone, Copy, Debug)]
pub struct Eval<R> {
    /// Ray direction (camera space, z = 1).
    pub d: V3<R>,
    /// Ray parameter of the plane hit, the hit relative to the centre, plane coords.
    pub lambda: R,
    pub q: V3<R>,
    pub u: R,
    pub v: R,
    /// Pixel minus projected centre.
    pub delta: [R; 2],
    /// True when the ray–plane distance (not the low-pass floor) is the smaller.
    pub ray_hit: bool,
    pub rho: R,
    pub g: R,
    /// σ(opacity)·G before the clamp, and the clamped alpha.
    pub raw_alpha: R,
    pub alpha: R,
}

/// Evaluates surfel `s` at the pixel centre (px, py).
pub fn eval<R: Real>(s: &Projected<R>, px: R, py: R, cam: &ViewCamera) -> Eval<R> {
    let d = [
        (px - R::of(cam.cx as f64)) / R::of(cam.fx as f64),
        (py - R::of(cam.cy as f64)) / R::of(cam.fy as f64),
        R::of(1.0),
    ];
    let nd = dot(s.n, d);
    let np = dot(s.n, s.pc);
    let zero = R::of(0.0);
    // Edge-on (the ray runs in the plane) or behind: no ray hit; the low-pass decides.
    let (mut lambda, mut q, mut u, mut v, mut rho3) = (zero, [zero; 3], zero, zero, R::big());
    if nd.abs() > R::of(1e-6) {
        let l = np / nd;
        if l > zero {
            lambda = l;
            q = sub(scale(d, l), s.pc);
            u = dot(q, s.tu) / s.su;
            v = dot(q, s.tv) / s.sv;
            rho3 = u * u + v * v;
        }
    }
    let delta = [px - s.mu[0], py - s.mu[1]];
    let rho2 = R::of(LOWPASS_INV_SQ) * (delta[0] * delta[0] + delta[1] * delta[1]);
    let ray_hit = rho3 < rho2;
    let rho = if ray_hit { rho3 } else { rho2 };
    let g = (R::of(-0.5) * rho).exp();
    let raw_alpha = s.opacity * g;
    let alpha = raw_alpha.min(R::of(MAX_ALPHA));
    Eval {
        d,
        lambda,
        q,
        u,
        v,
        delta,
        ray_hit,
        rho,
        g,
        raw_alpha,
        alpha,
    }
}

/// Everything the backward pass needs from the forward pass.
pub struct Forward<R> {
    pub image: Image<R>,
    pub projected: Vec<Option<Projected<R>>>,
    /// (sort key, surfel) pairs in compositing order.
    pub pairs: Vec<(u32, u32)>,
    /// Per tile: range into `pairs`.
    pub ranges: Vec<(usize, usize)>,
    /// Per pixel: final transmittance and one past the last contributing pair.
    pub t_final: Vec<R>,
    pub last: Vec<usize>,
    /// Per pixel: composited colour before exposure.
    pub colour: Vec<R>,
}

pub fn tile_ranges(pairs: &[(u32, u32)], tiles: u32, tile_bits: u32) -> Vec<(usize, usize)> {
    let shift = 32 - tile_bits;
    let mut ranges = vec![(0, 0); tiles as usize];
    let mut k = 0;
    while k < pairs.len() {
        let t = (pairs[k].0 >> shift) as usize;
        let start = k;
        while k < pairs.len() && (pairs[k].0 >> shift) as usize == t {
            k += 1;
        }
        ranges[t] = (start, k);
    }
    ranges
}

// Index loops mirror the kernel line by line, which is the point of an oracle.
pub fn render<R: Real>(p: &Params<R>, cam: &ViewCamera, cull: &CullConfig) -> Forward<R> {
    render_with(p, cam, cull, Compositing::Occlusion)
}

/// `render` with the given compositing (`Compositing::Average`: the map's view).
#[allow(clippy::needless_range_loop)]
pub fn render_with<R: Real>(
    p: &Params<R>,
    cam: &ViewCamera,
    cull: &CullConfig,
    comp: Compositing,
) -> Forward<R> {
    let average = comp == Compositing::Average;
    let (projected, pairs) = tile_lists(p, cam, cull);
    let ranges = tile_ranges(
        &pairs,
        cam.tiles_x() * cam.tiles_y(),
        super::project::tile_bits(cam),
    );
    let (w, h, ch) = (cam.width, cam.height, p.channels);
    let npx = (w * h) as usize;
    let zero = R::of(0.0);
    let mut image = Image {
        width: w,
        height: h,
        rgb: vec![zero; 3 * npx],
        logits: vec![zero; ch * npx],
        depth: vec![zero; npx],
        alpha: vec![zero; npx],
        channels: ch,
    };
    let mut t_final = vec![R::of(1.0); npx];
    let mut last = vec![0; npx];
    let mut colour = vec![zero; 3 * npx];
    let gain = R::of(cam.exposure[0] as f64).exp();
    let bias = R::of(cam.exposure[1] as f64);
    for y in 0..h {
        for x in 0..w {
            let pix = (y * w + x) as usize;
            let tile = ((y / TILE) * cam.tiles_x() + x / TILE) as usize;
            let (start, end) = ranges[tile];
            let (px, py) = (R::of(x as f64 + 0.5), R::of(y as f64 + 0.5));
            let mut t = R::of(1.0);
            let mut c = [zero; 3];
            let mut wsum = zero;
            for k in start..end {
                let i = pairs[k].1 as usize;
                let Some(s) = &projected[i] else { continue };
                let e = eval(s, px, py, cam);
                if e.alpha < R::of(MIN_ALPHA) {
                    continue;
                }
                let t_next = t * (R::of(1.0) - e.alpha);
                if t_next < R::of(MIN_TRANSMITTANCE) && !average {
                    break;
                }
                let wgt = if average { e.alpha } else { e.alpha * t };
                wsum += wgt;
                for (cc, &pc) in c.iter_mut().zip(&p.rgb[i]) {
                    *cc += pc * wgt;
                }
                for j in 0..ch {
                    image.logits[pix * ch + j] += p.logits[i * ch + j] * wgt;
                }
                image.depth[pix] += s.pc[2] * wgt;
                t = t_next;
                last[pix] = k + 1;
            }
            if average && wsum > zero {
                // The weighted mean, scaled by the coverage.
                let scale = (R::of(1.0) - t) / wsum;
                c.iter_mut().for_each(|v| *v = *v * scale);
                for j in 0..ch {
                    image.logits[pix * ch + j] = image.logits[pix * ch + j] * scale;
                }
                image.depth[pix] = image.depth[pix] * scale;
            }
            for j in 0..3 {
                colour[3 * pix + j] = c[j];
                image.rgb[3 * pix + j] = gain * c[j] + bias;
            }
            image.alpha[pix] = R::of(1.0) - t;
            t_final[pix] = t;
        }
    }
    Forward {
        image,
        projected,
        pairs,
        ranges,
        t_final,
        last,
        colour,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two overlapping coplanar surfels, red and blue, seen from 10 m straight above,
    /// one a millimetre above the other, then the other way round.
    fn pair(red_higher: bool, comp: Compositing) -> Vec<f64> {
        let cam = ViewCamera {
            world_to_cam: [
                [1.0, 0.0, 0.0, 0.0],
                [0.0, -1.0, 0.0, 0.0],
                [0.0, 0.0, -1.0, 10.0],
            ],
            fx: 160.0,
            fy: 160.0,
            cx: 8.0,
            cy: 8.0,
            width: 16,
            height: 16,
            exposure: [0.0, 0.0],
        };
        let dz = if red_higher { 0.001 } else { -0.001 };
        let p = Params::<f64> {
            pos: vec![[-0.05, 0.0, dz], [0.05, 0.0, 0.0]],
            rotation: vec![[1.0, 0.0, 0.0, 0.0]; 2],
            log_scale: vec![[0.06f64.ln(); 2]; 2],
            opacity: vec![2.0; 2],
            rgb: vec![[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            logits: vec![],
            channels: 0,
        };
        let cull = CullConfig::default();
        render_with(&p, &cam, &cull, comp).image.rgb
    }

    #[test]
    fn the_maps_view_does_not_depend_on_which_coplanar_surfel_lies_higher() {
        let diff = |comp| {
            let (a, b) = (pair(true, comp), pair(false, comp));
            a.iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
        };
        // Front to back, the higher one covers the overlap: the image changes. The
        // mean changes only by the millimetre's perspective (1e-4 of the scale).
        assert!(diff(Compositing::Occlusion) > 0.1);
        assert!(
            diff(Compositing::Average) < 1e-3,
            "{}",
            diff(Compositing::Average)
        );
        // Between the two centres both colours count.
        let img = pair(true, Compositing::Average);
        let mid = 3 * (8 * 16 + 8);
        let (r, b) = (img[mid], img[mid + 2]);
        assert!(
            r > 0.2 * (r + b) && b > 0.2 * (r + b),
            "{:?}",
            &img[mid..mid + 3]
        );
    }
}
