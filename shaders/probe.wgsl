//! probe: a dense blend, the platform's own speed. Every pixel composites the same
//! list of isotropic Gaussians front to back (an exp, a few multiply-adds and a
//! broadcast load per Gaussian), with no sort, no per-tile lists, no early exit, no
//! barriers and no atomics. `rogs bench raster` times it beside the rasteriser on the
//! same adapter, so that the ratio between two adapters (SwiftShader in the browser,
//! lavapipe natively) on this kernel is the platform's, and whatever the rasteriser's
//! ratio adds to it is the rasteriser's. `ProbeParams` is generated from
//! src/render/probe.rs and prepended.
//!
//! Oracle: `dense_blend_cpu` in src/render/probe.rs.

@group(0) @binding(0) var<uniform> params: ProbeParams;
// Per Gaussian two vec4: (x, y, 1/σ², opacity) in pixels, then (r, g, b, unused).
@group(0) @binding(1) var<storage, read> blobs: array<vec4<f32>>;
// Per pixel: rgb, then the transmittance left.
@group(0) @binding(2) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    if gid.x >= params.width || gid.y >= params.height {
        return;
    }
    let at = vec2<f32>(f32(gid.x) + 0.5, f32(gid.y) + 0.5);
    var t = 1.0;
    var c = vec3<f32>(0.0);
    for (var i = 0u; i < params.count; i++) {
        let g = blobs[2u * i];
        let d = at - g.xy;
        let a = min(0.99, g.w * exp(-0.5 * dot(d, d) * g.z));
        c += t * a * blobs[2u * i + 1u].xyz;
        t *= 1.0 - a;
    }
    let o = 4u * (gid.y * params.width + gid.x);
    out[o] = c.x;
    out[o + 1u] = c.y;
    out[o + 2u] = c.z;
    out[o + 3u] = t;
}
