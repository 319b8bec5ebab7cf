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

#[test]
fn gpu_timestamps_attribute_time_to_each_kernel() {
    use rogs::gpu::timing::PassTimer;
    use rogs::render::gpu::GpuRasterizer;
    let c = ctx();
    let (p, cam) = rogs::render::check::test_scene(3);
    let r = pollster::block_on(GpuRasterizer::new(&c)).expect("pipelines");
    let gp = GpuRasterizer::upload(&c, &p);
    let cull = rogs::render::CullConfig::default();
    let mut timer = PassTimer::install(&c).expect("lavapipe has TIMESTAMP_QUERY");
    pollster::block_on(r.forward(&c, &gp, &cam, &cull)).expect("forward");
    pollster::block_on(timer.collect(&c)).expect("collect");
    let got = timer.sorted();
    eprintln!("{got:?}");
    for kernel in ["project", "radix_sort", "rasterize"] {
        let (_, sec, passes) = got
            .iter()
            .find(|k| k.0 == kernel)
            .unwrap_or_else(|| panic!("{kernel} was not timed: {got:?}"));
        assert!(
            *passes >= 1 && *sec > 0.0 && *sec < 60.0,
            "{kernel}: {sec} s"
        );
    }
    assert!(!got.iter().any(|k| k.0 == "rasterize_backward"), "not run");
    drop(timer);
    pollster::block_on(r.forward(&c, &gp, &cam, &cull)).expect("forward without a timer");
}

/// 9 000 surfels in view, so the tile counts span five blocks of the scan (2 048
/// values each, shaders/scan.wgsl): the forward pass still equals the oracle.
#[test]
fn gpu_forward_matches_the_oracle_across_scan_blocks() {
    let c = ctx();
    let d = pollster::block_on(rogs::render::check::compare_forward_large(&c)).expect("gpu");
    assert!(d.candidates > 4 * 2048, "{} candidates", d.candidates);
    assert_eq!(d.pairs.0 as usize, d.pairs.1, "pair counts differ");
    assert!(d.forward < 1e-4, "forward max abs error {}", d.forward);
}
