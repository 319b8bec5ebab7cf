//! rasterize (forward): one workgroup per 8×8 tile; each invocation composites four
//! pixels of a column (rows 4j to 4j + 3) through its tile's depth-sorted surfels
//! front to back, evaluating each where its ray meets the surfel's plane (`eval4`
//! in view.wgsl, four rows at once); a pixel stops once its transmittance would
//! drop below 1e-4, the invocation when all four have. Four pixels share each
//! surfel's loads (list entry, reach, projected parameters, colour, logits), as in
//! `rasterize_backward`; their state is held as vec4 lanes (lane j = row 4j' + j),
//! not a struct per pixel nor an array, either of which SwiftShader keeps in memory
//! (with a struct per pixel this pass took 2.2 times as long in Chromium). A column
//! test and a four-compare reach test per pixel (`out_of_column`, then the pixels'
//! rows) come before the evaluation: most pairs of a far tile are out of reach, and pixels that never
//! saturate (sky, road beyond the far plane) walk the whole list. Measured on lavapipe:
//! 8×8 tiles halve the time of 16×16 ones (pixels that never saturate walk fewer
//! surfels; 4×4 loses it again to the extra pairs), and staging the list in workgroup
//! memory behind barriers gained nothing over reading storage directly. No barrier
//! at all: each invocation reads its tile's range itself, since where a CPU runs
//! workgroups (SwiftShader) a barrier, even a uniform load's, makes every invocation
//! group a coroutine (this pass took 1.23× as long in Chromium with one).
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


/// Whether pixel (x, y) composites at all: inside the view and, in training, the loss.
fn starts(x: u32, y: u32) -> bool {
    if x >= view.width || y >= view.height {
        return false;
    }
    return view.masked == 0u || (target_px[y * view.width + x] >> 24u) != 255u;
}

/// One pixel's state when the walk ends, lane j of the four.
struct Done {
    t: f32,
    c: vec3<f32>,
    depth: f32,
    wsum: f32,
    last_k: u32,
}

/// Writes pixel (x, y)'s outputs; lane j of `l` holds its logits.
fn finish(x: u32, y: u32, p: Done, gain: f32, l: ptr<function, array<vec4<f32>, CH_ARRAY>>, j: u32) {
    if x >= view.width || y >= view.height {
        return;
    }
    let pix = y * view.width + x;
    // The weighted mean scaled by the coverage (`view.average`), else the sums as they are.
    var scale = 1.0;
    if view.average != 0u && p.wsum > 0.0 {
        scale = (1.0 - p.t) / p.wsum;
    }
    for (var q = 0u; q < CH; q++) {
        out_logits[pix * CH + q] = (*l)[q][j] * scale;
    }
    let o = PIX_STRIDE * pix;
    for (var i = 0u; i < 3u; i++) {
        px_out[o + i] = gain * p.c[i] * scale + view.exposure_b;
        px_out[o + 7u + i] = p.c[i] * scale;
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
    let r = vec2<u32>(ranges[2u * tile], ranges[2u * tile + 1u]);
    let px = f32(x) + 0.5;
    let ys = vec4<f32>(f32(y) + 0.5, f32(y) + 1.5, f32(y) + 2.5, f32(y) + 3.5);
    // The four pixels' state, lane j for row y + j: plain vec4 variables rather than a
    // struct per pixel, which SwiftShader kept out of registers (the walk over the
    // list cost five times the bare walk there; docs/PERFORMANCE.md).
    var on = vec4<bool>(starts(x, y), starts(x, y + 1u), starts(x, y + 2u), starts(x, y + 3u));
    var t = vec4<f32>(1.0);
    var cr = vec4<f32>(0.0);
    var cg = vec4<f32>(0.0);
    var cb = vec4<f32>(0.0);
    var depth = vec4<f32>(0.0);
    var wsum = vec4<f32>(0.0);
    var last_k = vec4<u32>(0u);
    let average = view.average != 0u;
    var l: array<vec4<f32>, CH_ARRAY>;
    for (var k = r.x; k < r.y; k++) {
        if !any(on) {
            break;
        }
        let id = order[k];
        let reach = load_reach(id);
        // The column against the reach rectangle (`out_of_column`), then each pixel.
        if out_of_column(reach, px, ys.x, ys.w) {
            continue;
        }
        let off_x = px < reach.x || px > reach.z;
        var live = on & !(vec4<bool>(off_x) | (ys < vec4<f32>(reach.y)) | (ys > vec4<f32>(reach.w)));
        if !any(live) {
            continue;
        }
        let s = load_surfel(id);
        let alpha = eval4(s, px, ys, view).alpha;
        live = live & (alpha >= vec4<f32>(MIN_ALPHA));
        let t_next = t * (1.0 - alpha);
        // A pixel stops instead when the surfel would saturate it.
        if !average {
            let stop = live & (t_next < vec4<f32>(MIN_TRANSMITTANCE));
            on = on & !stop;
            live = live & !stop;
        }
        if !any(live) {
            continue;
        }
        let w = select(vec4<f32>(0.0), select(alpha * t, alpha, average), live);
        wsum += w;
        t = select(t, t_next, live);
        last_k = select(last_k, vec4<u32>(k + 1u), live);
        let o = (3u + CH) * id;
        cr += attrs[o] * w;
        cg += attrs[o + 1u] * w;
        cb += attrs[o + 2u] * w;
        depth += s.pc.z * w;
        for (var q = 0u; q < CH; q++) {
            l[q] += attrs[o + 3u + q] * w;
        }
    }
    let gain = exp(view.exposure_a + view.frame_a);
    finish(x, y, Done(t.x, vec3<f32>(cr.x, cg.x, cb.x), depth.x, wsum.x, last_k.x), gain, &l, 0u);
    finish(x, y + 1u, Done(t.y, vec3<f32>(cr.y, cg.y, cb.y), depth.y, wsum.y, last_k.y), gain, &l, 1u);
    finish(x, y + 2u, Done(t.z, vec3<f32>(cr.z, cg.z, cb.z), depth.z, wsum.z, last_k.z), gain, &l, 2u);
    finish(x, y + 3u, Done(t.w, vec3<f32>(cr.w, cg.w, cb.w), depth.w, wsum.w, last_k.w), gain, &l, 3u);
}
