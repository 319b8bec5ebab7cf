//! radix_sort: one pass of a stable LSD radix sort of (u32 key, u32 value) pairs.
//!
//! The host runs ceil(key_bits / 8) passes, 8 bits per pass, ping-ponging between two
//! key/value buffer pairs. A pass is five dispatches, all reading the element count
//! from `count_buf[0]` on the GPU (clamped to the bound buffers), so a producer kernel
//! can write the count and the sort can follow in the same command buffer with no
//! read-back; dispatches are sized for a host-known upper bound and the blocks past
//! the GPU count return at once.
//!
//! 1. `count`: each block of BLOCK = 256 threads x 16 keys builds a 256-bin digit
//!    histogram with workgroup atomics and stores it digit-major,
//!    `hist[digit * blocks + block]`, so that one exclusive scan of `hist` gives every
//!    (digit, block) its first output slot: all smaller digits, then the same digit in
//!    earlier blocks. That order is what makes the sort stable across blocks.
//! 2. `scan_reduce`, `scan_partials`, `scan_down`: a three-level exclusive scan of
//!    `hist` (tiles of 4096 summed, the tile sums scanned by one looping workgroup, the
//!    tiles scanned with their offsets). The single-workgroup level loops, so there is
//!    no size limit: 32M keys give 2M histogram entries and only 512 tile sums.
//! 3. `scatter`: each block walks its keys in chunks of 256, one key per thread in
//!    input order, and ranks every key among the keys of the chunk with the same digit
//!    and a lower thread index. No subgroup operations: every thread sets its bit in a
//!    256-bit mask of its digit (workgroup `atomicOr`), and its rank is the popcount of
//!    the lower bits of that mask. The last thread of each digit then advances the
//!    digit's running offset and clears the mask. Ranks within a chunk, chunks in
//!    order and blocks in scan order keep equal digits in input order: stable.
//!
//! Workgroups are 256 invocations, the most browsers guarantee (SwiftShader has no
//! more); the 2D grid (linearised with `num_workgroups`) lifts the 65535-groups-per-
//! dimension limit. Workgroup memory stays under 17 KiB per entry point (32 KiB is the
//! WebGPU minimum). Key bits above the pass's `shift + bits` are ignored, so keys only
//! need to be meaningful in their low `key_bits` bits.

const WG: u32 = 256u;
// Keys per thread in `count` and `scatter`: larger blocks mean a smaller histogram to
// scan, smaller ones more parallel blocks. 16 keeps 4M keys at 1024 blocks.
const ITEMS: u32 = 16u;
const BLOCK: u32 = 4096u; // WG * ITEMS
const SCAN_ITEMS: u32 = 16u;
const SCAN_BLOCK: u32 = 4096u; // WG * SCAN_ITEMS
// 256 digits x 256 threads of a chunk, 32 threads per mask word.
const MASK_WORDS: u32 = 8u;

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

var<workgroup> counts: array<atomic<u32>, 256>;
var<workgroup> sums: array<u32, 256>;
var<workgroup> tile: array<u32, 4096>;
var<workgroup> match_bits: array<atomic<u32>, 2048>; // 256 digits x MASK_WORDS
var<workgroup> digit_base: array<u32, 256>;

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

// Exclusive scan of one value per thread (Hillis-Steele in `sums`); afterwards
// `sums[WG - 1]` holds the total until the next barrier-free write to `sums`.
fn workgroup_exclusive_scan(t: u32, v: u32) -> u32 {
    sums[t] = v;
    workgroupBarrier();
    for (var off = 1u; off < WG; off <<= 1u) {
        var x = 0u;
        if t >= off {
            x = sums[t - off];
        }
        workgroupBarrier();
        sums[t] += x;
        workgroupBarrier();
    }
    return sums[t] - v;
}

@compute @workgroup_size(256)
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
    atomicStore(&counts[t], 0u);
    workgroupBarrier();
    let base = block * BLOCK;
    for (var j = 0u; j < ITEMS; j++) {
        // Thread-consecutive indices: coalesced loads on real GPUs.
        let i = base + j * WG + t;
        if i < n {
            atomicAdd(&counts[digit_of(keys_in[i])], 1u);
        }
    }
    workgroupBarrier();
    if t < radix() {
        hist[t * nb + block] = atomicLoad(&counts[t]);
    }
}

@compute @workgroup_size(256)
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
    sums[t] = acc;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride >>= 1u) {
        if t < stride {
            sums[t] += sums[t + stride];
        }
        workgroupBarrier();
    }
    if t == 0u {
        partials[s] = sums[0];
    }
}

// One workgroup: exclusive scan of the tile sums in place, 256 at a time with a carry.
@compute @workgroup_size(256)
fn scan_partials(@builtin(local_invocation_index) t: u32) {
    let tiles = (scan_len() + SCAN_BLOCK - 1u) / SCAN_BLOCK;
    var carry = 0u;
    for (var base = 0u; base < tiles; base += WG) {
        let i = base + t;
        var v = 0u;
        if i < tiles {
            v = partials[i];
        }
        let ex = workgroup_exclusive_scan(t, v);
        if i < tiles {
            partials[i] = carry + ex;
        }
        carry += sums[WG - 1u];
        // Everyone has read the total before the next round overwrites `sums`.
        workgroupBarrier();
    }
}

@compute @workgroup_size(256)
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
    // Coalesced load into workgroup memory, then each thread scans 16 consecutive
    // entries serially: 16x fewer steps in the barrier-bound workgroup scan.
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
    var run = partials[s] + workgroup_exclusive_scan(t, sum);
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

@compute @workgroup_size(256)
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
    if t < radix() {
        digit_base[t] = hist[t * nb + block];
    }
    for (var k = 0u; k < MASK_WORDS; k++) {
        atomicStore(&match_bits[t * MASK_WORDS + k], 0u);
    }
    workgroupBarrier();
    let word = t >> 5u;
    let bit = 1u << (t & 31u);
    let base = block * BLOCK;
    for (var j = 0u; j < ITEMS; j++) {
        let first = base + j * WG;
        // Uniform: the whole workgroup leaves together, so the barriers stay uniform.
        if first >= n {
            break;
        }
        let i = first + t;
        let valid = i < n;
        var key = 0u;
        var d = 0u;
        if valid {
            key = keys_in[i];
            d = digit_of(key);
            atomicOr(&match_bits[d * MASK_WORDS + word], bit);
        }
        workgroupBarrier();
        var total = 0u;
        var before = 0u;
        if valid {
            for (var w = 0u; w < MASK_WORDS; w++) {
                let m = atomicLoad(&match_bits[d * MASK_WORDS + w]);
                let c = countOneBits(m);
                total += c;
                if w < word {
                    before += c;
                } else if w == word {
                    before += countOneBits(m & (bit - 1u));
                }
            }
            let dst = digit_base[d] + before;
            keys_out[dst] = key;
            vals_out[dst] = vals_in[i];
        }
        // All ranks are taken before the offsets move and the masks are cleared.
        workgroupBarrier();
        if valid && before + 1u == total {
            digit_base[d] += total;
            for (var w = 0u; w < MASK_WORDS; w++) {
                atomicStore(&match_bits[d * MASK_WORDS + w], 0u);
            }
        }
        workgroupBarrier();
    }
}
