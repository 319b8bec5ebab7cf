//! rasterize_backward: the forward kernel's pairs traversed back to front. One
//! workgroup per 8×8 tile; each invocation owns four pixels of a column (rows 4j to
//! 4j + 3), walks its tile's list back from the latest of their `last` contributors
//! (so surfels behind every termination are never read), recovers each pixel's
//! transmittance by division (alpha ≤ 0.99 keeps it stable), and adds the two
//! pixels' summed share of each camera-space gradient with `lanes_add`: summed over
//! the subgroup first where the adapter has subgroups (lanes_subgroup.wgsl, the lanes
//! walking in step), then `accum_add` (native f32 atomics, or CAS in browsers;
//! `accum` is bound at 0 by the prepended snippet).
//!
//! Why four pixels per invocation: the adds are what this pass costs where there are
//! no float atomics (a compare-and-swap loop per value, 18 + channels values per
//! surfel) and, with subgroups, the reductions; neighbouring pixels share most
//! surfels, so summing four in registers divides both by up to four, and the surfel's
//! projected parameters, colour and logits are loaded once for four pixels. The four
//! are named variables, not an array: SwiftShader keeps an indexed array in memory,
//! and that cost more than the adds it saved (measured in docs/PERFORMANCE.md). Pixels read the list
//! straight from storage: on lavapipe, staging batches in workgroup memory behind
//! barriers was no faster. The exposure gradient is reduced over the workgroup
//! first, then added once. The logits need no per-pixel accumulators: their share of
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

var<workgroup> range: vec2<u32>;
var<workgroup> red: array<vec2<f32>, 16>;

/// One pixel's loss gradients, its state along the walk and the current surfel.
struct Pixel {
    pix: u32,
    at: vec2<f32>,
    dc: vec3<f32>,
    dd: f32,
    da_out: f32,
    t_fin: f32,
    // Its last contributor + 1 (0: outside the view or the loss mask, uses nothing).
    last: u32,
    t: f32,
    acc_c: vec3<f32>,
    last_c: vec3<f32>,
    last_alpha: f32,
    acc_d: f32,
    last_d: f32,
    // Σ_q dl_q·acc_q and Σ_q dl_q·l_q of the previous surfel.
    acc_l: f32,
    last_l: f32,
    // The current surfel: whether the pixel uses it, its evaluation, weight, dL/dalpha
    // so far and Σ_q l_q·dl_q.
    live: bool,
    e: Eval,
    w: f32,
    d_alpha: f32,
    l_dot: f32,
}

/// A surfel's camera-space gradients from one or more pixels.
struct Share {
    rgb: vec3<f32>,
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

fn start_pixel(x: u32, y: u32, gain: f32, dexp: ptr<function, vec2<f32>>) -> Pixel {
    var p = Pixel();
    p.at = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
    p.t = 1.0;
    p.t_fin = 1.0;
    if x < view.width && y < view.height {
        p.pix = y * view.width + x;
        let gp = GRAD_STRIDE * p.pix;
        let po = PIX_STRIDE * p.pix;
        let go = vec3<f32>(g_px[gp], g_px[gp + 1u], g_px[gp + 2u]);
        p.dc = gain * go;
        let col = vec3<f32>(px_out[po + 7u], px_out[po + 8u], px_out[po + 9u]);
        *dexp += vec2<f32>(dot(go * gain, col), go.x + go.y + go.z);
        p.dd = g_px[gp + 3u];
        p.da_out = g_px[gp + 4u];
        p.t_fin = px_out[po + 5u];
        p.t = p.t_fin;
        p.last = bitcast<u32>(px_out[po + 6u]);
    }
    return p;
}

/// Whether pixel `p` may use the surfel at list position k - 1 (the reach test).
fn reach_test(p: ptr<function, Pixel>, k: u32, reach: vec4<f32>) -> bool {
    (*p).live = k <= (*p).last && !out_of_reach(reach, (*p).at.x, (*p).at.y);
    return (*p).live;
}

/// Evaluates the surfel where the reach test passed; whether the pixel uses it.
fn evaluate(p: ptr<function, Pixel>, s: Surfel) -> bool {
    if (*p).live {
        (*p).e = eval_surfel(s, (*p).at.x, (*p).at.y, view);
        (*p).live = (*p).e.alpha >= MIN_ALPHA;
    }
    return (*p).live;
}

/// Colour step of a used surfel: transmittance, weight, colour term of dL/dalpha.
fn colour(p: ptr<function, Pixel>, c: vec3<f32>) {
    if !(*p).live {
        return;
    }
    let alpha = (*p).e.alpha;
    (*p).t = (*p).t / (1.0 - alpha);
    (*p).w = alpha * (*p).t;
    (*p).acc_c = (*p).last_alpha * (*p).last_c + (1.0 - (*p).last_alpha) * (*p).acc_c;
    (*p).last_c = c;
    (*p).d_alpha = dot(c - (*p).acc_c, (*p).dc);
}

/// The pixel's weight of the current surfel (0 where it does not use it).
fn weight(p: Pixel) -> f32 {
    return select(0.0, p.w, p.live);
}

/// Reads pixel j's logit gradients into lane j of `dl`.
fn load_dl(p: Pixel, x: u32, y: u32, dl: ptr<function, array<vec4<f32>, CH_ARRAY>>, j: u32) {
    if x >= view.width || y >= view.height {
        return;
    }
    for (var q = 0u; q < CH; q++) {
        (*dl)[q][j] = g_logits[p.pix * CH + q];
    }
}

/// The rest of a used surfel's gradients from pixel `p` (zero where it is not used).
fn geometry(p: ptr<function, Pixel>, s: Surfel) -> Share {
    var g = Share();
    if !(*p).live {
        return g;
    }
    let e = (*p).e;
    let w = (*p).w;
    g.rgb = w * (*p).dc;
    (*p).acc_l = (*p).last_alpha * (*p).last_l + (1.0 - (*p).last_alpha) * (*p).acc_l;
    (*p).last_l = (*p).l_dot;
    var d_alpha = (*p).d_alpha + (*p).l_dot - (*p).acc_l;
    (*p).acc_d = (*p).last_alpha * (*p).last_d + (1.0 - (*p).last_alpha) * (*p).acc_d;
    (*p).last_d = s.pc.z;
    d_alpha += (s.pc.z - (*p).acc_d) * (*p).dd;
    d_alpha = d_alpha * (*p).t + (*p).t_fin / (1.0 - e.alpha) * (*p).da_out;
    (*p).last_alpha = e.alpha;
    g.pc = vec3<f32>(0.0, 0.0, w * (*p).dd);
    if e.raw_alpha <= MAX_ALPHA {
        let sig = s.opacity;
        g.op = d_alpha * e.g * sig * (1.0 - sig);
        let d_rho = d_alpha * sig * -0.5 * e.g;
        if e.ray_hit {
            let gu = d_rho * 2.0 * e.u;
            let gv = d_rho * 2.0 * e.v;
            g.su = -gu * e.u / s.su;
            g.sv = -gv * e.v / s.sv;
            g.tu = gu * e.q / s.su;
            g.tv = gv * e.q / s.sv;
            let gq = gu * s.tu / s.su + gv * s.tv / s.sv;
            let nd = dot(s.n, e.d);
            let d_lambda = dot(gq, e.d);
            g.pc += -gq + d_lambda * s.n / nd;
            g.n = d_lambda * (s.pc - e.d * e.lambda) / nd;
        } else {
            let k2 = -2.0 * LOWPASS_INV_SQ * d_rho;
            let dmu = k2 * e.delta;
            let z = s.pc.z;
            g.pc += vec3<f32>(dmu.x * view.fx / z, dmu.y * view.fy / z, -(dmu.x * view.fx * s.pc.x + dmu.y * view.fy * s.pc.y) / (z * z));
        }
    }
    return g;
}

fn plus(a: Share, b: Share) -> Share {
    var g: Share;
    g.rgb = a.rgb + b.rgb;
    g.op = a.op + b.op;
    g.su = a.su + b.su;
    g.sv = a.sv + b.sv;
    g.tu = a.tu + b.tu;
    g.tv = a.tv + b.tv;
    g.n = a.n + b.n;
    g.pc = a.pc + b.pc;
    return g;
}

@compute @workgroup_size(8, 2)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wg.x + wg.y * view.tiles_x;
    let x = wg.x * TILE + lid.x;
    let y = wg.y * TILE + 4u * lid.y;
    let stride = S_LOGITS + CH;
    if li == 0u {
        range = vec2<u32>(ranges[2u * tile], ranges[2u * tile + 1u]);
    }
    let r = workgroupUniformLoad(&range);
    let gain = exp(view.exposure_a);
    var dexp = vec2<f32>(0.0);
    var a = start_pixel(x, y, gain, &dexp);
    var b = start_pixel(x, y + 1u, gain, &dexp);
    var c = start_pixel(x, y + 2u, gain, &dexp);
    var d = start_pixel(x, y + 3u, gain, &dexp);
    var dl: array<vec4<f32>, CH_ARRAY>;
    load_dl(a, x, y, &dl, 0u);
    load_dl(b, x, y + 1u, &dl, 1u);
    load_dl(c, x, y + 2u, &dl, 2u);
    load_dl(d, x, y + 3u, &dl, 3u);
    lanes_init(li);
    // The walk starts at the highest bound among the lanes so that they stay in step
    // (lanes_*.wgsl); a pixel uses surfel k - 1 only below its own last contributor.
    let hi = lanes_max(max(max(max(a.last, b.last), max(c.last, d.last)), r.x));
    for (var k = hi; k > r.x; k--) {
        let id = order[k - 1u];
        let reach = load_reach(id);
        // The four pixels' column against the reach rectangle first (one test rejects
        // most pairs for all four), then each pixel; non-short-circuit `|`: every
        // pixel's test must run. No `continue` before `lanes_any`: lanes stay in step.
        var any = false;
        if !out_of_column(reach, a.at.x, a.at.y, d.at.y) {
            any = reach_test(&a, k, reach) | reach_test(&b, k, reach) | reach_test(&c, k, reach) | reach_test(&d, k, reach);
        } else {
            a.live = false;
            b.live = false;
            c.live = false;
            d.live = false;
        }
        var s = Surfel();
        if any {
            s = load_surfel(id);
            any = evaluate(&a, s) | evaluate(&b, s) | evaluate(&c, s) | evaluate(&d, s);
        }
        if !lanes_any(any) {
            continue;
        }
        // Lanes whose pixels do not use this surfel add zeros and keep their state.
        let g0 = stride * id;
        let o = (3u + CH) * id;
        var col = vec3<f32>(0.0);
        if any {
            col = vec3<f32>(attrs[o], attrs[o + 1u], attrs[o + 2u]);
        }
        colour(&a, col);
        colour(&b, col);
        colour(&c, col);
        colour(&d, col);
        // Σ_q l_q·dl_q of the four pixels, and each logit's gradient from them.
        let w = vec4<f32>(weight(a), weight(b), weight(c), weight(d));
        var l_dot = vec4<f32>(0.0);
        for (var q = 0u; q < CH; q++) {
            var l = 0.0;
            if any {
                l = attrs[o + 3u + q];
            }
            l_dot += l * dl[q];
            lanes_add(g0 + S_LOGITS + q, dot(w, dl[q]));
        }
        a.l_dot = l_dot.x;
        b.l_dot = l_dot.y;
        c.l_dot = l_dot.z;
        d.l_dot = l_dot.w;
        let g = plus(plus(geometry(&a, s), geometry(&b, s)), plus(geometry(&c, s), geometry(&d, s)));
        add3(g0 + S_RGB, g.rgb);
        lanes_add(g0 + S_OPACITY, g.op);
        lanes_add(g0 + S_SU, g.su);
        lanes_add(g0 + S_SV, g.sv);
        add3(g0 + S_TU, g.tu);
        add3(g0 + S_TV, g.tv);
        add3(g0 + S_N, g.n);
        add3(g0 + S_PC, g.pc);
    }
    // The exposure gradient: one add per workgroup instead of one per pixel.
    red[li] = dexp;
    workgroupBarrier();
    for (var off = 8u; off > 0u; off = off / 2u) {
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
