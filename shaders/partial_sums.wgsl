//! partial_sums: sums of consecutive runs of `RUN` values (each `STRIDE` floats), one
//! invocation per run, with no workgroup memory and no barrier. The loss and the
//! regularisers write one value per pixel or per invocation; this reduces them to
//! the few kilobytes of partial sums the host reads back at the end of a step, and
//! (with `GUARD`: the loss, whose sums guard the update) raises `status[0]`
//! (guard.wgsl) when a sum is not usable.
//!
//! Why not a workgroup reduction inside those kernels: where a CPU runs the
//! workgroup, a kernel with any barrier runs every invocation group as a coroutine.
//! In Chromium (SwiftShader) the loss kernel with its reduction tree took 16-24× its
//! lavapipe time; the same work with its sums here took about 3× (docs/PERFORMANCE.md,
//! "Kernels without barriers"). `STRIDE`, `RUN` and `GUARD` are prepended by the host
//! (src/gpu/partial_sums.rs), with guard.wgsl.
//!
//! Oracle: `partial_sums_cpu` in src/gpu/partial_sums.rs.

// count: values; row: invocations per row of the 2D dispatch.
@group(0) @binding(0) var<uniform> sp: vec4<u32>;
@group(0) @binding(1) var<storage, read> values: array<f32>;
@group(0) @binding(2) var<storage, read_write> sums: array<f32>;
@group(0) @binding(3) var<storage, read_write> status: array<u32>;

@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = gid.x + gid.y * sp.y;
    let first = w * RUN;
    if first >= sp.x {
        return;
    }
    let last = min(first + RUN, sp.x);
    for (var k = 0u; k < STRIDE; k++) {
        var s = 0.0;
        for (var i = first; i < last; i++) {
            s += values[STRIDE * i + k];
        }
        sums[STRIDE * w + k] = s;
        if GUARD && !usable(s) {
            status[0] = 1u;
        }
    }
}
