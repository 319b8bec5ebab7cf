//! Oracle of `shaders/loss.wgsl`: the masked L1 on RGB and the cross-entropy of the
//! composited logits, and their gradients with respect to the rendered outputs.

use super::targets::MASKED;
use super::LossConfig;
use crate::render::rasterize_backward::OutputGrads;
use crate::render::Image;

/// Loss sums (already weighted and divided by the mask count).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewLoss {
    pub rgb: f64,
    pub ce: f64,
}

/// `inv_n` is 1 / (pixels inside the mask), as the host computes it from the target.
pub fn photometric(
    img: &Image<f32>,
    target: &[u32],
    cfg: &LossConfig,
    inv_n: f32,
) -> (ViewLoss, OutputGrads<f32>) {
    let npx = (img.width * img.height) as usize;
    let ch = img.channels;
    let mut g = OutputGrads {
        rgb: vec![0.0; 3 * npx],
        logits: vec![0.0; ch * npx],
        depth: vec![0.0; npx],
        alpha: vec![0.0; npx],
    };
    let mut loss = ViewLoss::default();
    for (i, &t) in target.iter().enumerate().take(npx) {
        let cls = t >> 24;
        if cls == MASKED || img.alpha[i] < cfg.min_alpha {
            continue;
        }
        let k_rgb = cfg.rgb * inv_n / 3.0;
        for c in 0..3 {
            let tc = ((t >> (8 * c)) & 255) as f32 / 255.0;
            let d = img.rgb[3 * i + c] - tc;
            loss.rgb += (k_rgb * d.abs()) as f64;
            // WGSL's sign(0) is 0, like f32::signum only away from zero.
            g.rgb[3 * i + c] = if d == 0.0 { 0.0 } else { k_rgb * d.signum() };
        }
        let l = &img.logits[i * ch..(i + 1) * ch];
        let mx = l.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let z: f32 = l.iter().map(|&v| (v - mx).exp()).sum();
        let lse = mx + z.ln();
        let k_ce = cfg.ce * inv_n;
        loss.ce += (k_ce * (lse - l[cls as usize])) as f64;
        for (q, &lq) in l.iter().enumerate() {
            let p = (lq - lse).exp();
            let onehot = if q == cls as usize { 1.0 } else { 0.0 };
            g.logits[i * ch + q] = k_ce * (p - onehot);
        }
    }
    (loss, g)
}
