//! workgroup: a 256-invocation workgroup's exclusive prefix sum (`workgroup_scan`) in
//! three barriers, prepended by the host to the kernels that scan per workgroup
//! (scan, radix_sort).
//!
//! Why not Hillis–Steele: where a CPU runs the workgroup (SwiftShader in Chromium,
//! lavapipe natively), each barrier suspends and resumes every invocation group of
//! the workgroup, and Hillis–Steele over 256 values takes 17 of them. Here 16
//! invocations each walk 16 values serially and one walks the 16 run totals: 3
//! barriers and 32 serial additions (scan_blocks in Chromium: 9.6 → 7.2 ms per step
//! on `demo`). A kernel with any barrier at all still pays for running its
//! invocations as coroutines there (partial_sums.wgsl).
//!
//! Call from uniform control flow by all 256 invocations.

var<workgroup> scan_all: array<u32, 256>;
var<workgroup> scan_runs: array<u32, 16>;
var<workgroup> scan_total: u32;

/// The exclusive prefix sum of `v` over the workgroup's 256 invocations (x) and the
/// workgroup's total (y), in every invocation.
fn workgroup_scan(li: u32, v: u32) -> vec2<u32> {
    scan_all[li] = v;
    workgroupBarrier();
    if li < 16u {
        var run = 0u;
        for (var k = 16u * li; k < 16u * li + 16u; k++) {
            let x = scan_all[k];
            scan_all[k] = run;
            run += x;
        }
        scan_runs[li] = run;
    }
    workgroupBarrier();
    if li == 0u {
        var run = 0u;
        for (var k = 0u; k < 16u; k++) {
            let x = scan_runs[k];
            scan_runs[k] = run;
            run += x;
        }
        scan_total = run;
    }
    workgroupBarrier();
    return vec2<u32>(scan_all[li] + scan_runs[li / 16u], scan_total);
}
