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
//! `zreg`, and Adam's momentum move it), as dense Adam does.
//!
//! Moments: x and y stay fixed on the grid, so they have none; m and v are held for
//! the L = 11 + channels learnable slots (z, rotation 4, log-scales 2, opacity, rgb 3,
//! logits), learnable slot k being gradient slot k + 2. They are stored in blocks of
//! BLOCK = 256 surfels (one workgroup; the host prepends the constant), slot-major
//! within a block: m of slot k for surfel i at ((i / B)·2L + 2k)·B + i % B, v B words
//! later. Neighbouring invocations so
//! read neighbouring words: on a CPU rasteriser such as lavapipe, whose SIMD lanes are
//! neighbouring invocations, that is one vector load instead of a gather.
//! A block holds all of its surfels' moments, so the moments can exceed one storage
//! binding (lavapipe binds 128 MiB; a 5 cm `nuscenes-like` model needs 285 MB) at
//! little cost: the host dispatches `main` once per window of whole blocks, binding
//! only that window's moments, and every surfel is visited once (four passes: 74 ms
//! per step against 67 for one, `nuscenes-like` at 10 cm). Windows of slots, the
//! layout before, visited every surfel once per window: three took 1.8–1.9× one pass.
//! Browsers bind 1 GiB, one window.
//!
//! The exposure (a, b) per camera is followed in its buffer by its moments (m_a, v_a,
//! m_b, v_b per camera); its gradient follows the last candidate's slot.
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
    cameras: u32,
    // The first surfel of this pass (a multiple of BLOCK: its window starts a block).
    first: u32,
    // L, the learnable slots per surfel.
    learnable: u32,
    // One past the last surfel of this pass.
    end: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> ap: AdamParams;
@group(0) @binding(1) var<storage, read> grads: array<f32>;
// The moments of this pass's blocks (from surfel `first`).
@group(0) @binding(2) var<storage, read_write> moments: array<f32>;
@group(0) @binding(3) var<storage, read_write> pos: array<f32>;
@group(0) @binding(4) var<storage, read_write> rotation: array<f32>;
@group(0) @binding(5) var<storage, read_write> log_scale: array<f32>;
@group(0) @binding(6) var<storage, read_write> opacity: array<f32>;
@group(0) @binding(7) var<storage, read_write> rgb: array<f32>;
// The logits of this pass's surfels (from surfel `first`, like the moments): the
// model's largest per-surfel buffer need not fit one binding.
@group(0) @binding(8) var<storage, read_write> logits: array<f32>;
// (a, b) per camera, then (m_a, v_a, m_b, v_b) per camera.
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

/// One Adam step: (new value, m, v) from the value, its gradient and old moments.
fn adam(value: f32, g: f32, m0: f32, v0: f32, lr: f32) -> vec3<f32> {
    let m = ap.beta1 * m0 + (1.0 - ap.beta1) * g;
    let v = ap.beta2 * v0 + (1.0 - ap.beta2) * g * g;
    return vec3<f32>(value - lr * (m / ap.bias1) / (sqrt(v / ap.bias2) + ap.eps), m, v);
}

/// Learnable slot k of surfel i: its new value from `value`, storing the moments.
fn step_slot(i: u32, k: u32, value: f32, g: f32, lr: f32) -> f32 {
    let mi = (((i - ap.first) / BLOCK) * 2u * ap.learnable + 2u * k) * BLOCK + i % BLOCK;
    let r = adam(value, g, moments[mi], moments[mi + BLOCK], lr);
    moments[mi] = r.y;
    moments[mi + BLOCK] = r.z;
    return r.x;
}

/// Surfel i's update of every learnable slot. Written out group by group rather than
/// as one loop over slots with a branch per group: on lavapipe the loop took three
/// times as long (270 vs 85 ms per step on `nuscenes-like` at 10 cm).
fn update_surfel(i: u32) {
    let ch = ap.channels;
    let n = ap.count;
    let mask = bitcast<u32>(zreg[n + 2u * (i / 32u)]);
    let before = bitcast<u32>(zreg[n + 2u * (i / 32u) + 1u]);
    let bit = 1u << (i % 32u);
    seen = (mask & bit) != 0u;
    gs = ap.grad_stride * (before + countOneBits(mask & (bit - 1u))) + 2u;
    pos[3u * i + 2u] = step_slot(i, 0u, pos[3u * i + 2u], zreg[i] + grad(0u), ap.lr_z);
    for (var k = 0u; k < 4u; k++) {
        rotation[4u * i + k] = step_slot(i, 1u + k, rotation[4u * i + k], grad(1u + k), ap.lr_rotation);
    }
    for (var k = 0u; k < 2u; k++) {
        log_scale[2u * i + k] = step_slot(i, 5u + k, log_scale[2u * i + k], grad(5u + k), ap.lr_scale);
    }
    opacity[i] = step_slot(i, 7u, opacity[i], grad(7u), ap.lr_opacity);
    for (var k = 0u; k < 3u; k++) {
        rgb[3u * i + k] = clamp(step_slot(i, 8u + k, rgb[3u * i + k], grad(8u + k), ap.lr_rgb), 0.0, 1.0);
    }
    let li = ch * (i - ap.first);
    for (var q = 0u; q < ch; q++) {
        logits[li + q] = step_slot(i, 11u + q, logits[li + q], grad(11u + q), ap.lr_logits);
    }
}

fn update_exposure() {
    let c = ap.camera;
    for (var k = 0u; k < 2u; k++) {
        let mi = 2u * ap.cameras + 4u * c + 2u * k;
        let r = adam(exposure[2u * c + k], grads[ap.exposure_at + k], exposure[mi], exposure[mi + 1u], ap.lr_exposure);
        exposure[2u * c + k] = r.x;
        exposure[mi] = r.y;
        exposure[mi + 1u] = r.z;
    }
}

@compute @workgroup_size(BLOCK)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = ap.first + gid.x + gid.y * ap.row;
    if i >= ap.end || status[0] != 0u {
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
