//! The same GPU and bundle checks in a browser (headless Chromium, WebGPU on
//! SwiftShader), run with `wasm-pack test --headless --chrome`.
#![cfg(target_arch = "wasm32")]

use rogs::bundle::{example, write_zip, Bundle, Limits, Problem};
use rogs::gpu::scatter_add::{scatter_add_cpu, scatter_add_gpu};
use rogs::gpu::{AccumStrategy, GpuContext};
use rogs::render::probe::{blobs, dense_blend_cpu, DenseBlend};
use wasm_bindgen_test::*;

wasm_bindgen_test_configure!(run_in_browser);

#[wasm_bindgen_test]
async fn webgpu_adapter_found_and_scatter_add_matches_cpu() {
    let ctx = match GpuContext::new().await {
        Ok(c) => c,
        Err(e) => panic!("WebGPU adapter required: {e}"),
    };
    // Browsers have no float atomics: the CAS path must have been chosen.
    assert_eq!(ctx.report.accumulation, AccumStrategy::CasU32);
    let n = 200_000;
    let index: Vec<u32> = (0..n as u32)
        .map(|i| i.wrapping_mul(2654435761) % 331)
        .collect();
    let values: Vec<f32> = (0..n)
        .map(|i| ((i * 37 % 101) as f32 - 50.0) / 64.0)
        .collect();
    let gpu = scatter_add_gpu(&ctx, AccumStrategy::CasU32, 331, &index, &values)
        .await
        .expect("gpu");
    let cpu = scatter_add_cpu(331, &index, &values);
    let max_mag = cpu.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (b, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert!(
            (g - c).abs() <= 1e-3 * max_mag.max(1.0),
            "bin {b}: gpu {g} cpu {c}"
        );
    }
}

#[wasm_bindgen_test]
async fn the_platform_probe_matches_its_oracle_in_the_browser() {
    let ctx = match GpuContext::new().await {
        Ok(c) => c,
        Err(e) => panic!("WebGPU adapter required: {e}"),
    };
    let (w, h) = (37, 21);
    let list = blobs(w, h, 48);
    let gpu = DenseBlend::new(&ctx, w, h, &list)
        .run(&ctx)
        .await
        .expect("gpu");
    let cpu = dense_blend_cpu(w, h, &list);
    assert_eq!(gpu.len(), cpu.len());
    for (i, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert!((g - c).abs() <= 1e-4, "value {i}: gpu {g} cpu {c}");
    }
}

#[wasm_bindgen_test]
fn bundle_round_trip_and_named_error_in_wasm() {
    let (m, files) = example::tiny();
    let b = Bundle::from_zip_bytes(write_zip(&m, &files).expect("zip"), Limits::default())
        .expect("valid");
    assert_eq!(b.manifest, m);
    let mut files = files;
    files.retain(|(p, _)| p != "images/front/000001.png");
    let e = Bundle::from_zip_bytes(write_zip(&m, &files).expect("zip"), Limits::default())
        .err()
        .expect("invalid");
    assert!(
        matches!(&e.0[..], [Problem::MissingFile { field, .. }] if field == "frames[1].views[0].image")
    );
}

#[wasm_bindgen_test]
async fn rasteriser_matches_the_cpu_oracle_in_the_browser() {
    let ctx = match GpuContext::new().await {
        Ok(c) => c,
        Err(e) => panic!("WebGPU adapter required: {e}"),
    };
    // The per-pixel path always; the subgroup reduction too where the adapter has it
    // (headless Chromium 156 through wgpu 30 reports no subgroups).
    let mut paths = vec![false];
    if ctx.report.subgroups {
        paths.push(true);
    }
    web_sys::console::log_1(&format!("subgroup reduction tested: {}", ctx.report.subgroups).into());
    for subgroups in paths {
        // Colours and logits gathered in windows of 64 surfels, the path of a model
        // whose logits exceed one storage binding.
        let d = rogs::render::check::compare(&ctx, AccumStrategy::CasU32, subgroups, Some(64))
            .await
            .expect("gpu");
        assert_eq!(
            d.pairs.0 as usize, d.pairs.1,
            "surfel-tile pair counts differ"
        );
        assert!(d.pairs.1 > 2000);
        assert!(d.forward < 1e-4, "forward max abs error {}", d.forward);
        for (name, rel) in &d.grads {
            assert!(
                *rel < 2e-3,
                "{name} (subgroups {subgroups}): GPU vs CPU gradient differs by {rel}"
            );
        }
    }
    // Tile counts spanning several scan blocks (shaders/scan.wgsl).
    let d = rogs::render::check::compare_forward_large(&ctx)
        .await
        .expect("gpu");
    assert!(
        d.candidates > 4 * 2048 && d.pairs.0 as usize == d.pairs.1,
        "{d:?}"
    );
    assert!(d.forward < 1e-4, "forward max abs error {}", d.forward);
}

#[wasm_bindgen_test]
async fn optimisation_step_matches_the_oracles_in_the_browser() {
    // In 3 windows of moments (blocks of 256 surfels, the last partial): the model is
    // small, so one would do, but a large one takes this path; the page's full runs
    // take the single-window one. Step 2's pair buffers are too small, so it overflows
    // them once and runs again. Dense Adam (the default), its view with a frame gain
    // on top of its camera's exposure, and selective, whose step 1 measures the view's
    // gain from its own forward pass.
    for (mode, gain) in [
        (rogs::optim::AdamScope::Dense, Some(-0.2)),
        (rogs::optim::AdamScope::Selective, None),
    ] {
        let ctx = match GpuContext::new().await {
            Ok(c) => c,
            Err(e) => panic!("WebGPU adapter required: {e}"),
        };
        let d = rogs::optim::check::compare_step(ctx, mode, Some(3), Some(0.4), 0.2, gain)
            .await
            .expect("gpu step");
        assert_eq!(d.pair_overflows, [0, 1]);
        for (name, gpu, cpu) in &d.losses {
            assert!(
                *cpu > 0.0 && (gpu - cpu).abs() <= 1e-4 * cpu.abs(),
                "{mode:?} {name}: {gpu} vs {cpu}"
            );
        }
        for (name, rel) in &d.grads {
            assert!(
                *rel < 2e-3,
                "{mode:?} {name}: GPU vs CPU gradient differs by {rel}"
            );
        }
        assert!(d.moved > 1e-3);
        assert_eq!(d.applied, [true; 4], "every update is finite");
        assert_eq!(d.decayed > 0, mode == rogs::optim::AdamScope::Selective);
        assert!(
            d.params.iter().all(|&p| p < 1e-5),
            "{mode:?} Adam: {:?}",
            d.params
        );
        assert!(d.exposure < 1e-6);
        assert_eq!(d.gain.is_some(), gain.is_none());
        if let Some((gpu, cpu, pixels)) = d.gain {
            assert!(
                pixels >= 64 && cpu < -0.2 && cpu > -0.99,
                "{gpu} {cpu} {pixels}"
            );
            assert!((gpu - cpu).abs() < 1e-4, "gain: GPU {gpu} vs CPU {cpu}");
        }
    }
}

#[wasm_bindgen_test]
async fn pose_gradient_matches_the_oracle_in_the_browser() {
    let ctx = match GpuContext::new().await {
        Ok(c) => c,
        Err(e) => panic!("WebGPU adapter required: {e}"),
    };
    let (gpu, cpu) = rogs::optim::check::compare_pose_grad(ctx)
        .await
        .expect("gpu step");
    let scale = cpu.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "the pose gradient must not vanish");
    for (k, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert!(
            (g - c).abs() <= 2e-3 * scale,
            "axis {k}: GPU {g} vs CPU {c}"
        );
    }
}

#[wasm_bindgen_test]
async fn a_surfel_the_candidate_list_missed_is_found_in_the_browser() {
    let ctx = match GpuContext::new().await {
        Ok(c) => c,
        Err(e) => panic!("WebGPU adapter required: {e}"),
    };
    let d = rogs::optim::check::missed_candidate(ctx, rogs::optim::AdamScope::Selective)
        .await
        .expect("steps");
    assert_eq!(d.refreshes, [1, 1], "refreshed once, then listed: {d:?}");
    assert_eq!(
        d.host_z[1], d.gpu_z,
        "the host now knows where the surfel is"
    );
}
