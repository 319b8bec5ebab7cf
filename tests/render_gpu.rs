//! The rasteriser kernels against the CPU oracle, natively on lavapipe, with both
//! gradient-accumulation strategies. No adapter is a failure.
#![cfg(not(target_arch = "wasm32"))]

use rogs::gpu::{AccumStrategy, GpuContext};
use rogs::render::check::compare;

fn ctx() -> GpuContext {
    GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"))
}

fn run(strategy: AccumStrategy, subgroups: bool) {
    let c = ctx();
    if subgroups {
        assert!(
            c.report.subgroups,
            "lavapipe has subgroups: this path must be tested"
        );
    }
    let d = pollster::block_on(compare(&c, strategy, subgroups)).expect("gpu");
    eprintln!("{strategy:?}, subgroups {subgroups}: {d:?}");
    assert_eq!(
        d.pairs.0 as usize, d.pairs.1,
        "surfel-tile pair counts differ"
    );
    assert!(d.pairs.1 > 2000, "the scene should produce many pairs");
    assert!(d.forward < 1e-4, "forward max abs error {}", d.forward);
    for (name, rel) in &d.grads {
        assert!(
            *rel < 2e-3,
            "{name}: GPU vs CPU gradient differs by {rel} of its largest value"
        );
    }
}

#[test]
fn gpu_forward_and_backward_match_the_oracle_with_cas_accumulation() {
    run(AccumStrategy::CasU32, true);
}

#[test]
fn gpu_forward_and_backward_match_the_oracle_with_native_atomics() {
    let c = ctx();
    assert_eq!(
        c.report.accumulation,
        AccumStrategy::NativeF32,
        "lavapipe has f32 atomics"
    );
    run(AccumStrategy::NativeF32, true);
}

#[test]
fn gpu_backward_matches_the_oracle_without_subgroup_reduction() {
    run(AccumStrategy::NativeF32, false);
    run(AccumStrategy::CasU32, false);
}
