//! frame_gain: a view's own log gain, measured from its step's own forward pass the
//! first time the view is stepped (auto-exposure changes a real camera's brightness
//! from frame to frame, which one exposure per camera would bake into the map's
//! colours). g = ln(Σ target / Σ render) over the loss mask's pixels that the model
//! covers (alpha ≥ `min_alpha`: 0.95 or the loss's, the larger, src/optim/gain.rs),
//! rendered with the camera's exposure and a frame gain of 0, clamped to
//! ±`max_log_gain`; 0 with fewer than `min_pixels` pixels or a dark render, which say
//! nothing about the frame's exposure. A ratio of sums, not a
//! least-squares fit: a fit of the target on a blurred render shrinks the gain toward
//! the mean. A mean needs no detail, so only every `stride`-th pixel of every
//! `stride`-th row counts (at least `GAIN_PIXELS` of them, src/optim/gain.rs).
//!
//! The host copies `gain[0]` into the view uniform's `frame_a` before `loss` and
//! `rasterize_backward` run, so the same step trains the view at its gain, and reads
//! the four words back with the step's sums: no second forward pass and no read-back
//! in the middle of the step (both cost 3.5 s of the page's 78-view demo when the
//! gain was measured apart). One invocation sums every sampled pixel (16–66 k, well
//! under a millisecond on lavapipe and SwiftShader): no workgroup memory and no
//! barrier, which SwiftShader runs as coroutines (partial_sums.wgsl says why).
//!
//! Oracle: `frame_gain_cpu` in src/optim/gain.rs.

// `GainParams` (the uniform block) is generated from src/optim/gain.rs and prepended,
// after view.wgsl's constants (`PIX_STRIDE`).

@group(0) @binding(0) var<uniform> gp: GainParams;
@group(0) @binding(1) var<storage, read> px_out: array<f32>;
@group(0) @binding(2) var<storage, read> target_px: array<u32>;
// g, the pixels counted, Σ target, Σ render (the last three for the read-back).
@group(0) @binding(3) var<storage, read_write> gain: array<f32>;

@compute @workgroup_size(1)
fn main() {
    let s = max(gp.stride, 1u);
    // Sums in f32: at most 66 k pixels of three channels in [0, 1], a relative error
    // near 1e-5.
    var st = 0.0;
    var sr = 0.0;
    var n = 0u;
    for (var ky = 0u; ky < gp.height / s; ky++) {
        let y = ky * s + s / 2u;
        for (var kx = 0u; kx < gp.width / s; kx++) {
            let i = y * gp.width + kx * s + s / 2u;
            let t = target_px[i];
            let o = PIX_STRIDE * i;
            if (t >> 24u) == 255u || px_out[o + 4u] < gp.min_alpha {
                continue;
            }
            st += f32((t & 255u) + ((t >> 8u) & 255u) + ((t >> 16u) & 255u));
            sr += px_out[o] + px_out[o + 1u] + px_out[o + 2u];
            n += 1u;
        }
    }
    let sum_t = st / 255.0;
    var g = 0.0;
    if n >= gp.min_pixels && sr > 1e-3 * f32(n) {
        g = clamp(log(sum_t / sr), -gp.max_log_gain, gp.max_log_gain);
    }
    gain[0] = g;
    gain[1] = f32(n);
    gain[2] = sum_t;
    gain[3] = sr;
}
