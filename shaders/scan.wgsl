//! scan: exclusive prefix sum of u32 counts, in three dispatches: (1) each invocation
//! scans a block of PER consecutive values serially and records the block's total;
//! (2) one workgroup scans the block totals, each invocation walking a contiguous
//! run (so any count of blocks works without recursion; `workgroup_scan`,
//! workgroup.wgsl, three barriers, prepended by the host); (3) every value gets its
//! block's offset. The grand total lands in `total[0]`, on the GPU, for the kernels
//! that follow (no read-back).
//!
//! Why the blocks are one invocation's: where a CPU runs the workgroups (SwiftShader
//! in Chromium, lavapipe natively), a kernel with any barrier runs every invocation
//! group as a coroutine. With one invocation per value and Hillis–Steele in each
//! 256-value block, SwiftShader took ~200 ms on 113 k values; with 8 values per
//! invocation and a workgroup scan per 2048 values, pass (1) still took 20× its
//! lavapipe time in Chromium (9.6 ms per step on `demo`). Without a barrier in (1),
//! only the single workgroup of (2) pays for one.

@group(0) @binding(0) var<storage, read> input: array<u32>;
@group(0) @binding(1) var<storage, read_write> output: array<u32>;
@group(0) @binding(2) var<storage, read_write> block_sums: array<u32>;
@group(0) @binding(3) var<storage, read_write> total: array<u32>;
// count, blocks (count / PER, rounded up), row stride of the block dispatch and of the
// per-value dispatch (in invocations).
@group(0) @binding(4) var<uniform> params: vec4<u32>;

// `PER` (values per block) is prepended by the host (src/render/gpu.rs, `SCAN_PER`).

@compute @workgroup_size(256)
fn scan_blocks(@builtin(global_invocation_id) gid: vec3<u32>) {
    let block = gid.x + gid.y * params.z;
    if block >= params.y {
        return;
    }
    let base = block * PER;
    var run = 0u;
    for (var i = base; i < min(base + PER, params.x); i++) {
        let v = input[i];
        output[i] = run;
        run += v;
    }
    block_sums[block] = run;
}

@compute @workgroup_size(256)
fn scan_sums(@builtin(local_invocation_index) li: u32) {
    let blocks = params.y;
    let per = (blocks + 255u) / 256u;
    let start = min(li * per, blocks);
    let end = min(start + per, blocks);
    var run = 0u;
    for (var b = start; b < end; b++) {
        run += block_sums[b];
    }
    let scanned = workgroup_scan(li, run);
    var acc = scanned.x;
    for (var b = start; b < end; b++) {
        let s = block_sums[b];
        block_sums[b] = acc;
        acc += s;
    }
    if li == 255u {
        total[0] = scanned.y;
    }
}

@compute @workgroup_size(256)
fn add_offsets(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * params.w;
    if i < params.x {
        output[i] += block_sums[i / PER];
    }
}
