//! scan: exclusive prefix sum of u32 counts, in three dispatches: (1) each workgroup
//! scans a block of 256 × PER values: each invocation sums its PER consecutive values
//! in registers, the workgroup scans the 256 sums in workgroup memory (Hillis–Steele,
//! 8 steps), and the block total is recorded; (2) one workgroup scans the block
//! totals, each invocation walking a contiguous run (so any count of blocks works
//! without recursion); (3) every value gets its block's offset. The grand total lands
//! in `total[0]`, on the GPU, for the kernels that follow (no read-back).
//!
//! Why PER values per invocation: workgroup barriers are dear where a CPU runs the
//! workgroup (SwiftShader in Chromium measured ~200 ms for one invocation per value on
//! 113 k values, 17 barriers per 256 values); PER = 8 divides the barriers by 8.

@group(0) @binding(0) var<storage, read> input: array<u32>;
@group(0) @binding(1) var<storage, read_write> output: array<u32>;
@group(0) @binding(2) var<storage, read_write> block_sums: array<u32>;
@group(0) @binding(3) var<storage, read_write> total: array<u32>;
// count, blocks, row stride of the block dispatch and of the per-value dispatch (in
// invocations).
@group(0) @binding(4) var<uniform> params: vec4<u32>;

const PER: u32 = 8u;
const BLOCK: u32 = 2048u; // 256 × PER

var<workgroup> tmp: array<u32, 256>;

@compute @workgroup_size(256)
fn scan_blocks(@builtin(local_invocation_index) li: u32, @builtin(workgroup_id) wg: vec3<u32>) {
    let block = wg.x + wg.y * (params.z / 256u);
    let base = block * BLOCK + li * PER;
    // Exclusive sums within this invocation's run.
    var before: array<u32, 8>;
    var run = 0u;
    for (var j = 0u; j < PER; j++) {
        let i = base + j;
        before[j] = run;
        run += select(0u, input[min(i, params.x - 1u)], i < params.x);
    }
    tmp[li] = run;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        let add = select(0u, tmp[li - off], li >= off);
        workgroupBarrier();
        tmp[li] = tmp[li] + add;
        workgroupBarrier();
    }
    let offset = tmp[li] - run;
    for (var j = 0u; j < PER; j++) {
        if base + j < params.x {
            output[base + j] = offset + before[j];
        }
    }
    if li == 255u {
        block_sums[block] = tmp[255];
    }
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
    tmp[li] = run;
    workgroupBarrier();
    for (var off = 1u; off < 256u; off = off * 2u) {
        let add = select(0u, tmp[li - off], li >= off);
        workgroupBarrier();
        tmp[li] = tmp[li] + add;
        workgroupBarrier();
    }
    var acc = tmp[li] - run;
    for (var b = start; b < end; b++) {
        let s = block_sums[b];
        block_sums[b] = acc;
        acc += s;
    }
    if li == 255u {
        total[0] = tmp[255];
    }
}

@compute @workgroup_size(256)
fn add_offsets(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x + gid.y * params.w;
    if i < params.x {
        output[i] += block_sums[i / BLOCK];
    }
}
