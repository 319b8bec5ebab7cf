//! adam: one Adam step for every learnable surfel parameter, in place, with per-group
//! learning rates, and one step of the view's camera exposure (a, b).
//!
//! Gradients are read where `project_backward` left them, in place at the head of each
//! surfel's view-gradient slot (`grad_stride` = 18 + channels apart): position 3,
//! rotation 4, log-scales 2, opacity, rgb 3, logits. x and y stay fixed on the grid,
//! so they have no moments: the moments hold m and v interleaved for the 11 + channels
//! learnable slots (z, rotation 4, log-scales 2, opacity, rgb 3, logits), learnable
//! slot k being gradient slot k + 2. The exposure gradient follows the last surfel's
//! slot, and the exposure moments (4 per camera) follow the surfels'.
//!
//! All or nothing: `check` computes every update without writing and raises `status`
//! if any new value or second moment is not finite; `main` and `step_exposure` then
//! do nothing. A NaN from a gradient or a learning rate therefore never reaches the
//! model, and the host needs no copy of the parameters to fall back to. The finiteness
//! test is on the bit pattern because WGSL lets compilers assume that NaN and Inf do
//! not occur in float comparisons. Colours are clamped to [0, 1] after the step.
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
@group(0) @binding(10) var<storage, read_write> status: atomic<u32>;

var<private> ok: bool;

fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

/// The Adam update of `value` with gradient `g` and the moments at `mi` (m) and
/// `mi + 1` (v); stores the moments when `apply`, and clears `ok` when not finite.
fn adam(mi: u32, value: f32, g: f32, lr: f32, apply: bool) -> f32 {
    let m = ap.beta1 * moments[mi] + (1.0 - ap.beta1) * g;
    let v = ap.beta2 * moments[mi + 1u] + (1.0 - ap.beta2) * g * g;
    let next = value - lr * (m / ap.bias1) / (sqrt(v / ap.bias2) + ap.eps);
    ok = ok && finite(m) && finite(v) && finite(next);
    if apply {
        moments[mi] = m;
        moments[mi + 1u] = v;
    }
    return next;
}

/// Surfel i's update: learnable slot k uses moments 2 (L i + k) and gradient slot
/// k + 2, with L = 11 + channels.
fn update_surfel(i: u32, apply: bool) {
    let ch = ap.channels;
    let ms = 2u * (11u + ch) * i;
    let gs = ap.grad_stride * i + 2u;
    let z = adam(ms, pos[3u * i + 2u], grads[gs], ap.lr_z, apply);
    if apply {
        pos[3u * i + 2u] = z;
    }
    for (var k = 0u; k < 4u; k++) {
        let r = adam(ms + 2u * (1u + k), rotation[4u * i + k], grads[gs + 1u + k], ap.lr_rotation, apply);
        if apply {
            rotation[4u * i + k] = r;
        }
    }
    for (var k = 0u; k < 2u; k++) {
        let s = adam(ms + 2u * (5u + k), log_scale[2u * i + k], grads[gs + 5u + k], ap.lr_scale, apply);
        if apply {
            log_scale[2u * i + k] = s;
        }
    }
    let o = adam(ms + 14u, opacity[i], grads[gs + 7u], ap.lr_opacity, apply);
    if apply {
        opacity[i] = o;
    }
    for (var k = 0u; k < 3u; k++) {
        let c = adam(ms + 2u * (8u + k), rgb[3u * i + k], grads[gs + 8u + k], ap.lr_rgb, apply);
        if apply {
            rgb[3u * i + k] = clamp(c, 0.0, 1.0);
        }
    }
    for (var q = 0u; q < ch; q++) {
        let l = adam(ms + 2u * (11u + q), logits[ch * i + q], grads[gs + 11u + q], ap.lr_logits, apply);
        if apply {
            logits[ch * i + q] = l;
        }
    }
}

fn update_exposure(apply: bool) {
    let mi = 2u * (11u + ap.channels) * ap.count + 4u * ap.camera;
    for (var k = 0u; k < 2u; k++) {
        let e = adam(mi + 2u * k, exposure[2u * ap.camera + k], grads[ap.exposure_at + k], ap.lr_exposure, apply);
        if apply {
            exposure[2u * ap.camera + k] = e;
        }
    }
}

@compute @workgroup_size(256)
fn check(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * ap.row;
    if i >= ap.count {
        return;
    }
    ok = true;
    update_surfel(i, false);
    if i == 0u {
        update_exposure(false);
    }
    if !ok {
        atomicOr(&status, 1u);
    }
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * ap.row;
    if i >= ap.count || atomicLoad(&status) != 0u {
        return;
    }
    update_surfel(i, true);
}

@compute @workgroup_size(1)
fn step_exposure() {
    if atomicLoad(&status) != 0u {
        return;
    }
    update_exposure(true);
}
