//! loss (photometric and semantic): per pixel of a rendered view, the masked L1 on RGB
//! and the cross-entropy of the composited logits against the image's class, and
//! their gradients with respect to the forward outputs (`g_px`, `g_logits`), which
//! `rasterize_backward` consumes. One invocation per pixel, which writes its two loss
//! terms; `partial_sums` reduces them to a pair per 256 pixels, so the host reads a
//! few kilobytes, not an image. No workgroup memory and no barrier: where a CPU runs
//! workgroups (SwiftShader), a barrier alone made this kernel 16× slower than on
//! lavapipe.
//!
//! The target is packed per pixel as r | g << 8 | b << 16 | class << 24 (class = dense
//! channel index, 255 = outside the loss mask). Pixels the model leaves uncovered
//! (alpha below `min_alpha`: beyond the corridor or the culling box) are skipped: no
//! surfel there could learn from them.
//!
//! Two checks guard the step that follows (guard.wgsl, `adam` applies nothing when
//! `status[0]` is raised): a loss sum that is not `usable` raises 1 (in
//! `partial_sums`), and a view whose surfel–tile pairs overflowed the capacity the
//! host gave the forward pass (`total` beyond `capacity`: the image lacks pairs)
//! raises 2; the host then renders the view again with the exact count
//! (src/optim/train.rs). Checking here, on the GPU, lets the
//! whole step run without waiting for the count.
//!
//! The colour is taken before exposure (`px_out`'s colour slots 7–9) and exposed here
//! with the view's (a, b) and frame gain: the step may have measured the frame's gain
//! after the forward pass (frame_gain.wgsl, which writes `view.frame_a`), and the loss
//! and `rasterize_backward` then both see the view at it.
//!
//! Oracle: src/loss/photometric.rs.

// `LossParams` (the uniform block) is generated from src/optim/train.rs and prepended,
// after view.wgsl (`View`, `PIX_STRIDE`, `GRAD_STRIDE`).

@group(0) @binding(0) var<uniform> lp: LossParams;
@group(0) @binding(1) var<storage, read> px_out: array<f32>;
@group(0) @binding(2) var<storage, read> out_logits: array<f32>;
@group(0) @binding(3) var<storage, read> target_px: array<u32>;
@group(0) @binding(4) var<storage, read_write> g_px: array<f32>;
@group(0) @binding(5) var<storage, read_write> g_logits: array<f32>;
// The pixel's (L1, cross-entropy) terms, summed by `partial_sums`.
@group(0) @binding(6) var<storage, read_write> terms: array<vec2<f32>>;
@group(0) @binding(7) var<storage, read_write> status: array<u32>;
// The forward pass's pair count (scan.wgsl), before any clamping to the capacity.
@group(0) @binding(8) var<storage, read> total: array<u32>;
@group(0) @binding(9) var<uniform> view: View;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * lp.row;
    let ch = lp.channels;
    let gain = exp(view.exposure_a + view.frame_a);
    var l = vec2<f32>(0.0);
    if i < lp.width * lp.height {
        let o = PIX_STRIDE * i;
        let g = GRAD_STRIDE * i;
        for (var k = 0u; k < GRAD_STRIDE; k++) {
            g_px[g + k] = 0.0;
        }
        for (var q = 0u; q < ch; q++) {
            g_logits[i * ch + q] = 0.0;
        }
        let t = target_px[i];
        let cls = t >> 24u;
        if cls != 255u && px_out[o + 4u] >= lp.min_alpha {
            let tc = vec3<f32>(f32(t & 255u), f32((t >> 8u) & 255u), f32((t >> 16u) & 255u)) / 255.0;
            let raw = vec3<f32>(px_out[o + 7u], px_out[o + 8u], px_out[o + 9u]);
            let d = gain * raw + view.exposure_b - tc;
            // Robust weighting (drives without labels, where cars and people are in
            // the mask): a Cauchy weight 1 / (1 + (r/c)²) of the pixel's mean
            // residual r, held constant in the gradient (one IRLS step per step).
            var wr = 1.0;
            if lp.robust_c > 0.0 {
                let r = (abs(d.x) + abs(d.y) + abs(d.z)) / 3.0 / lp.robust_c;
                wr = 1.0 / (1.0 + r * r);
            }
            let k_rgb = lp.w_rgb * lp.inv_n / 3.0 * wr;
            l.x = k_rgb * (abs(d.x) + abs(d.y) + abs(d.z));
            let s = sign(d) * k_rgb;
            g_px[g] = s.x;
            g_px[g + 1u] = s.y;
            g_px[g + 2u] = s.z;
            // Softmax with the maximum subtracted, so large logits cannot overflow.
            var mx = out_logits[i * ch];
            for (var q = 1u; q < ch; q++) {
                mx = max(mx, out_logits[i * ch + q]);
            }
            var z = 0.0;
            for (var q = 0u; q < ch; q++) {
                z += exp(out_logits[i * ch + q] - mx);
            }
            let lse = mx + log(z);
            let k_ce = lp.w_ce * lp.inv_n;
            l.y = k_ce * (lse - out_logits[i * ch + cls]);
            for (var q = 0u; q < ch; q++) {
                let p = exp(out_logits[i * ch + q] - lse);
                g_logits[i * ch + q] = k_ce * (p - select(0.0, 1.0, q == cls));
            }
        }
    }
    if i < lp.width * lp.height {
        terms[i] = l;
    }
    if i == 0u && total[0] > lp.capacity {
        status[0] = 2u;
    }
}
