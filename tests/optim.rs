//! One optimisation step on lavapipe against the CPU oracles (loss, regularisers,
//! rasteriser gradients, Adam), the regulariser oracle against finite differences,
//! and the loss mask. No adapter is a failure.
#![cfg(not(target_arch = "wasm32"))]

use rogs::gpu::GpuContext;
use rogs::loss::regularise::{regularise, RegWeights};
use rogs::optim::check::{compare_pose_grad, compare_step};

/// Selective and dense Adam, with every moment in one binding, and in windows of 3
/// blocks of 256 surfels (3 `adam` passes, the last one partial, as a model larger
/// than one binding takes); step 2 sized from step 1's pair count, and with too small
/// a margin, so that its pairs overflow and it runs again.
#[test]
fn gpu_step_matches_the_oracles() {
    use rogs::optim::AdamScope;
    for mode in [AdamScope::Selective, AdamScope::Dense] {
        // The fourth case weighs the RGB term robustly (a drive without labels' loss);
        // the fifth renders the view with a frame gain on top of its camera's exposure;
        // in the last, step 1 measures the view's gain from its own forward pass.
        for (window, margin, overflows, robust_c, gain) in [
            (None, None, 0, 0.0, Some(0.0)),
            (Some(3), None, 0, 0.0, Some(0.0)),
            (None, Some(0.4), 1, 0.0, Some(0.0)),
            (None, None, 0, 0.2, Some(0.0)),
            (None, None, 0, 0.0, Some(0.3)),
            (None, Some(0.4), 1, 0.0, None),
        ] {
            let ctx = GpuContext::new_blocking()
                .unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"));
            let d = pollster::block_on(compare_step(ctx, mode, window, margin, robust_c, gain))
                .expect("gpu step");
            assert_eq!(d.pair_overflows, [0, overflows], "{d:#?}");
            assert_eq!(d.decayed > 0, mode != AdamScope::Dense, "{d:#?}");
            assert_eq!(d.gain.is_some(), gain.is_none(), "{d:#?}");
            check_step(d);
        }
    }
}

/// The pose gradient `pose_grad` reduces on the GPU against the CPU chain.
#[test]
fn gpu_pose_gradient_matches_the_oracle() {
    let ctx =
        GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"));
    let (gpu, cpu) = pollster::block_on(compare_pose_grad(ctx)).expect("gpu step");
    check_pose_grad(gpu, cpu);
}

pub fn check_pose_grad(gpu: [f64; 6], cpu: [f64; 6]) {
    eprintln!("pose gradient GPU {gpu:?}\n              CPU {cpu:?}");
    let scale = cpu.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0, "the pose gradient must not vanish");
    for (k, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert!(
            (g - c).abs() <= 2e-3 * scale,
            "axis {k}: GPU {g} vs CPU {c} (largest {scale})"
        );
    }
}

fn check_step(d: rogs::optim::check::StepDifferences) {
    eprintln!("{d:#?}");
    for (name, gpu, cpu) in &d.losses {
        assert!(*cpu > 0.0, "{name}: the test should exercise this term");
        assert!(
            (gpu - cpu).abs() <= 1e-4 * cpu.abs(),
            "{name}: GPU {gpu} vs CPU {cpu}"
        );
    }
    for (name, r) in &d.grads {
        assert!(
            *r < 2e-3,
            "{name}: gradient differs by {r} of its largest value"
        );
    }
    assert!(d.moved > 1e-3, "the step should change the parameters");
    assert_eq!(d.applied, [true; 4], "every update is finite");
    assert!(d.params.iter().all(|&p| p < 1e-5), "Adam: {:?}", d.params);
    assert!(d.exposure < 1e-6, "exposure Adam differs by {}", d.exposure);
    check_gain(d.gain);
}

/// A gain measured in the step (`frame_gain.wgsl`) against its oracle: the target
/// is about half as bright as the render, so the gain is far from 0 and unclamped.
pub fn check_gain(gain: Option<(f32, f32, u32)>) {
    if let Some((gpu, cpu, pixels)) = gain {
        assert!(pixels >= 64, "the gain counted {pixels} pixels");
        assert!(
            cpu < -0.2 && cpu > -0.99,
            "the test's gain should be well inside (-1, 0): {cpu}"
        );
        assert!((gpu - cpu).abs() < 1e-4, "gain: GPU {gpu} vs CPU {cpu}");
    }
}

#[test]
fn regulariser_gradient_matches_finite_differences() {
    use rogs::loss::regularise::RegData;
    let n: usize = 12;
    let z: Vec<f32> = (0..n).map(|i| (i as f32 * 0.37).sin() * 0.2).collect();
    let mut adj_start = vec![0u32];
    let mut adj = Vec::new();
    for i in 0..n {
        for j in [i.wrapping_sub(1), i + 1, i + 4, i.wrapping_sub(4)] {
            if j < n {
                adj.push(j as u32);
            }
        }
        adj_start.push(adj.len() as u32);
    }
    let priors = (0..n)
        .map(|i| {
            [
                z[i] + 0.03 * (i as f32 - 5.0),
                0.5 + 0.04 * i as f32,
                z[i] - 0.02,
                (i % 2) as f32,
            ]
        })
        .collect();
    let d = RegData {
        edges: adj.len() / 2,
        adj_start,
        adj,
        priors,
        with_lidar: n / 2,
    };
    let w = RegWeights {
        smooth: 0.3,
        traj: 0.7,
        huber: 0.05,
        lidar: 0.5,
    };
    let total = |z: &[f32]| regularise(&d, &w, z).0.iter().sum::<f64>();
    let (_, g) = regularise(&d, &w, &z);
    for i in 0..n {
        let h = 1e-3f32;
        let (mut a, mut b) = (z.clone(), z.clone());
        a[i] += h;
        b[i] -= h;
        let fd = (total(&a) - total(&b)) / (2.0 * h as f64);
        let err = (fd - g[i] as f64).abs() / fd.abs().max(1e-3);
        assert!(
            err < 1e-2,
            "surfel {i}: analytic {} vs finite difference {fd}",
            g[i]
        );
    }
}

/// The candidate lists assume surfels stay within a margin of the positions the host
/// knows; a surfel that leaves it is noticed on the GPU and the positions are re-read.
#[test]
fn a_surfel_the_candidate_list_missed_is_found_and_listed_next_time() {
    use rogs::optim::AdamScope;
    for mode in [AdamScope::Selective, AdamScope::Dense] {
        let ctx =
            GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"));
        let d = pollster::block_on(rogs::optim::check::missed_candidate(ctx, mode)).expect("steps");
        eprintln!("{mode:?}: {d:?}");
        assert_eq!(d.refreshes, [1, 1], "refreshed once, then listed");
        assert!(mode == AdamScope::Selective || d.host_z[0] == 50.0);
        assert_eq!(
            d.host_z[1], d.gpu_z,
            "the host now knows where the surfel is"
        );
    }
}

/// What a model must fit: 16 bytes per surfel (rotations, priors) in one storage
/// binding. The logits (4 bytes per class) are bound in windows, so a model whose
/// logits alone exceed the binding is accepted, and one past the 16-byte bound is
/// refused with advice that names the way out.
#[test]
fn models_whose_logits_exceed_one_binding_fit_and_larger_ones_are_refused() {
    use rogs::optim::train::check_fits;
    let ctx =
        GpuContext::new_blocking().unwrap_or_else(|e| panic!("GPU tests need an adapter: {e}"));
    let limit = ctx.limits.max_storage_buffer_binding_size;
    let classes = 9;
    let logits_over = (limit / (4 * classes as u64) + 1) as usize;
    let over = (limit / 16 + 1) as usize;
    assert!(
        check_fits(&ctx, logits_over, classes, 4 * logits_over).is_ok(),
        "{logits_over} surfels' logits exceed the binding, but they are windowed"
    );
    let e = check_fits(&ctx, over, classes, 4 * over).expect_err("over 16 bytes per surfel");
    let msg = e.to_string();
    assert!(
        msg.contains("one GPU binding") && msg.contains("--resolution"),
        "{msg}"
    );
    // Neighbour lists count too: 4 bytes per entry.
    let adj = (limit / 4 + 1) as usize;
    assert!(check_fits(&ctx, 1000, classes, adj).is_err());
}
