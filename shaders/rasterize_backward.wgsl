//! rasterize_backward: the forward kernel's pairs traversed back to front. One
//! workgroup per 8×8 tile; each invocation owns four pixels of a column (rows 4j to
//! 4j + 3), walks its tile's list back from the latest of their `last` contributors
//! (so surfels behind every termination are never read), recovers each pixel's
//! transmittance by division (alpha ≤ 0.99 keeps it stable), and adds the four
//! pixels' summed share of each camera-space gradient with `lanes_add`: summed over
//! the subgroup first where the adapter has subgroups (lanes_subgroup.wgsl, the lanes
//! walking in step), then `accum_add` (native f32 atomics, or CAS in browsers;
//! `accum` is bound at 0 by the prepended snippet).
//!
//! Why four pixels per invocation: the adds are what this pass costs where there are
//! no float atomics (a compare-and-swap loop per value, 18 + channels values per
//! surfel) and, with subgroups, the reductions; neighbouring pixels share most
//! surfels, so summing four in registers divides both by up to four, and the surfel's
//! projected parameters, colour and logits are loaded once for four pixels. Their
//! state is held as vec4 lanes (lane j = row 4j' + j: transmittance, the colour,
//! depth and logit accumulators, the flags), the surfel is evaluated for the four at
//! once (`eval4`) and their shares are summed across the lanes (`shares`): neither an
//! array nor a struct per pixel, both of which SwiftShader keeps in memory (with a
//! struct per pixel this pass took 1.6 times as long in Chromium; docs/PERFORMANCE.md).
//! Pixels read the list
//! straight from storage: on lavapipe, staging batches in workgroup memory behind
//! barriers was no faster. The kernel has no barrier at all: each invocation reads
//! its tile's range itself and adds its four pixels' exposure gradient itself, since
//! where a CPU runs workgroups (SwiftShader) a barrier makes every invocation group
//! a coroutine (a workgroup reduction of the exposure gradient and a uniform load of
//! the range made this pass 1.25× as long in Chromium; docs/PERFORMANCE.md). The logits need no per-pixel accumulators: their share of
//! dL/dalpha is Σ_q (l_q − acc_q)·dl_q, and since dl is fixed per pixel the
//! accumulated Σ_q acc_q·dl_q follows the same recurrence as acc_q, so two scalars
//! carry it (the oracle keeps one accumulator per channel, which is the same sum).
//! The four pixels' logit gradients dl are read once, before the walk, into
//! registers, one vec4 per channel (`CH`, the model's channel count, is fixed when
//! the pipeline is built): reading them per surfel, scattered, cost a fifth of this
//! kernel on lavapipe.
//!
//! Oracle: src/render/rasterize_backward.rs; slot layout `slot::*` there.

@group(0) @binding(1) var<uniform> view: View;
@group(0) @binding(2) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> order: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<u32>;
// Per candidate slot: colour 3, then the logits (the view's copy, `gather.wgsl`).
@group(0) @binding(5) var<storage, read> attrs: array<f32>;
// Forward outputs (PIX_STRIDE per pixel) and loss gradients (GRAD_STRIDE per pixel:
// rgb 3, depth, alpha), packed to stay within 10 storage buffers per stage.
@group(0) @binding(7) var<storage, read> px_out: array<f32>;
@group(0) @binding(8) var<storage, read> g_px: array<f32>;
@group(0) @binding(9) var<storage, read> g_logits: array<f32>;

const S_PC: u32 = 0u;
const S_TU: u32 = 3u;
const S_TV: u32 = 6u;
const S_N: u32 = 9u;
const S_SU: u32 = 12u;
const S_SV: u32 = 13u;
const S_OPACITY: u32 = 14u;
const S_RGB: u32 = 15u;
const S_LOGITS: u32 = 18u;


/// A pixel's loss gradients and forward outputs, as the walk starts.
struct PixelIn {
    dc: vec3<f32>,
    dd: f32,
    da_out: f32,
    t_fin: f32,
    // Its last contributor + 1 (0: outside the view or the loss mask, uses nothing).
    last: u32,
    // Its share of the exposure gradient.
    dexp: vec2<f32>,
}

/// A surfel's camera-space gradients summed over the four pixels.
struct Share {
    op: f32,
    su: f32,
    sv: f32,
    tu: vec3<f32>,
    tv: vec3<f32>,
    n: vec3<f32>,
    pc: vec3<f32>,
}

fn add3(base: u32, v: vec3<f32>) {
    lanes_add(base, v.x);
    lanes_add(base + 1u, v.y);
    lanes_add(base + 2u, v.z);
}

fn sum4(v: vec4<f32>) -> f32 {
    return (v.x + v.y) + (v.z + v.w);
}

fn load_pixel(x: u32, y: u32, gain: f32) -> PixelIn {
    var p = PixelIn();
    p.t_fin = 1.0;
    if x < view.width && y < view.height {
        let pix = y * view.width + x;
        let gp = GRAD_STRIDE * pix;
        let po = PIX_STRIDE * pix;
        let go = vec3<f32>(g_px[gp], g_px[gp + 1u], g_px[gp + 2u]);
        p.dc = gain * go;
        let col = vec3<f32>(px_out[po + 7u], px_out[po + 8u], px_out[po + 9u]);
        p.dexp = vec2<f32>(dot(go * gain, col), go.x + go.y + go.z);
        p.dd = g_px[gp + 3u];
        p.da_out = g_px[gp + 4u];
        p.t_fin = px_out[po + 5u];
        p.last = bitcast<u32>(px_out[po + 6u]);
    }
    return p;
}

/// Reads pixel j's logit gradients into lane j of `dl`.
fn load_dl(x: u32, y: u32, dl: ptr<function, array<vec4<f32>, CH_ARRAY>>, j: u32) {
    if x >= view.width || y >= view.height {
        return;
    }
    let pix = y * view.width + x;
    for (var q = 0u; q < CH; q++) {
        (*dl)[q][j] = g_logits[pix * CH + q];
    }
}

/// The surfel's geometric gradients from the pixels of mask `m` (lanes used and below
/// the alpha clamp), given each pixel's dL/dalpha `da`; summed over the four.
fn shares(s: Surfel, e: Eval4, m: vec4<bool>, da: vec4<f32>) -> Share {
    var g = Share();
    let zero = vec4<f32>(0.0);
    let sig = s.opacity;
    g.op = sum4(select(zero, da * e.g * sig * (1.0 - sig), m));
    let d_rho = da * sig * -0.5 * e.g;
    // Where the ray hits the plane: through u, v and the hit point.
    let mh = m & e.ray_hit;
    let gu = select(zero, d_rho * 2.0 * e.u, mh);
    let gv = select(zero, d_rho * 2.0 * e.v, mh);
    g.su = sum4(-gu * e.u) / s.su;
    g.sv = sum4(-gv * e.v) / s.sv;
    g.tu = vec3<f32>(sum4(gu * e.qx), sum4(gu * e.qy), sum4(gu * e.qz)) / s.su;
    g.tv = vec3<f32>(sum4(gv * e.qx), sum4(gv * e.qy), sum4(gv * e.qz)) / s.sv;
    let gqx = gu * s.tu.x / s.su + gv * s.tv.x / s.sv;
    let gqy = gu * s.tu.y / s.su + gv * s.tv.y / s.sv;
    let gqz = gu * s.tu.z / s.su + gv * s.tv.z / s.sv;
    let nd = select(vec4<f32>(1.0), s.n.x * e.dx + s.n.y * e.dy + s.n.z, mh);
    let d_lambda = gqx * e.dx + gqy * e.dy + gqz;
    let dln = d_lambda / nd;
    g.pc = vec3<f32>(sum4(-gqx + dln * s.n.x), sum4(-gqy + dln * s.n.y), sum4(-gqz + dln * s.n.z));
    g.n = vec3<f32>(sum4(dln * (s.pc.x - e.dx * e.lambda)), sum4(dln * (s.pc.y - e.dy * e.lambda)), sum4(dln * (s.pc.z - e.lambda)));
    // Elsewhere the screen-space low-pass: through the projected centre.
    let ml = m & !e.ray_hit;
    let k2 = select(zero, -2.0 * LOWPASS_INV_SQ * d_rho, ml);
    let dmx = sum4(k2 * e.ddx);
    let dmy = sum4(k2 * e.ddy);
    let z = s.pc.z;
    g.pc += vec3<f32>(dmx * view.fx / z, dmy * view.fy / z, -(dmx * view.fx * s.pc.x + dmy * view.fy * s.pc.y) / (z * z));
    return g;
}

@compute @workgroup_size(8, 2)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wg.x + wg.y * view.tiles_x;
    let x = wg.x * TILE + lid.x;
    let y = wg.y * TILE + 4u * lid.y;
    let stride = S_LOGITS + CH;
    let r = vec2<u32>(ranges[2u * tile], ranges[2u * tile + 1u]);
    let gain = exp(view.exposure_a + view.frame_a);
    let pa = load_pixel(x, y, gain);
    let pb = load_pixel(x, y + 1u, gain);
    let pc = load_pixel(x, y + 2u, gain);
    let pd = load_pixel(x, y + 3u, gain);
    let dexp = pa.dexp + pb.dexp + pc.dexp + pd.dexp;
    // The four pixels' inputs and state as vec4 lanes (lane j = row y + j), not a
    // struct per pixel, which SwiftShader keeps out of registers (docs/PERFORMANCE.md).
    let dcr = vec4<f32>(pa.dc.x, pb.dc.x, pc.dc.x, pd.dc.x);
    let dcg = vec4<f32>(pa.dc.y, pb.dc.y, pc.dc.y, pd.dc.y);
    let dcb = vec4<f32>(pa.dc.z, pb.dc.z, pc.dc.z, pd.dc.z);
    let dd = vec4<f32>(pa.dd, pb.dd, pc.dd, pd.dd);
    let da_out = vec4<f32>(pa.da_out, pb.da_out, pc.da_out, pd.da_out);
    let t_fin = vec4<f32>(pa.t_fin, pb.t_fin, pc.t_fin, pd.t_fin);
    let last = vec4<u32>(pa.last, pb.last, pc.last, pd.last);
    var t = t_fin;
    let zero = vec4<f32>(0.0);
    var acc_r = zero;
    var acc_g = zero;
    var acc_b = zero;
    var last_r = zero;
    var last_g = zero;
    var last_b = zero;
    var last_alpha = zero;
    var acc_d = zero;
    var last_d = zero;
    // Σ_q dl_q·acc_q and Σ_q dl_q·l_q of the previous surfel.
    var acc_l = zero;
    var last_l = zero;
    var dl: array<vec4<f32>, CH_ARRAY>;
    load_dl(x, y, &dl, 0u);
    load_dl(x, y + 1u, &dl, 1u);
    load_dl(x, y + 2u, &dl, 2u);
    load_dl(x, y + 3u, &dl, 3u);
    let px = f32(x) + 0.5;
    let ys = vec4<f32>(f32(y) + 0.5, f32(y) + 1.5, f32(y) + 2.5, f32(y) + 3.5);
    lanes_init(li);
    // The walk starts at the highest bound among the lanes so that they stay in step
    // (lanes_*.wgsl); a pixel uses surfel k - 1 only below its own last contributor.
    let hi = lanes_max(max(max(max(last.x, last.y), max(last.z, last.w)), r.x));
    for (var k = hi; k > r.x; k--) {
        let id = order[k - 1u];
        let reach = load_reach(id);
        // The column against the reach rectangle first (one test rejects most pairs
        // for all four), then each pixel. No `continue` before `lanes_any`: lanes
        // stay in step.
        var live = vec4<bool>(false);
        if !out_of_column(reach, px, ys.x, ys.w) {
            let off_x = px < reach.x || px > reach.z;
            live = (vec4<u32>(k) <= last) & !(vec4<bool>(off_x) | (ys < vec4<f32>(reach.y)) | (ys > vec4<f32>(reach.w)));
        }
        if !lanes_any(any(live)) {
            continue;
        }
        let s = load_surfel(id);
        let e = eval4(s, px, ys, view);
        live = live & (e.alpha >= vec4<f32>(MIN_ALPHA));
        if !lanes_any(any(live)) {
            continue;
        }
        // Lanes whose pixels do not use this surfel add zeros and keep their state.
        let g0 = stride * id;
        let o = (3u + CH) * id;
        let col = vec3<f32>(attrs[o], attrs[o + 1u], attrs[o + 2u]);
        // Colour: transmittance, weight, the colour term of dL/dalpha.
        t = select(t, t / (1.0 - e.alpha), live);
        let w = select(zero, e.alpha * t, live);
        acc_r = select(acc_r, last_alpha * last_r + (1.0 - last_alpha) * acc_r, live);
        acc_g = select(acc_g, last_alpha * last_g + (1.0 - last_alpha) * acc_g, live);
        acc_b = select(acc_b, last_alpha * last_b + (1.0 - last_alpha) * acc_b, live);
        last_r = select(last_r, vec4<f32>(col.x), live);
        last_g = select(last_g, vec4<f32>(col.y), live);
        last_b = select(last_b, vec4<f32>(col.z), live);
        var da = (col.x - acc_r) * dcr + (col.y - acc_g) * dcg + (col.z - acc_b) * dcb;
        // Σ_q l_q·dl_q of the four pixels, and each logit's gradient from them.
        var l_dot = zero;
        for (var q = 0u; q < CH; q++) {
            l_dot += attrs[o + 3u + q] * dl[q];
            lanes_add(g0 + S_LOGITS + q, dot(w, dl[q]));
        }
        acc_l = select(acc_l, last_alpha * last_l + (1.0 - last_alpha) * acc_l, live);
        last_l = select(last_l, l_dot, live);
        da += l_dot - acc_l;
        acc_d = select(acc_d, last_alpha * last_d + (1.0 - last_alpha) * acc_d, live);
        last_d = select(last_d, vec4<f32>(s.pc.z), live);
        da += (s.pc.z - acc_d) * dd;
        da = da * t + t_fin / (1.0 - e.alpha) * da_out;
        last_alpha = select(last_alpha, e.alpha, live);
        let g = shares(s, e, live & (e.raw_alpha <= vec4<f32>(MAX_ALPHA)), da);
        add3(g0 + S_RGB, vec3<f32>(dot(w, dcr), dot(w, dcg), dot(w, dcb)));
        lanes_add(g0 + S_OPACITY, g.op);
        lanes_add(g0 + S_SU, g.su);
        lanes_add(g0 + S_SV, g.sv);
        add3(g0 + S_TU, g.tu);
        add3(g0 + S_TV, g.tv);
        add3(g0 + S_N, g.n);
        add3(g0 + S_PC, g.pc + vec3<f32>(0.0, 0.0, dot(w, dd)));
    }
    // The exposure gradient: one add per invocation (four pixels).
    let e0 = stride * view.count;
    accum_add(e0, dexp.x);
    accum_add(e0 + 1u, dexp.y);
}
