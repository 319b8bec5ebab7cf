//! adam: one Adam step for every learnable surfel parameter, in place, with per-group
//! learning rates, and one step of the view's camera exposure (a, b).
//!
//! Gradients are read where `project_backward` left them, in place at the head of each
//! view candidate's view-gradient slot (`grad_stride` = 18 + channels apart):
//! position 3, rotation 4, log-scales 2, opacity, rgb 3, logits. A surfel finds its
//! slot through the membership words the host wrote after the z gradients in `zreg`
//! (per 32 surfels: a bit mask of candidates and the count before them,
//! src/render/candidates.rs); a surfel outside the view has a zero photometric
//! gradient. Every surfel takes a step, in view or not (the regularisers' z gradient,
//! `zreg`, and Adam's momentum move it), as dense Adam does. x and y stay fixed on the grid,
//! so they have no moments: the moments hold m and v for the L = 11 + channels
//! learnable slots (z, rotation 4, log-scales 2, opacity, rgb 3, logits), learnable
//! slot k being gradient slot k + 2. They are stored slot-major (m of slot k for
//! surfel i at 2k·count + i, v at (2k + 1)·count + i) so that neighbouring invocations
//! read neighbouring words: on a CPU rasteriser such as lavapipe, whose SIMD lanes are
//! neighbouring invocations, that is one vector load instead of a gather. The exposure
//! gradient follows the last surfel's slot, and the exposure moments (4 per camera)
//! follow the surfels'.
//!
//! All or nothing: when `project_backward` or `regularise` raised `status` (a gradient
//! that is not usable, guard.wgsl), neither entry point changes anything, so a NaN
//! never reaches the model and the host needs no copy of it to fall back to. Colours
//! are clamped to [0, 1] after the step.
//!
//! Oracle: src/optim/adam.rs.

struct AdamParams {
    count: u32,
    row: u32,
    grad_stride: u32,
    camera: u32,
    lr_z: f32,
    lr_rotation: f32,
    lr_scale: f32,
    lr_opacity: f32,
    lr_rgb: f32,
    lr_logits: f32,
    lr_exposure: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    bias1: f32,
    bias2: f32,
    exposure_at: u32,
    channels: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> ap: AdamParams;
@group(0) @binding(1) var<storage, read> grads: array<f32>;
@group(0) @binding(2) var<storage, read_write> moments: array<f32>;
@group(0) @binding(3) var<storage, read_write> pos: array<f32>;
@group(0) @binding(4) var<storage, read_write> rotation: array<f32>;
@group(0) @binding(5) var<storage, read_write> log_scale: array<f32>;
@group(0) @binding(6) var<storage, read_write> opacity: array<f32>;
@group(0) @binding(7) var<storage, read_write> rgb: array<f32>;
@group(0) @binding(8) var<storage, read_write> logits: array<f32>;
@group(0) @binding(9) var<storage, read_write> exposure: array<f32>;
// Non-zero when this step's update is refused.
@group(0) @binding(10) var<storage, read_write> status: array<u32>;
// z gradient of the regularisers per surfel (`count` floats), then the membership
// words (mask, candidates before) per 32 surfels, as f32 bits.
@group(0) @binding(11) var<storage, read> zreg: array<f32>;

var<private> seen: bool;
var<private> gs: u32;

/// Photometric gradient slot k + 2 of this surfel (0 when the view does not see it).
fn grad(k: u32) -> f32 {
    if seen {
        return grads[gs + k];
    }
    return 0.0;
}

/// The Adam update of `value` with gradient `g` and the moments at `mi` (m) and
/// `mi + step` (v), which it stores.
fn adam(mi: u32, step: u32, value: f32, g: f32, lr: f32) -> f32 {
    let m = ap.beta1 * moments[mi] + (1.0 - ap.beta1) * g;
    let v = ap.beta2 * moments[mi + step] + (1.0 - ap.beta2) * g * g;
    moments[mi] = m;
    moments[mi + step] = v;
    return value - lr * (m / ap.bias1) / (sqrt(v / ap.bias2) + ap.eps);
}

/// Surfel i's update: learnable slot k uses moments 2k·n + i and (2k + 1)·n + i, and
/// gradient slot k + 2.
fn update_surfel(i: u32) {
    let ch = ap.channels;
    let n = ap.count;
    // m of slot k at ms + 2k·n; its v one n further.
    let ms = i;
    let mask = bitcast<u32>(zreg[n + 2u * (i / 32u)]);
    let before = bitcast<u32>(zreg[n + 2u * (i / 32u) + 1u]);
    let bit = 1u << (i % 32u);
    seen = (mask & bit) != 0u;
    gs = ap.grad_stride * (before + countOneBits(mask & (bit - 1u))) + 2u;
    pos[3u * i + 2u] = adam(ms, n, pos[3u * i + 2u], zreg[i] + grad(0u), ap.lr_z);
    for (var k = 0u; k < 4u; k++) {
        rotation[4u * i + k] = adam(ms + 2u * (1u + k) * n, n, rotation[4u * i + k], grad(1u + k), ap.lr_rotation);
    }
    for (var k = 0u; k < 2u; k++) {
        log_scale[2u * i + k] = adam(ms + 2u * (5u + k) * n, n, log_scale[2u * i + k], grad(5u + k), ap.lr_scale);
    }
    opacity[i] = adam(ms + 14u * n, n, opacity[i], grad(7u), ap.lr_opacity);
    for (var k = 0u; k < 3u; k++) {
        let c = adam(ms + 2u * (8u + k) * n, n, rgb[3u * i + k], grad(8u + k), ap.lr_rgb);
        rgb[3u * i + k] = clamp(c, 0.0, 1.0);
    }
    for (var q = 0u; q < ch; q++) {
        logits[ch * i + q] = adam(ms + 2u * (11u + q) * n, n, logits[ch * i + q], grad(11u + q), ap.lr_logits);
    }
}

fn update_exposure() {
    let mi = 2u * (11u + ap.channels) * ap.count + 4u * ap.camera;
    for (var k = 0u; k < 2u; k++) {
        exposure[2u * ap.camera + k] = adam(mi + 2u * k, 1u, exposure[2u * ap.camera + k], grads[ap.exposure_at + k], ap.lr_exposure);
    }
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * ap.row;
    if i >= ap.count || status[0] != 0u {
        return;
    }
    update_surfel(i);
}

@compute @workgroup_size(1)
fn step_exposure() {
    if status[0] != 0u {
        return;
    }
    update_exposure();
}
