//! adam: one Adam step of the learnable surfel parameters, in place, with per-group
//! learning rates, and one step of the view's camera exposure (a, b).
//!
//! Selective (`ap.selective` 1, `--adam selective`): only the view's candidates take a step,
//! as gsplat's SelectiveAdam and Taming 3DGS do, so a step's cost follows the view
//! (5 % of a 5 cm `nuscenes-like` model), not the model. Invocation j takes candidate
//! slot j: `regularise` left (z gradient, surfel) at `zreg[2j]`, and the photometric
//! gradients are at slot j. A surfel that missed k steps since its last first catches
//! up what k steps of zero gradient would have done under dense Adam: its moments
//! decay by β1ᵏ and β2ᵏ, and it moves by its momentum, Σⱼ₌₁..ₖ rʲ (r = β1/√β2) times
//! its last normalised moment at this step's rate. Without that move, a surfel seen by
//! a few views of a one-epoch run lost the ~1/(1 − β1) = 10 steps its momentum carries
//! it under dense Adam (`demo` at 10 cm: −0.4 dB, −0.03 mIoU). The step it was last
//! stepped at and the z the host last knew (`sync_known` copies it) sit in its block
//! after its moments; a stepped surfel
//! whose z leaves `Z_MARGIN` of the host's raises `status[1]`, and the host reads the
//! positions back before the next view (src/render/candidates.rs: only stepped
//! surfels move, so this is the whole check).
//!
//! Dense (0, the default): every surfel takes a step.
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
//! BLOCK = 256 surfels (one workgroup; the host prepends the constants), slot-major
//! within a block of W = 2L + 2 words per surfel: m of slot k for surfel i at
//! ((i / B)·W + 2k)·B + i % B, v B words later, then the step it was last stepped at
//! (a float) and the z the host knows. Neighbouring invocations so
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

// `AdamParams` (the uniform block) is generated from src/optim/train.rs and prepended.

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
// Dense: z gradient of the regularisers per surfel (`count` f32 bits), then the
// membership words (mask, candidates before) per 32 surfels. Selective: (z gradient,
// surfel) per candidate slot (regularise.wgsl).
@group(0) @binding(11) var<storage, read> zreg: array<u32>;

var<private> seen: bool;
var<private> gs: u32;
// Selective: what the steps this surfel missed would have done (src/optim/adam.rs,
// `Missed`): its moments decay by these, and it moves by `drift` normalised moments.
var<private> decay1: f32;
var<private> decay2: f32;
var<private> drift: f32;

/// Words per surfel in a block: m, v per learnable slot, the last step, the known z.
fn words() -> u32 {
    return 2u * ap.learnable + 2u;
}

/// Index in `moments` of word k (of `words()`) of surfel i.
fn word(i: u32, k: u32) -> u32 {
    return (((i - ap.first) / BLOCK) * words() + k) * BLOCK + i % BLOCK;
}

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
    let mi = word(i, 2u * k);
    let m0 = moments[mi];
    let v0 = moments[mi + BLOCK];
    let caught = value - lr * drift * (m0 / ap.bias1) / (sqrt(v0 / ap.bias2) + ap.eps);
    let r = adam(caught, g, decay1 * m0, decay2 * v0, lr);
    moments[mi] = r.y;
    moments[mi + BLOCK] = r.z;
    return r.x;
}

/// Surfel i's z, with `zr` its regularisers' z gradient.
fn update_z(i: u32, zr: f32) {
    pos[3u * i + 2u] = step_slot(i, 0u, pos[3u * i + 2u], zr + grad(0u), ap.lr_z);
}

/// Sets what surfel i catches up (`decay1`, `decay2`, `drift`) for the steps it
/// missed since its last, and marks it stepped at this one.
fn catch_up(i: u32) {
    let lw = word(i, 2u * ap.learnable);
    // Held as a float: exact for the first 2²⁴ steps.
    let last = u32(moments[lw]);
    let missed = f32(ap.step - 1u - min(last, ap.step - 1u));
    let r = ap.beta1 / sqrt(ap.beta2);
    decay1 = pow(ap.beta1, missed);
    decay2 = pow(ap.beta2, missed);
    drift = r * (1.0 - pow(r, missed)) / (1.0 - r);
    if missed == 0.0 {
        no_catch_up();
    }
    moments[lw] = f32(ap.step);
}

fn no_catch_up() {
    decay1 = 1.0;
    decay2 = 1.0;
    drift = 0.0;
}

/// Surfel i's update of every learnable slot but z. Written out group by group rather
/// than as one loop over slots with a branch per group: on lavapipe the loop took
/// three times as long (270 vs 85 ms per step on `nuscenes-like` at 10 cm).
fn update_rest(i: u32) {
    let ch = ap.channels;
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

/// Dense: surfel `first + gid`, every surfel of the window; its slot, if the view has
/// it, from the membership words.
fn dense(g: u32) {
    let i = ap.first + g;
    if i >= ap.end {
        return;
    }
    let n = ap.count;
    let mask = zreg[n + 2u * (i / 32u)];
    let before = zreg[n + 2u * (i / 32u) + 1u];
    let bit = 1u << (i % 32u);
    seen = (mask & bit) != 0u;
    gs = ap.grad_stride * (before + countOneBits(mask & (bit - 1u))) + 2u;
    no_catch_up();
    update_z(i, bitcast<f32>(zreg[i]));
    update_rest(i);
}

/// Selective: candidate slot `cand_first + gid` of the window, after the decay of the
/// steps its surfel missed; raises `status[1]` when its z leaves the host's margin.
fn selective(g: u32) {
    let j = ap.cand_first + g;
    if j >= ap.cand_end {
        return;
    }
    let i = zreg[2u * j + 1u];
    seen = true;
    gs = ap.grad_stride * j + 2u;
    catch_up(i);
    update_z(i, bitcast<f32>(zreg[2u * j]));
    update_rest(i);
    if abs(pos[3u * i + 2u] - moments[word(i, 2u * ap.learnable + 1u)]) > Z_MARGIN {
        status[1] = 1u;
    }
}

@compute @workgroup_size(BLOCK)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if status[0] != 0u {
        return;
    }
    let g = gid.x + gid.y * ap.row;
    if ap.selective == 1u {
        selective(g);
    } else {
        dense(g);
    }
}

/// The z the host knows of every surfel of the window (it has just read them back or
/// uploaded them) into its block, for `selective`'s margin check.
@compute @workgroup_size(BLOCK)
fn sync_known(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = ap.first + gid.x + gid.y * ap.row;
    if i < ap.end {
        moments[word(i, 2u * ap.learnable + 1u)] = pos[3u * i + 2u];
    }
}

@compute @workgroup_size(1)
fn step_exposure() {
    if status[0] != 0u {
        return;
    }
    update_exposure();
}
