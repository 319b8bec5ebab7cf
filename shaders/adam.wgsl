//! adam: one Adam step for every learnable surfel parameter, in place, from the packed
//! gradients (`13 + channels` per surfel: position 3, rotation 4, log-scales 2,
//! opacity, rgb 3, logits) with per-group learning rates; x and y stay fixed on the
//! grid. Moments m and v are interleaved per slot. Colours are clamped to [0, 1]
//! after the step. `exposure` steps one camera's (a, b) from the exposure gradient
//! that `rasterize_backward` leaves after the per-surfel view gradients.
//!
//! Oracle: src/optim/adam.rs.

struct AdamParams {
    count: u32,
    row: u32,
    stride: u32,
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
    pad0: u32,
    pad1: u32,
    pad2: u32,
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

/// Updates the moments at `mi` (m) and `mi + 1` (v) and returns the step to add.
fn adam_step(mi: u32, g: f32, lr: f32) -> f32 {
    let m = ap.beta1 * moments[mi] + (1.0 - ap.beta1) * g;
    let v = ap.beta2 * moments[mi + 1u] + (1.0 - ap.beta2) * g * g;
    moments[mi] = m;
    moments[mi + 1u] = v;
    return -lr * (m / ap.bias1) / (sqrt(v / ap.bias2) + ap.eps);
}

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * ap.row;
    if i >= ap.count {
        return;
    }
    let gs = ap.stride * i;
    let ms = 2u * gs;
    pos[3u * i + 2u] += adam_step(ms + 4u, grads[gs + 2u], ap.lr_z);
    for (var k = 0u; k < 4u; k++) {
        rotation[4u * i + k] += adam_step(ms + 2u * (3u + k), grads[gs + 3u + k], ap.lr_rotation);
    }
    for (var k = 0u; k < 2u; k++) {
        log_scale[2u * i + k] += adam_step(ms + 2u * (7u + k), grads[gs + 7u + k], ap.lr_scale);
    }
    opacity[i] += adam_step(ms + 18u, grads[gs + 9u], ap.lr_opacity);
    for (var k = 0u; k < 3u; k++) {
        let c = rgb[3u * i + k] + adam_step(ms + 2u * (10u + k), grads[gs + 10u + k], ap.lr_rgb);
        rgb[3u * i + k] = clamp(c, 0.0, 1.0);
    }
    let ch = ap.stride - 13u;
    for (var q = 0u; q < ch; q++) {
        logits[ch * i + q] += adam_step(ms + 2u * (13u + q), grads[gs + 13u + q], ap.lr_logits);
    }
}

@group(0) @binding(9) var<storage, read> view_grad: array<f32>;
@group(0) @binding(10) var<storage, read_write> exposure: array<f32>;

@compute @workgroup_size(1)
fn step_exposure() {
    // Exposure moments follow the surfels' in `moments`, 4 per camera.
    let mi = 2u * ap.stride * ap.count + 4u * ap.camera;
    for (var k = 0u; k < 2u; k++) {
        exposure[2u * ap.camera + k] += adam_step(mi + 2u * k, view_grad[ap.exposure_at + k], ap.lr_exposure);
    }
}
