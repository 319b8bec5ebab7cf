//! rasterize (forward): one workgroup per 8×8 tile; each invocation composites four
//! pixels of a column (rows 4j to 4j + 3) through its tile's depth-sorted surfels
//! front to back, evaluating each where its ray meets the surfel's plane
//! (`eval_surfel`); a pixel stops once its transmittance would drop below 1e-4, the
//! invocation when all four have. Four pixels share each surfel's loads (list entry,
//! reach, projected parameters, colour, logits), as in `rasterize_backward`, and are
//! named variables rather than an array, which SwiftShader would keep in memory. A
//! four-compare reach test (`out_of_reach`) comes before the
//! evaluation: most pairs of a far tile are out of reach, and pixels that never
//! saturate (sky, road beyond the far plane) walk the whole list. Measured on lavapipe:
//! 8×8 tiles halve the time of 16×16 ones (pixels that never saturate walk fewer
//! surfels; 4×4 loses it again to the extra pairs), and staging the list in workgroup
//! memory behind barriers gained nothing over reading storage directly.
//!
//! Logits: the channel count is the model's, fixed when the pipeline is built (`CH`,
//! prepended by the host, any count). The four pixels' sums live in registers, one
//! vec4 per channel (lane j = pixel j), so a composited surfel adds its logit times
//! the four weights in one multiply-add per channel and the output is written once
//! per pixel. Accumulating in the output buffer instead (a load and a store per pixel
//! and channel, scattered) cost 35 % of this kernel on lavapipe; SwiftShader keeps
//! the array in memory, and it is faster there too (docs/PERFORMANCE.md).
//!
//! With `view.masked` (training), pixels outside the loss mask (class 255 in the packed
//! target) composite nothing: the loss ignores them, so their outputs and gradients
//! are not needed, and they are often the sky and far pixels that walk a whole list.
//! Their outputs read as empty (alpha 0, no last contributor), so the backward pass
//! walks nothing for them either. The loss, and so every gradient, is unchanged.
//!
//! With `view.average` (the map's view from above, `Compositing::Average`), a pixel
//! takes the alpha-weighted mean of every surfel it meets instead, scaled by the
//! coverage 1 − Π(1 − α): coplanar neighbours sorted front to back would let
//! whichever lies a millimetre higher cover their overlap, shifting the map downhill
//! and speckling it. Nothing trains through that view, so the backward pass has no
//! such mode.
//!
//! Oracle: src/render/rasterize.rs.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> proj: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> order: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<u32>;
// Per candidate slot: colour 3, then the logits (the view's copy, `gather.wgsl`).
@group(0) @binding(4) var<storage, read> attrs: array<f32>;
// Per pixel, PIX_STRIDE floats (browsers allow 10 storage buffers per stage, so the
// per-pixel outputs share one): rgb 3, depth, alpha, final transmittance, last
// contributor (u32 bits), colour before exposure 3.
@group(0) @binding(6) var<storage, read_write> px_out: array<f32>;
@group(0) @binding(7) var<storage, read_write> out_logits: array<f32>;
// The packed training target (class in the top byte); read only when `view.masked`.
@group(0) @binding(8) var<storage, read> target_px: array<u32>;

var<workgroup> range: vec2<u32>;

/// One pixel's compositing state and its use of the current surfel.
struct Pixel {
    pix: u32,
    at: vec2<f32>,
    // Still compositing: inside the view and the loss, transmittance not yet spent.
    on: bool,
    t: f32,
    c: vec3<f32>,
    depth: f32,
    last_k: u32,
    // The sum of the weights (`view.average`).
    wsum: f32,
    // The current surfel: whether it is composited here, and its weight.
    live: bool,
    w: f32,
}

fn start_pixel(x: u32, y: u32) -> Pixel {
    var p = Pixel();
    p.at = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
    p.t = 1.0;
    if x < view.width && y < view.height {
        p.pix = y * view.width + x;
        p.on = view.masked == 0u || (target_px[p.pix] >> 24u) != 255u;
    }
    return p;
}

/// The reach test: whether the surfel may cover a pixel still compositing.
fn near(p: ptr<function, Pixel>, reach: vec4<f32>) -> bool {
    (*p).live = (*p).on && !out_of_reach(reach, (*p).at.x, (*p).at.y);
    return (*p).live;
}

/// Evaluates the surfel at list position k for a pixel that passed the reach test:
/// whether it is composited (the pixel stops instead when it would saturate).
fn weigh(p: ptr<function, Pixel>, s: Surfel, k: u32) -> bool {
    if !(*p).live {
        return false;
    }
    let e = eval_surfel(s, (*p).at.x, (*p).at.y, view);
    (*p).live = false;
    if e.alpha < MIN_ALPHA {
        return false;
    }
    let t_next = (*p).t * (1.0 - e.alpha);
    let average = view.average != 0u;
    if t_next < MIN_TRANSMITTANCE && !average {
        (*p).on = false;
        return false;
    }
    (*p).live = true;
    (*p).w = select(e.alpha * (*p).t, e.alpha, average);
    (*p).wsum += (*p).w;
    (*p).t = t_next;
    (*p).last_k = k + 1u;
    return true;
}

fn blend(p: ptr<function, Pixel>, col: vec3<f32>, z: f32) {
    if (*p).live {
        (*p).c += col * (*p).w;
        (*p).depth += z * (*p).w;
    }
}

/// The pixel's weight of the current surfel (0 where it is not composited).
fn weight(p: Pixel) -> f32 {
    return select(0.0, p.w, p.live);
}

/// Writes pixel j's outputs; `l` holds the four pixels' logits (lane j is this one).
fn finish(p: Pixel, x: u32, y: u32, gain: f32, l: ptr<function, array<vec4<f32>, CH_ARRAY>>, j: u32) {
    if x >= view.width || y >= view.height {
        return;
    }
    // The weighted mean scaled by the coverage (`view.average`), else the sums as they are.
    var scale = 1.0;
    if view.average != 0u && p.wsum > 0.0 {
        scale = (1.0 - p.t) / p.wsum;
    }
    for (var q = 0u; q < CH; q++) {
        out_logits[p.pix * CH + q] = (*l)[q][j] * scale;
    }
    let o = PIX_STRIDE * p.pix;
    for (var j = 0u; j < 3u; j++) {
        px_out[o + j] = gain * p.c[j] * scale + view.exposure_b;
        px_out[o + 7u + j] = p.c[j] * scale;
    }
    px_out[o + 3u] = p.depth * scale;
    px_out[o + 4u] = 1.0 - p.t;
    px_out[o + 5u] = p.t;
    px_out[o + 6u] = bitcast<f32>(p.last_k);
}

@compute @workgroup_size(8, 2)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wg.x + wg.y * view.tiles_x;
    let x = wg.x * TILE + lid.x;
    let y = wg.y * TILE + 4u * lid.y;
    if li == 0u {
        range = vec2<u32>(ranges[2u * tile], ranges[2u * tile + 1u]);
    }
    let r = workgroupUniformLoad(&range);
    var a = start_pixel(x, y);
    var b = start_pixel(x, y + 1u);
    var c = start_pixel(x, y + 2u);
    var d = start_pixel(x, y + 3u);
    var l: array<vec4<f32>, CH_ARRAY>;
    for (var k = r.x; k < r.y; k++) {
        if !(a.on || b.on || c.on || d.on) {
            break;
        }
        let id = order[k];
        let reach = load_reach(id);
        // The four pixels' column against the reach rectangle first: one test
        // rejects most pairs of a tile for all four.
        if out_of_column(reach, a.at.x, a.at.y, d.at.y) {
            continue;
        }
        // Non-short-circuit `|`: every pixel's test must run.
        if !(near(&a, reach) | near(&b, reach) | near(&c, reach) | near(&d, reach)) {
            continue;
        }
        let s = load_surfel(id);
        if !(weigh(&a, s, k) | weigh(&b, s, k) | weigh(&c, s, k) | weigh(&d, s, k)) {
            continue;
        }
        let o = (3u + CH) * id;
        let col = vec3<f32>(attrs[o], attrs[o + 1u], attrs[o + 2u]);
        blend(&a, col, s.pc.z);
        blend(&b, col, s.pc.z);
        blend(&c, col, s.pc.z);
        blend(&d, col, s.pc.z);
        let w = vec4<f32>(weight(a), weight(b), weight(c), weight(d));
        for (var q = 0u; q < CH; q++) {
            l[q] += attrs[o + 3u + q] * w;
        }
    }
    let gain = exp(view.exposure_a);
    finish(a, x, y, gain, &l, 0u);
    finish(b, x, y + 1u, gain, &l, 1u);
    finish(c, x, y + 2u, gain, &l, 2u);
    finish(d, x, y + 3u, gain, &l, 3u);
}
