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
        let d: [f32; 3] =
            std::array::from_fn(|c| img.rgb[3 * i + c] - ((t >> (8 * c)) & 255) as f32 / 255.0);
        let mut wr = 1.0;
        if cfg.robust_c > 0.0 {
            let r = (d[0].abs() + d[1].abs() + d[2].abs()) / 3.0 / cfg.robust_c;
            wr = 1.0 / (1.0 + r * r);
        }
        let k_rgb = cfg.rgb * inv_n / 3.0 * wr;
        for c in 0..3 {
            let d = d[c];
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Two pixels against a grey target: one off by 0.1 in every channel, one by 0.4
    /// (a car on the road). With c = 0.1 their weights are 1/2 and 1/17.
    #[test]
    fn robust_weight_follows_the_cauchy_curve() {
        let grey = 128u32 | 128 << 8 | 128 << 16;
        let t = 128.0 / 255.0;
        let img = Image {
            width: 2,
            height: 1,
            rgb: vec![t + 0.1, t + 0.1, t + 0.1, t + 0.4, t + 0.4, t + 0.4],
            logits: vec![0.0; 2],
            depth: vec![0.0; 2],
            alpha: vec![1.0; 2],
            channels: 1,
        };
        let target = [grey, grey];
        let plain = photometric(&img, &target, &LossConfig::default(), 0.5).1;
        let cfg = LossConfig {
            robust_c: 0.1,
            ..LossConfig::default()
        };
        let robust = photometric(&img, &target, &cfg, 0.5).1;
        let near = robust.rgb[0] / plain.rgb[0];
        let far = robust.rgb[3] / plain.rgb[3];
        assert!((near - 0.5).abs() < 1e-3, "{near}");
        assert!((far - 1.0 / 17.0).abs() < 1e-3, "{far}");
    }
}
