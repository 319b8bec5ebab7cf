//! The rasteriser kernels against the CPU oracle, natively on lavapipe, with both
//! gradient-accumulation strategies. No adapter is a failure.
#![cfg(not(target_arch = "wasm32"))]

use rogs::gpu::{AccumStrategy, GpuContext};
use rogs::render::check::compare;

fn ctx() -> GpuContext {
    GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"))
}

fn run(strategy: AccumStrategy, subgroups: bool) {
    run_windows(strategy, subgroups, None);
}

fn run_windows(strategy: AccumStrategy, subgroups: bool, attr_window: Option<u32>) {
    let c = ctx();
    if subgroups {
        assert!(
            c.report.subgroups,
            "lavapipe has subgroups: this path must be tested"
        );
    }
    let d = pollster::block_on(compare(&c, strategy, subgroups, attr_window)).expect("gpu");
    eprintln!("{strategy:?}, subgroups {subgroups}, windows {attr_window:?}: {d:?}");
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
fn gpu_forward_and_backward_match_the_oracle_with_logits_gathered_in_windows() {
    // The ~2k-surfel scene in windows of 64 surfels: 32 gather passes, each binding one
    // range of the model's colours and logits, as a model whose logits exceed the
    // storage binding is rendered (3.7 M surfels with 9 classes on lavapipe).
    run_windows(AccumStrategy::NativeF32, true, Some(64));
    run_windows(AccumStrategy::CasU32, false, Some(192));
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
    let r = pollster::block_on(GpuRasterizer::new(&c, p.channels as u32)).expect("pipelines");
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

/// The map's view (the alpha-weighted mean of a pixel's surfels, whatever their
/// order) on the GPU equals the oracle's.
#[test]
fn gpu_average_compositing_matches_the_oracle() {
    let c = ctx();
    let d = pollster::block_on(rogs::render::check::compare_forward_average(&c)).expect("gpu");
    assert!(d < 1e-4, "forward max abs error {d}");
}

/// The BEV lists per chunk only the surfels that can reach it (so that a large model
/// needs no per-view buffer of its own size); the image must be the one every surfel
/// listed for every chunk gives.
#[test]
fn bev_chunks_listing_their_own_surfels_render_the_same_map() {
    use rogs::bev::{render, BevGeometry, CHUNK};
    use rogs::render::gpu::GpuRasterizer;
    let c = ctx();
    // 40 m × 30 m at 0.25 m: 3 × 3 chunks of 256 px at 5 cm, surfels on every border.
    let p = rogs::render::scene::road_patch(160, 120, 0.25, -20.0, -15.0, 3, 7).cast::<f32>();
    let g = BevGeometry::around(p.pos.iter().map(|q| [q[0] as f64, q[1] as f64]), 0.05, 0.5);
    assert!(
        g.width > 2 * CHUNK && g.height > 2 * CHUNK,
        "{} × {}",
        g.width,
        g.height
    );
    let raster = pollster::block_on(GpuRasterizer::new(&c, p.channels as u32)).expect("rasteriser");
    let gp = GpuRasterizer::upload(&c, &p);
    let bev = |per_chunk| {
        pollster::block_on(render(
            &c,
            &raster,
            &gp,
            &p,
            &g,
            [0.0; 3],
            &mut |_, _| {},
            per_chunk,
        ))
        .expect("bev")
    };
    let (listed, all) = (bev(true), bev(false));
    let covered = all.alpha.iter().filter(|&&a| a > 0.5).count();
    assert!(
        covered > all.alpha.len() / 2,
        "the map covers {covered} pixels"
    );
    let diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .filter(|(x, y)| !(x.is_nan() && y.is_nan()))
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    assert!(diff(&listed.alpha, &all.alpha) < 1e-5);
    assert!(diff(&listed.rgb, &all.rgb) < 1e-5);
    assert!(diff(&listed.logits, &all.logits) < 1e-5);
    assert!(diff(&listed.elevation, &all.elevation) < 1e-4);
}
