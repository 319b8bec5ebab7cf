//! rasterize_backward: the forward kernel's pairs traversed back to front. One
//! workgroup per 8×8 tile, one invocation per pixel, each walking its tile's list back
//! from its own `last` contributor (so surfels behind its termination are never read),
//! recovering transmittance by division (alpha ≤ 0.99 keeps it stable), and adding its
//! share of each camera-space gradient with `lanes_add`: summed over the subgroup
//! first where the adapter has subgroups (lanes_subgroup.wgsl, the lanes walking in
//! step), then `accum_add` (native f32 atomics, or CAS in browsers; `accum` is bound
//! at 0 by the prepended snippet). Pixels read the list
//! straight from storage: on lavapipe, staging batches in workgroup memory behind
//! barriers was no faster. The exposure gradient is reduced over the workgroup first,
//! then added once. The logits (runtime channel count) need no per-pixel accumulators:
//! their share of dL/dalpha is Σ_q (l_q − acc_q)·dl_q, and since dl is fixed per pixel
//! the accumulated Σ_q acc_q·dl_q follows the same recurrence as acc_q, so two scalars
//! carry it (the oracle keeps one accumulator per channel, which is the same sum).
//!
//! Oracle: src/render/rasterize_backward.rs; slot layout `slot::*` there.

@group(0) @binding(1) var<uniform> view: View;
@group(0) @binding(2) var<storage, read> proj: array<f32>;
@group(0) @binding(3) var<storage, read> order: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<u32>;
@group(0) @binding(5) var<storage, read> rgb: array<f32>;
@group(0) @binding(6) var<storage, read> logits: array<f32>;
// Forward outputs (PIX_STRIDE per pixel) and loss gradients (GRAD_STRIDE per pixel:
// rgb 3, depth, alpha), packed to stay within 10 storage buffers per stage.
@group(0) @binding(7) var<storage, read> px_out: array<f32>;
@group(0) @binding(8) var<storage, read> g_px: array<f32>;
@group(0) @binding(9) var<storage, read> g_logits: array<f32>;
// Pairs and view gradients are per candidate slot; colours and logits per surfel.
@group(0) @binding(10) var<storage, read> cand: array<u32>;

const S_PC: u32 = 0u;
const S_TU: u32 = 3u;
const S_TV: u32 = 6u;
const S_N: u32 = 9u;
const S_SU: u32 = 12u;
const S_SV: u32 = 13u;
const S_OPACITY: u32 = 14u;
const S_RGB: u32 = 15u;
const S_LOGITS: u32 = 18u;

var<workgroup> range: vec2<u32>;
var<workgroup> red: array<vec2<f32>, 64>;

fn add3(base: u32, v: vec3<f32>) {
    lanes_add(base, v.x);
    lanes_add(base + 1u, v.y);
    lanes_add(base + 2u, v.z);
}

@compute @workgroup_size(8, 8)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wg.x + wg.y * view.tiles_x;
    let x = wg.x * TILE + lid.x;
    let y = wg.y * TILE + lid.y;
    let inside = x < view.width && y < view.height;
    let pix = y * view.width + x;
    let ch = view.channels;
    let stride = S_LOGITS + ch;
    if li == 0u {
        range = vec2<u32>(ranges[2u * tile], ranges[2u * tile + 1u]);
    }
    let r = workgroupUniformLoad(&range);
    let px = f32(x) + 0.5;
    let py = f32(y) + 0.5;
    let gain = exp(view.exposure_a);
    var dc = vec3<f32>(0.0);
    var dexp = vec2<f32>(0.0);
    var dd = 0.0;
    var t_fin = 1.0;
    var da_out = 0.0;
    var my_last = 0u;
    if inside {
        let gp = GRAD_STRIDE * pix;
        let po = PIX_STRIDE * pix;
        let go = vec3<f32>(g_px[gp], g_px[gp + 1u], g_px[gp + 2u]);
        dc = gain * go;
        let col = vec3<f32>(px_out[po + 7u], px_out[po + 8u], px_out[po + 9u]);
        dexp = vec2<f32>(dot(go * gain, col), go.x + go.y + go.z);
        dd = g_px[gp + 3u];
        da_out = g_px[gp + 4u];
        t_fin = px_out[po + 5u];
        my_last = bitcast<u32>(px_out[po + 6u]);
    }
    var t = t_fin;
    var acc_c = vec3<f32>(0.0);
    var last_c = vec3<f32>(0.0);
    var last_alpha = 0.0;
    var acc_d = 0.0;
    var last_d = 0.0;
    // Σ_q dl_q·acc_q and Σ_q dl_q·l_q of the previous surfel.
    var acc_l = 0.0;
    var last_l = 0.0;
    lanes_init(li);
    // Pixels outside the view or the loss mask have my_last = 0 and use nothing. A
    // pixel uses surfel k - 1 only below its own last contributor; the walk starts at
    // the highest bound among the lanes so that they stay in step (lanes_*.wgsl).
    let hi = lanes_max(max(my_last, r.x));
    for (var k = hi; k > r.x; k--) {
        let id = order[k - 1u];
        var live = k <= my_last && !out_of_reach(load_reach(id), px, py);
        var s: Surfel;
        var e: Eval;
        if live {
            s = load_surfel(id);
            e = eval_surfel(s, px, py, view);
            live = e.alpha >= MIN_ALPHA;
        }
        if !lanes_any(live) {
            continue;
        }
        // Lanes whose pixel does not use this surfel add zeros and keep their state.
        let g0 = stride * id;
        let si = cand[id];
        var w = 0.0;
        var d_alpha = 0.0;
        var g_rgb = vec3<f32>(0.0);
        if live {
            t = t / (1.0 - e.alpha);
            w = e.alpha * t;
            let c = vec3<f32>(rgb[3u * si], rgb[3u * si + 1u], rgb[3u * si + 2u]);
            acc_c = last_alpha * last_c + (1.0 - last_alpha) * acc_c;
            last_c = c;
            d_alpha = dot(c - acc_c, dc);
            g_rgb = w * dc;
        }
        add3(g0 + S_RGB, g_rgb);
        var l_dot = 0.0;
        for (var q = 0u; q < ch; q++) {
            var g_l = 0.0;
            if live {
                let dl = g_logits[pix * ch + q];
                l_dot += logits[si * ch + q] * dl;
                g_l = w * dl;
            }
            lanes_add(g0 + S_LOGITS + q, g_l);
        }
        if live {
            acc_l = last_alpha * last_l + (1.0 - last_alpha) * acc_l;
            last_l = l_dot;
            d_alpha += l_dot - acc_l;
        }
        var g_op = 0.0;
        var g_su = 0.0;
        var g_sv = 0.0;
        var g_tu = vec3<f32>(0.0);
        var g_tv = vec3<f32>(0.0);
        var g_n = vec3<f32>(0.0);
        var dpc = vec3<f32>(0.0);
        if live {
            acc_d = last_alpha * last_d + (1.0 - last_alpha) * acc_d;
            last_d = s.pc.z;
            d_alpha += (s.pc.z - acc_d) * dd;
            d_alpha = d_alpha * t + t_fin / (1.0 - e.alpha) * da_out;
            last_alpha = e.alpha;
            dpc = vec3<f32>(0.0, 0.0, w * dd);
            if e.raw_alpha <= MAX_ALPHA {
                let sig = s.opacity;
                g_op = d_alpha * e.g * sig * (1.0 - sig);
                let d_rho = d_alpha * sig * -0.5 * e.g;
                if e.ray_hit {
                    let gu = d_rho * 2.0 * e.u;
                    let gv = d_rho * 2.0 * e.v;
                    g_su = -gu * e.u / s.su;
                    g_sv = -gv * e.v / s.sv;
                    g_tu = gu * e.q / s.su;
                    g_tv = gv * e.q / s.sv;
                    let gq = gu * s.tu / s.su + gv * s.tv / s.sv;
                    let nd = dot(s.n, e.d);
                    let d_lambda = dot(gq, e.d);
                    dpc += -gq + d_lambda * s.n / nd;
                    g_n = d_lambda * (s.pc - e.d * e.lambda) / nd;
                } else {
                    let k2 = -2.0 * LOWPASS_INV_SQ * d_rho;
                    let dmu = k2 * e.delta;
                    let z = s.pc.z;
                    dpc += vec3<f32>(dmu.x * view.fx / z, dmu.y * view.fy / z, -(dmu.x * view.fx * s.pc.x + dmu.y * view.fy * s.pc.y) / (z * z));
                }
            }
        }
        lanes_add(g0 + S_OPACITY, g_op);
        lanes_add(g0 + S_SU, g_su);
        lanes_add(g0 + S_SV, g_sv);
        add3(g0 + S_TU, g_tu);
        add3(g0 + S_TV, g_tv);
        add3(g0 + S_N, g_n);
        add3(g0 + S_PC, dpc);
    }
    // The exposure gradient: one add per workgroup instead of one per pixel.
    red[li] = dexp;
    workgroupBarrier();
    for (var off = 32u; off > 0u; off = off / 2u) {
        if li < off {
            red[li] += red[li + off];
        }
        workgroupBarrier();
    }
    if li == 0u {
        let e0 = stride * view.count;
        accum_add(e0, red[0].x);
        accum_add(e0 + 1u, red[0].y);
    }
}
