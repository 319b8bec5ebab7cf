//! radix_sort: one pass of a stable LSD radix sort of (u32 key, u32 value) pairs.
//!
//! The host runs ceil(key_bits / 8) passes, 8 bits per pass, ping-ponging between two
//! key/value buffer pairs. A pass is five dispatches, all reading the element count
//! from `count_buf[0]` on the GPU (clamped to the bound buffers), so a producer kernel
//! can write the count and the sort can follow in the same command buffer with no
//! read-back; dispatches are sized for a host-known upper bound and the blocks past
//! the GPU count return at once.
//!
//! A block is BLOCK = 8192 consecutive keys, one workgroup of 16 threads, each thread
//! owning a run of 512 consecutive keys that it walks serially. Every thread counts
//! digits in its own column of a 256 x 16 counter matrix in workgroup memory, so there
//! are no atomics and at most two barriers per block.
//!
//! 1. `count`: per block, the column counts are summed into a 256-bin histogram,
//!    stored digit-major, `hist[digit * blocks + block]`, so that one exclusive scan
//!    of `hist` gives every (digit, block) its first output slot: all smaller digits,
//!    then the same digit in earlier blocks.
//! 2. `scan_reduce`, `scan_partials`, `scan_down`: a three-level exclusive scan of
//!    `hist` (tiles of 2048 summed, the tile sums scanned by one looping workgroup, the
//!    tiles scanned with their offsets). The looping level has no size limit: 32M keys
//!    give 1M histogram entries and 512 tile sums.
//! 3. `scatter`: each block counts again, turns every digit's row of counters into
//!    output slots (its scanned `hist` entry plus the counts of the columns before:
//!    a thread's keys of digit d follow those of the threads before it) and walks its
//!    run once more, writing each pair to its digit's next slot.
//!    Runs in input order within threads, threads in order within blocks and blocks
//!    in scan order keep equal digits in input order: the sort is stable.
//!
//! Why this shape: a software adapter (lavapipe, SwiftShader) runs a workgroup as
//! coroutines over SIMD lanes, so every workgroup barrier costs microseconds and
//! workgroup atomics several times a plain access. Two textbook designs measured here
//! on lavapipe, a block-local sort by two 4-bit split steps (~40 barriers per 2048
//! keys) and a per-chunk rank from `atomicOr` digit masks, sorted 2.5-4x slower. On
//! real GPUs the column layout has no bank conflicts (thread t owns bank t) and all
//! runs proceed at once, each walk short enough to take well under a millisecond;
//! the cost there is 16-invocation workgroups filling half a 32-wide SIMD unit. Workgroups of at most
//! 256 invocations (the browser limit); the 2D grid, linearised with `num_workgroups`,
//! lifts the 65535-groups-per-dimension limit. Every entry point stays within 16 KiB
//! of workgroup memory, WebGPU's default limit. Key bits above `shift + bits` are
//! ignored, so keys only need to be meaningful in their low `key_bits` bits.

// Threads per block and keys per thread in `count` and `scatter`: 256 digits x 16
// columns of u32 counters fill 16 KiB. Longer runs mean fewer blocks (a smaller
// histogram to scan) but longer serial walks.
const COLS: u32 = 16u;
const RUN: u32 = 512u;
const BLOCK: u32 = 8192u; // COLS * RUN
const WG: u32 = 256u; // scan kernels
const SCAN_ITEMS: u32 = 8u;
const SCAN_BLOCK: u32 = 2048u; // WG * SCAN_ITEMS

struct Pass {
    shift: u32,
    // 1..=8: the last pass of a key_bits that is not a multiple of 8 is narrower.
    bits: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(0) @binding(0) var<storage, read> keys_in: array<u32>;
@group(0) @binding(1) var<storage, read> vals_in: array<u32>;
@group(0) @binding(2) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(3) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> hist: array<u32>;
@group(0) @binding(5) var<storage, read_write> partials: array<u32>;
@group(0) @binding(6) var<storage, read> count_buf: array<u32>;
@group(0) @binding(7) var<uniform> pass_params: Pass;

// counters[d * COLS + t]: thread t's count of digit d (`count`), then the output
// slot of its next key of digit d (`scatter`).
var<workgroup> counters: array<u32, 4096>; // 256 * COLS
var<workgroup> tile: array<u32, 2048>; // SCAN_BLOCK

// The count from the GPU, never past the bound key buffers (bound with the capacity
// as their size). Read-only storage: uniform, so it may guard barriers.
fn element_count() -> u32 {
    return min(count_buf[0], arrayLength(&keys_in));
}

fn block_count(n: u32) -> u32 {
    return (n + BLOCK - 1u) / BLOCK;
}

fn radix() -> u32 {
    return 1u << pass_params.bits;
}

// Histogram entries this pass: only the digits a narrow last pass can produce.
fn scan_len() -> u32 {
    return radix() * block_count(element_count());
}

fn digit_of(key: u32) -> u32 {
    return (key >> pass_params.shift) & (radix() - 1u);
}

fn group_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

// Zeroes the counters, then thread t counts the digits of its run into its column.
// Ends with a barrier: the whole matrix is ready.
fn count_columns(t: u32, base: u32, n: u32) {
    for (var d = 0u; d < 256u; d++) {
        counters[d * COLS + t] = 0u;
    }
    // Each thread only touches its own column: no barrier needed before counting.
    let first = base + t * RUN;
    let last = min(first + RUN, n);
    for (var i = first; i < last; i++) {
        counters[digit_of(keys_in[i]) * COLS + t] += 1u;
    }
    workgroupBarrier();
}

@compute @workgroup_size(COLS)
fn count(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let block = group_index(wid, nwg);
    let n = element_count();
    let nb = block_count(n);
    if block >= nb {
        return;
    }
    count_columns(t, block * BLOCK, n);
    // Thread t sums the rows of digits t, t + 16, ...
    for (var d = t; d < radix(); d += COLS) {
        var total = 0u;
        for (var c = 0u; c < COLS; c++) {
            total += counters[d * COLS + c];
        }
        hist[d * nb + block] = total;
    }
}

@compute @workgroup_size(WG)
fn scan_reduce(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let s = group_index(wid, nwg);
    let len = scan_len();
    if s * SCAN_BLOCK >= len {
        return;
    }
    var acc = 0u;
    for (var j = 0u; j < SCAN_ITEMS; j++) {
        let i = s * SCAN_BLOCK + j * WG + t;
        if i < len {
            acc += hist[i];
        }
    }
    // The tile's sum: the total of the workgroup's scan (workgroup.wgsl).
    let total = workgroup_scan(t, acc).y;
    if t == 0u {
        partials[s] = total;
    }
}

// One workgroup: exclusive scan of the tile sums in place, 256 at a time with a carry.
@compute @workgroup_size(WG)
fn scan_partials(@builtin(local_invocation_index) t: u32) {
    let tiles = (scan_len() + SCAN_BLOCK - 1u) / SCAN_BLOCK;
    var carry = 0u;
    for (var base = 0u; base < tiles; base += WG) {
        let i = base + t;
        var v = 0u;
        if i < tiles {
            v = partials[i];
        }
        let ex = workgroup_scan(t, v);
        if i < tiles {
            partials[i] = carry + ex.x;
        }
        carry += ex.y;
        // Everyone has read the scan before the next round overwrites it.
        workgroupBarrier();
    }
}

@compute @workgroup_size(WG)
fn scan_down(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let s = group_index(wid, nwg);
    let len = scan_len();
    if s * SCAN_BLOCK >= len {
        return;
    }
    let base = s * SCAN_BLOCK;
    // Coalesced load into workgroup memory, then each thread scans SCAN_ITEMS
    // consecutive entries serially: fewer steps in the barrier-bound workgroup scan.
    for (var j = 0u; j < SCAN_ITEMS; j++) {
        let i = base + j * WG + t;
        var v = 0u;
        if i < len {
            v = hist[i];
        }
        tile[j * WG + t] = v;
    }
    workgroupBarrier();
    let own = t * SCAN_ITEMS;
    var sum = 0u;
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        sum += tile[own + k];
    }
    var run = partials[s] + workgroup_scan(t, sum).x;
    for (var k = 0u; k < SCAN_ITEMS; k++) {
        let v = tile[own + k];
        tile[own + k] = run;
        run += v;
    }
    workgroupBarrier();
    for (var j = 0u; j < SCAN_ITEMS; j++) {
        let i = base + j * WG + t;
        if i < len {
            hist[i] = tile[j * WG + t];
        }
    }
}

// Counts again, turns every digit's row of counters into output slots, and walks
// each run in order writing pairs to their digit's next slot.
@compute @workgroup_size(COLS)
fn scatter(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let block = group_index(wid, nwg);
    let n = element_count();
    let nb = block_count(n);
    if block >= nb {
        return;
    }
    let base = block * BLOCK;
    count_columns(t, base, n);
    for (var d = t; d < radix(); d += COLS) {
        var slot = hist[d * nb + block];
        for (var c = 0u; c < COLS; c++) {
            let v = counters[d * COLS + c];
            counters[d * COLS + c] = slot;
            slot += v;
        }
    }
    workgroupBarrier();
    let first = base + t * RUN;
    let last = min(first + RUN, n);
    for (var i = first; i < last; i++) {
        let key = keys_in[i];
        let c = digit_of(key) * COLS + t;
        let dst = counters[c];
        counters[c] = dst + 1u;
        keys_out[dst] = key;
        vals_out[dst] = vals_in[i];
    }
}
