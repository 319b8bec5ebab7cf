//! Gradient accumulation with native float atomics.
//!
//! `atomicAdd` on `atomic<f32>` exists only natively (wgpu's SHADER_FLOAT32_ATOMIC,
//! storage buffers only); lavapipe has it and it is the fastest path under contention.
//! Kernels include this or `accum_cas.wgsl`, never both: both declare `accum` at
//! group 0, binding 0, and `accum_add`.

@group(0) @binding(0) var<storage, read_write> accum: array<atomic<f32>>;

fn accum_add(i: u32, v: f32) {
    atomicAdd(&accum[i], v);
}
