//! gather: copies the colour and logits of a view's candidate surfels, in candidate
//! slot order, into the view's `attrs` (3 + CH floats per slot: rgb, then logits),
//! from one window of the model's buffers.
//!
//! Why: the logits are the model's largest per-surfel buffer (4·CH bytes), and a
//! buffer bound whole must fit the adapter's storage binding (128 MiB on lavapipe:
//! 3.7 M surfels with 9 classes). The compositing kernels read colours and logits
//! only for the view's candidates (a tenth of a large model), so they read them from
//! this per-view copy, and only this pass touches the model's buffers, one window of
//! whole surfels at a time (`GpuRasterizer::attr_windows`). Candidates are increasing,
//! so a window's candidates are one run of slots [first, first + count) and each pass
//! visits only those. The copy is also contiguous in slot order, which is the order
//! the compositing kernels' loads follow.
//!
//! Oracle: none needed: a copy, checked through the forward and backward passes
//! against src/render/rasterize.rs with windows of 64 surfels (`tests/render_gpu.rs`).

struct Gather {
    // First candidate slot of this window and how many slots follow.
    first: u32,
    count: u32,
    // First surfel of the bound window of `rgb` and `logits`.
    base: u32,
    // Invocations per row of the 2D dispatch.
    row: u32,
}

@group(0) @binding(0) var<uniform> g: Gather;
@group(0) @binding(1) var<storage, read> cand: array<u32>;
@group(0) @binding(2) var<storage, read> rgb: array<f32>;
@group(0) @binding(3) var<storage, read> logits: array<f32>;
@group(0) @binding(4) var<storage, read_write> attrs: array<f32>;

@compute @workgroup_size(256)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = id.y * g.row + id.x;
    if k >= g.count {
        return;
    }
    let slot = g.first + k;
    let s = cand[slot] - g.base;
    let o = (3u + CH) * slot;
    attrs[o] = rgb[3u * s];
    attrs[o + 1u] = rgb[3u * s + 1u];
    attrs[o + 2u] = rgb[3u * s + 2u];
    for (var q = 0u; q < CH; q++) {
        attrs[o + 3u + q] = logits[CH * s + q];
    }
}
