//! Oracle of `shaders/rasterize_backward.wgsl`: per pixel, back to front over the same
//! contributors as the forward pass, the gradient of the loss with respect to each
//! surfel's camera-space quantities (centre, axes, normal, scales, opacity, colour,
//! logits) and to the view's exposure.

use super::rasterize::{eval, Forward};
use super::real::{dot, scale, sub, Real};
use super::{Params, ViewCamera, LOWPASS_INV_SQ, MAX_ALPHA, MIN_ALPHA, TILE};

/// Layout of the per-surfel view gradient (camera space), `VIEW_GRAD + channels` floats.
pub mod slot {
    pub const PC: usize = 0;
    pub const TU: usize = 3;
    pub const TV: usize = 6;
    pub const N: usize = 9;
    pub const SU: usize = 12;
    pub const SV: usize = 13;
    pub const OPACITY: usize = 14;
    pub const RGB: usize = 15;
    pub const LOGITS: usize = 18;
}
pub const VIEW_GRAD: usize = slot::LOGITS;

/// Loss gradients with respect to the forward outputs (same layout as `Image`).
#[derive(Clone, Debug, Default)]
pub struct OutputGrads<R> {
    pub rgb: Vec<R>,
    pub logits: Vec<R>,
    pub depth: Vec<R>,
    pub alpha: Vec<R>,
}

/// Returns the view gradients (stride `VIEW_GRAD + channels` per surfel) and the
/// exposure gradient (d/da, d/db).
// Index loops mirror the kernel line by line, which is the point of an oracle.
#[allow(clippy::needless_range_loop)]
pub fn backward<R: Real>(
    p: &Params<R>,
    cam: &ViewCamera,
    f: &Forward<R>,
    g: &OutputGrads<R>,
) -> (Vec<R>, [R; 2]) {
    let ch = p.channels;
    let stride = VIEW_GRAD + ch;
    let zero = R::of(0.0);
    let one = R::of(1.0);
    let mut vg = vec![zero; stride * p.len()];
    let mut exposure = [zero; 2];
    let gain = R::of(cam.exposure[0] as f64).exp();
    let (w, h) = (cam.width, cam.height);
    for y in 0..h {
        for x in 0..w {
            let pix = (y * w + x) as usize;
            let tile = ((y / TILE) * cam.tiles_x() + x / TILE) as usize;
            let start = f.ranges[tile].0;
            let (px, py) = (R::of(x as f64 + 0.5), R::of(y as f64 + 0.5));
            let mut dc = [zero; 3];
            for j in 0..3 {
                let go = g.rgb[3 * pix + j];
                dc[j] = gain * go;
                exposure[0] += go * gain * f.colour[3 * pix + j];
                exposure[1] += go;
            }
            let dl: Vec<R> = (0..ch).map(|j| g.logits[pix * ch + j]).collect();
            let dd = g.depth[pix];
            let t_final = f.t_final[pix];
            let da_out = g.alpha[pix];
            let mut t = t_final;
            let (mut acc_c, mut acc_l, mut acc_d) = ([zero; 3], vec![zero; ch], zero);
            let (mut last_alpha, mut last_c, mut last_l, mut last_d) =
                (zero, [zero; 3], vec![zero; ch], zero);
            for k in (start..f.last[pix]).rev() {
                let i = f.pairs[k].1 as usize;
                let Some(s) = &f.projected[i] else { continue };
                let e = eval(s, px, py, cam);
                if e.alpha < R::of(MIN_ALPHA) {
                    continue;
                }
                t = t / (one - e.alpha);
                let wgt = e.alpha * t;
                let base = stride * i;
                let mut d_alpha = zero;
                for j in 0..3 {
                    acc_c[j] = last_alpha * last_c[j] + (one - last_alpha) * acc_c[j];
                    last_c[j] = p.rgb[i][j];
                    d_alpha += (p.rgb[i][j] - acc_c[j]) * dc[j];
                    vg[base + slot::RGB + j] += wgt * dc[j];
                }
                for j in 0..ch {
                    let l = p.logits[i * ch + j];
                    acc_l[j] = last_alpha * last_l[j] + (one - last_alpha) * acc_l[j];
                    last_l[j] = l;
                    d_alpha += (l - acc_l[j]) * dl[j];
                    vg[base + slot::LOGITS + j] += wgt * dl[j];
                }
                acc_d = last_alpha * last_d + (one - last_alpha) * acc_d;
                last_d = s.pc[2];
                d_alpha += (s.pc[2] - acc_d) * dd;
                d_alpha = d_alpha * t;
                d_alpha += t_final / (one - e.alpha) * da_out;
                last_alpha = e.alpha;
                // The depth output also depends on the centre depth directly.
                vg[base + slot::PC + 2] += wgt * dd;
                if e.raw_alpha > R::of(MAX_ALPHA) {
                    continue;
                }
                let sig = s.opacity;
                vg[base + slot::OPACITY] += d_alpha * e.g * sig * (one - sig);
                let d_rho = d_alpha * sig * R::of(-0.5) * e.g;
                if e.ray_hit {
                    let (gu, gv) = (d_rho * R::of(2.0) * e.u, d_rho * R::of(2.0) * e.v);
                    vg[base + slot::SU] += -gu * e.u / s.su;
                    vg[base + slot::SV] += -gv * e.v / s.sv;
                    for j in 0..3 {
                        vg[base + slot::TU + j] += gu * e.q[j] / s.su;
                        vg[base + slot::TV + j] += gv * e.q[j] / s.sv;
                    }
                    let gq = [0, 1, 2].map(|j| gu * s.tu[j] / s.su + gv * s.tv[j] / s.sv);
                    let nd = dot(s.n, e.d);
                    let d_lambda = dot(gq, e.d);
                    let off = sub(s.pc, scale(e.d, e.lambda));
                    for j in 0..3 {
                        vg[base + slot::PC + j] += -gq[j] + d_lambda * s.n[j] / nd;
                        vg[base + slot::N + j] += d_lambda * off[j] / nd;
                    }
                } else {
                    let k2 = R::of(-2.0 * LOWPASS_INV_SQ) * d_rho;
                    let dmu = [k2 * e.delta[0], k2 * e.delta[1]];
                    let (fx, fy) = (R::of(cam.fx as f64), R::of(cam.fy as f64));
                    let z = s.pc[2];
                    vg[base + slot::PC] += dmu[0] * fx / z;
                    vg[base + slot::PC + 1] += dmu[1] * fy / z;
                    vg[base + slot::PC + 2] +=
                        -(dmu[0] * fx * s.pc[0] + dmu[1] * fy * s.pc[1]) / (z * z);
                }
            }
        }
    }
    (vg, exposure)
}
