//! rasterize (forward): one workgroup per 16×16 tile, one invocation per pixel. The
//! tile's depth-sorted surfels are loaded 256 at a time into workgroup memory (each
//! invocation fetches one), then every pixel composites the batch front to back,
//! evaluating each surfel where its ray meets the surfel's plane (`eval_surfel`),
//! stopping once transmittance would drop below 1e-4. Logits have a runtime channel
//! count, so they accumulate in the output buffer rather than in registers.
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

var<workgroup> batch: array<Surfel, 256>;
var<workgroup> batch_id: array<u32, 256>;
var<workgroup> range: vec2<u32>;

@compute @workgroup_size(16, 16)
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
    var done = !inside;
    let batches = (r.y - r.x + 255u) / 256u;
    for (var b = 0u; b < batches; b++) {
        let base = r.x + b * 256u;
        let k = base + li;
        if k < r.y {
            let id = order[k];
            batch_id[li] = id;
            batch[li] = load_surfel(id);
        }
        workgroupBarrier();
        if !done {
            let m = min(256u, r.y - base);
            for (var j = 0u; j < m; j++) {
                let s = batch[j];
                let e = eval_surfel(s, px, py, view);
                if e.alpha < MIN_ALPHA {
                    continue;
                }
                let t_next = t * (1.0 - e.alpha);
                if t_next < MIN_TRANSMITTANCE {
                    done = true;
                    break;
                }
                let w = e.alpha * t;
                let id = batch_id[j];
                c += vec3<f32>(rgb[3u * id], rgb[3u * id + 1u], rgb[3u * id + 2u]) * w;
                for (var q = 0u; q < ch; q++) {
                    out_logits[pix * ch + q] += logits[id * ch + q] * w;
                }
                depth += s.pc.z * w;
                t = t_next;
                last_k = base + j + 1u;
            }
        }
        workgroupBarrier();
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
