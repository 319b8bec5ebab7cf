//! GPU radix sort against its CPU oracle on the native adapter (lavapipe in CI). Exact
//! equality of keys and values checks stability too. No adapter is a failure.
#![cfg(not(target_arch = "wasm32"))]

use rogs::gpu::radix_sort::{sort_pairs, sort_pairs_cpu, RadixSorter, SortPairs, SortedIn};
use rogs::gpu::readback::read_bytes;
use rogs::gpu::GpuContext;
use wgpu::util::DeviceExt;

fn ctx() -> GpuContext {
    match GpuContext::new_blocking() {
        Ok(c) => c,
        Err(e) => panic!("GPU tests need an adapter: {e}"),
    }
}

fn sorter(c: &GpuContext) -> RadixSorter {
    pollster::block_on(RadixSorter::new(c)).expect("pipelines")
}

/// Deterministic pseudo-random u32s (xorshift64*).
fn random(n: usize, seed: u64) -> Vec<u32> {
    let mut s = seed | 1;
    (0..n)
        .map(|_| {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            (s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 32) as u32
        })
        .collect()
}

fn check(c: &GpuContext, s: &RadixSorter, keys: &[u32], key_bits: u32) {
    // Values are the input positions: any instability shows as a value mismatch.
    let values: Vec<u32> = (0..keys.len() as u32).collect();
    let (gk, gv) = pollster::block_on(s.sort(c, keys, &values, key_bits)).expect("gpu sort");
    let (ck, cv) = sort_pairs_cpu(keys, &values, key_bits);
    assert_eq!(gk.len(), ck.len(), "n {} bits {key_bits}", keys.len());
    if let Some(i) = (0..ck.len()).find(|&i| gk[i] != ck[i] || gv[i] != cv[i]) {
        panic!(
            "n {} bits {key_bits}: first mismatch at {i}: gpu ({}, {}) cpu ({}, {})",
            keys.len(),
            gk[i],
            gv[i],
            ck[i],
            cv[i]
        );
    }
}

#[test]
fn sizes_around_the_block_match_cpu() {
    let c = ctx();
    let s = sorter(&c);
    for n in [0, 1, 2, 255, 256, 257, 4095, 4096, 4097, 100_003] {
        check(&c, &s, &random(n, n as u64 + 7), 32);
    }
    // The convenience entry point, with its own pipelines, on a small case.
    let keys = random(1000, 3);
    let values: Vec<u32> = random(1000, 4);
    let gpu = pollster::block_on(sort_pairs(&c, &keys, &values, 32)).expect("sort_pairs");
    assert_eq!(gpu, sort_pairs_cpu(&keys, &values, 32));
}

#[test]
fn two_million_random_keys_match_cpu() {
    let c = ctx();
    let s = sorter(&c);
    check(&c, &s, &random(2_000_003, 11), 32);
}

#[test]
fn few_distinct_keys_stay_in_input_order() {
    let c = ctx();
    let s = sorter(&c);
    // 5 distinct keys spread over all four bytes: every pass moves long runs of equal
    // digits, across chunks and blocks.
    let table = [0xdead_beef, 7, 0x0100_0000, 0xdead_beee, 0];
    let keys: Vec<u32> = random(300_000, 5)
        .iter()
        .map(|r| table[(r % 5) as usize])
        .collect();
    check(&c, &s, &keys, 32);
    // All keys equal: the output is the input.
    check(&c, &s, &vec![42; 70_000], 32);
}

#[test]
fn short_keys_ignore_the_bits_above_key_bits() {
    let c = ctx();
    let s = sorter(&c);
    // Random high bits: the sort must order by the low bits only and keep the high bits
    // in the output keys.
    let keys = random(150_001, 13);
    for bits in [20, 12, 9, 8, 3, 1, 0] {
        check(&c, &s, &keys, bits);
    }
    assert_eq!(rogs::gpu::radix_sort::passes(20), 3);
}

#[test]
fn two_dimensional_grids_match_cpu() {
    let mut c = ctx();
    // A tiny per-dimension limit forces 2D grids with spare workgroups (55 blocks in a
    // 3x19 grid, 7 scan tiles in 3x3), which real limits only need past 500M keys.
    c.limits.max_compute_workgroups_per_dimension = 3;
    let s = sorter(&c);
    check(&c, &s, &random(450_001, 17), 32);
    check(&c, &s, &random(450_001, 19), 13);
}

/// Sorts with the count in a GPU buffer, as the rasteriser will.
fn sort_with_gpu_count(
    c: &GpuContext,
    s: &RadixSorter,
    keys: &[u32],
    gpu_count: u32,
    key_bits: u32,
) -> (Vec<u32>, Vec<u32>) {
    let usage =
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
    let init = |data: &[u32]| {
        c.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: None,
                contents: bytemuck::cast_slice(data),
                usage,
            })
    };
    let values: Vec<u32> = (0..keys.len() as u32).collect();
    let (ka, va) = (init(keys), init(&values));
    let (kb, vb) = (init(keys), init(&values));
    let count = init(&[gpu_count]);
    let max_count = keys.len() as u32;
    let scratch = s.scratch(c, max_count);
    let mut enc = c.device.create_command_encoder(&Default::default());
    let pairs = SortPairs {
        keys_a: &ka,
        values_a: &va,
        keys_b: &kb,
        values_b: &vb,
        count: &count,
    };
    let sorted = s
        .encode(c, &mut enc, &pairs, &scratch, max_count, key_bits)
        .expect("encode");
    c.queue.submit([enc.finish()]);
    let (k, v) = match sorted {
        SortedIn::A => (&ka, &va),
        SortedIn::B => (&kb, &vb),
    };
    let bytes = 4 * max_count as u64;
    let k = pollster::block_on(read_bytes(c, k, bytes)).expect("keys");
    let v = pollster::block_on(read_bytes(c, v, bytes)).expect("values");
    (
        bytemuck::pod_collect_to_vec(&k),
        bytemuck::pod_collect_to_vec(&v),
    )
}

#[test]
fn count_is_read_from_the_gpu_and_clamped_to_capacity() {
    let c = ctx();
    let s = sorter(&c);
    let keys = random(10_000, 23);
    let values: Vec<u32> = (0..10_000).collect();
    for (gpu_count, bits) in [(3001u32, 32u32), (3001, 24), (0, 32), (10_000, 32)] {
        let (gk, gv) = sort_with_gpu_count(&c, &s, &keys, gpu_count, bits);
        let n = gpu_count as usize;
        let (ck, cv) = sort_pairs_cpu(&keys[..n], &values[..n], bits);
        assert_eq!(&gk[..n], &ck[..], "count {gpu_count} bits {bits}");
        assert_eq!(&gv[..n], &cv[..], "count {gpu_count} bits {bits}");
    }
    // A count past the capacity sorts the capacity, never beyond the buffers.
    let (gk, gv) = sort_with_gpu_count(&c, &s, &keys, 1 << 30, 32);
    assert_eq!((gk, gv), sort_pairs_cpu(&keys, &values, 32));
}

#[test]
fn bad_arguments_are_errors() {
    let c = ctx();
    let s = sorter(&c);
    let block = pollster::block_on;
    assert!(block(s.sort(&c, &[1, 2], &[1], 32)).is_err());
    assert!(block(s.sort(&c, &[1, 2], &[1, 2], 33)).is_err());
    // Scratch smaller than max_count.
    let buf = c.device.create_buffer(&wgpu::BufferDescriptor {
        label: None,
        size: 4096,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    let pairs = SortPairs {
        keys_a: &buf,
        values_a: &buf,
        keys_b: &buf,
        values_b: &buf,
        count: &buf,
    };
    let mut enc = c.device.create_command_encoder(&Default::default());
    let small = s.scratch(&c, 100);
    assert!(s.encode(&c, &mut enc, &pairs, &small, 1000, 32).is_err());
    // Buffers smaller than max_count.
    let big = s.scratch(&c, 5000);
    assert!(s.encode(&c, &mut enc, &pairs, &big, 5000, 32).is_err());
}

#[test]
fn bench_reports_a_throughput() {
    let c = ctx();
    let rate = pollster::block_on(rogs::gpu::radix_sort::bench_sort(&c, 1 << 16)).expect("bench");
    assert!(rate.is_finite() && rate > 0.0, "{rate}");
}

/// `cargo test --test gpu_sort -- --ignored --nocapture` prints the throughput.
#[test]
#[ignore = "benchmark: slow on a software adapter"]
fn bench_one_and_four_million() {
    let c = ctx();
    for n in [1u32 << 20, 1 << 22] {
        let rate = pollster::block_on(rogs::gpu::radix_sort::bench_sort(&c, n)).expect("bench");
        println!("radix sort {n} keys: {:.1} M keys/s", rate / 1e6);
    }
}
