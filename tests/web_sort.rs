//! The GPU radix sort against its CPU oracle in a browser (headless Chromium, WebGPU on
//! SwiftShader), run with `wasm-pack test --headless --chrome -- --test web_sort`.
#![cfg(target_arch = "wasm32")]

use rogs::gpu::radix_sort::{sort_pairs_cpu, RadixSorter};
use rogs::gpu::GpuContext;
use wasm_bindgen_test::*;

wasm_bindgen_test_configure!(run_in_browser);

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

#[wasm_bindgen_test]
async fn radix_sort_matches_cpu_in_the_browser() {
    let ctx = match GpuContext::new().await {
        Ok(c) => c,
        Err(e) => panic!("WebGPU adapter required: {e}"),
    };
    let sorter = RadixSorter::new(&ctx).await.expect("pipelines");
    let keys = random(100_003, 29);
    // Values are the input positions: exact equality also checks stability.
    let values: Vec<u32> = (0..keys.len() as u32).collect();
    // 32 bits (4 passes), and 20 bits with random high bits that must be ignored.
    for key_bits in [32, 20] {
        let gpu = sorter
            .sort(&ctx, &keys, &values, key_bits)
            .await
            .expect("gpu sort");
        let cpu = sort_pairs_cpu(&keys, &values, key_bits);
        assert!(gpu == cpu, "key_bits {key_bits}: GPU and CPU orders differ");
    }
    // Few distinct keys: long runs of equal digits.
    let few: Vec<u32> = keys.iter().map(|k| k % 3 * 0x0101_0101).collect();
    let gpu = sorter
        .sort(&ctx, &few, &values, 32)
        .await
        .expect("gpu sort");
    assert!(
        gpu == sort_pairs_cpu(&few, &values, 32),
        "few distinct keys"
    );
}
