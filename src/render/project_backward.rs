//! Oracle of `shaders/project_backward.wgsl`: camera-space view gradients of each
//! surfel to gradients of its parameters (z, rotation quaternion, log-scales,
//! opacity logit, colour, logits).

use super::rasterize_backward::{slot, VIEW_GRAD};
use super::real::Real;
use super::{Params, ViewCamera};

/// Parameter gradients, same layout as `Params` (pos holds d/dx, d/dy, d/dz; only z
/// is optimised).
pub type Grads<R> = Params<R>;

fn wt<R: Real>(cam: &ViewCamera, v: [R; 3]) -> [R; 3] {
    let m = &cam.world_to_cam;
    [0, 1, 2].map(|j| {
        R::of(m[0][j] as f64) * v[0] + R::of(m[1][j] as f64) * v[1] + R::of(m[2][j] as f64) * v[2]
    })
}

pub fn backward<R: Real>(p: &Params<R>, cam: &ViewCamera, vg: &[R]) -> Grads<R> {
    let ch = p.channels;
    let stride = VIEW_GRAD + ch;
    let zero = R::of(0.0);
    let mut out = Grads {
        pos: vec![[zero; 3]; p.len()],
        rgb: vec![[zero; 3]; p.len()],
        log_scale: vec![[zero; 2]; p.len()],
        opacity: vec![zero; p.len()],
        rotation: vec![[zero; 4]; p.len()],
        logits: vec![zero; p.len() * ch],
        channels: ch,
    };
    for i in 0..p.len() {
        let g = &vg[stride * i..stride * (i + 1)];
        let v3 = |o: usize| [g[o], g[o + 1], g[o + 2]];
        out.pos[i] = wt(cam, v3(slot::PC));
        let su = p.log_scale[i][0].exp();
        let sv = p.log_scale[i][1].exp();
        out.log_scale[i] = [g[slot::SU] * su, g[slot::SV] * sv];
        out.opacity[i] = g[slot::OPACITY];
        out.rgb[i] = v3(slot::RGB);
        for j in 0..ch {
            out.logits[i * ch + j] = g[slot::LOGITS + j];
        }
        // Columns of R(q̂): tangent u, tangent v, normal.
        let (g0, g1, g2) = (
            wt(cam, v3(slot::TU)),
            wt(cam, v3(slot::TV)),
            wt(cam, v3(slot::N)),
        );
        let q = p.rotation[i];
        let norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        let (w, x, y, z) = (q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm);
        let two = R::of(2.0);
        let d3 = |a: [R; 3], b: [R; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let dq = [
            two * (d3(g0, [zero, z, -y]) + d3(g1, [-z, zero, x]) + d3(g2, [y, -x, zero])),
            two * (d3(g0, [zero, y, z]) + d3(g1, [y, -two * x, w]) + d3(g2, [z, -w, -two * x])),
            two * (d3(g0, [-two * y, x, -w]) + d3(g1, [x, zero, z]) + d3(g2, [w, z, -two * y])),
            two * (d3(g0, [-two * z, w, x]) + d3(g1, [-w, -two * z, y]) + d3(g2, [x, y, zero])),
        ];
        let qh = [w, x, y, z];
        let proj = (0..4).fold(zero, |a, k| a + qh[k] * dq[k]);
        out.rotation[i] = [0, 1, 2, 3].map(|k| (dq[k] - qh[k] * proj) / norm);
    }
    out
}
