//! rasterize (forward): one workgroup per 8×8 tile, one invocation per pixel, each
//! compositing its tile's depth-sorted surfels front to back, evaluating each where its
//! ray meets the surfel's plane (`eval_surfel`) and stopping once transmittance would
//! drop below 1e-4. A four-compare reach test (`out_of_reach`) comes before the
//! evaluation: most pairs of a far tile are out of reach, and pixels that never
//! saturate (sky, road beyond the far plane) walk the whole list. Measured on lavapipe:
//! 8×8 tiles halve the time of 16×16 ones (pixels that never saturate walk fewer
//! surfels; 4×4 loses it again to the extra pairs), and staging the list in workgroup
//! memory behind barriers gained nothing over reading storage directly. Logits have a
//! runtime channel count, so they accumulate in the output buffer, not in registers.
//!
//! With `view.masked` (training), pixels outside the loss mask (class 255 in the packed
//! target) composite nothing: the loss ignores them, so their outputs and gradients
//! are not needed, and they are often the sky and far pixels that walk a whole list.
//! Their outputs read as empty (alpha 0, no last contributor), so the backward pass
//! walks nothing for them either. The loss, and so every gradient, is unchanged.
//!
//! Oracle: src/render/rasterize.rs.

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> proj: array<f32>;
@group(0) @binding(2) var<storage, read> order: array<u32>;
@group(0) @binding(3) var<storage, read> ranges: array<u32>;
@group(0) @binding(4) var<storage, read> rgb: array<f32>;
@group(0) @binding(5) var<storage, read> logits: array<f32>;
// Per pixel, PIX_STRIDE floats (browsers allow 10 storage buffers per stage, so the
// per-pixel outputs share one): rgb 3, depth, alpha, final transmittance, last
// contributor (u32 bits), colour before exposure 3.
@group(0) @binding(6) var<storage, read_write> px_out: array<f32>;
@group(0) @binding(7) var<storage, read_write> out_logits: array<f32>;
// The packed training target (class in the top byte); read only when `view.masked`.
@group(0) @binding(8) var<storage, read> target_px: array<u32>;
// Pairs name candidate slots; the colours and logits are the surfel's, `cand[slot]`.
@group(0) @binding(9) var<storage, read> cand: array<u32>;

var<workgroup> range: vec2<u32>;

@compute @workgroup_size(8, 8)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let tile = wg.x + wg.y * view.tiles_x;
    let x = wg.x * TILE + lid.x;
    let y = wg.y * TILE + lid.y;
    let inside = x < view.width && y < view.height;
    let pix = y * view.width + x;
    let ch = view.channels;
    if li == 0u {
        range = vec2<u32>(ranges[2u * tile], ranges[2u * tile + 1u]);
    }
    let r = workgroupUniformLoad(&range);
    if inside {
        for (var j = 0u; j < ch; j++) {
            out_logits[pix * ch + j] = 0.0;
        }
    }
    let px = f32(x) + 0.5;
    let py = f32(y) + 0.5;
    var t = 1.0;
    var c = vec3<f32>(0.0);
    var depth = 0.0;
    var last_k = 0u;
    let in_loss = inside && (view.masked == 0u || (target_px[pix] >> 24u) != 255u);
    if in_loss {
        for (var k = r.x; k < r.y; k++) {
            let id = order[k];
            if out_of_reach(load_reach(id), px, py) {
                continue;
            }
            let s = load_surfel(id);
            let e = eval_surfel(s, px, py, view);
            if e.alpha < MIN_ALPHA {
                continue;
            }
            let t_next = t * (1.0 - e.alpha);
            if t_next < MIN_TRANSMITTANCE {
                break;
            }
            let w = e.alpha * t;
            let si = cand[id];
            c += vec3<f32>(rgb[3u * si], rgb[3u * si + 1u], rgb[3u * si + 2u]) * w;
            for (var q = 0u; q < ch; q++) {
                out_logits[pix * ch + q] += logits[si * ch + q] * w;
            }
            depth += s.pc.z * w;
            t = t_next;
            last_k = k + 1u;
        }
    }
    if !inside {
        return;
    }
    let gain = exp(view.exposure_a);
    let o = PIX_STRIDE * pix;
    for (var j = 0u; j < 3u; j++) {
        px_out[o + j] = gain * c[j] + view.exposure_b;
        px_out[o + 7u + j] = c[j];
    }
    px_out[o + 3u] = depth;
    px_out[o + 4u] = 1.0 - t;
    px_out[o + 5u] = t;
    px_out[o + 6u] = bitcast<f32>(last_k);
}
