//! GPU smoke tests on the native adapter (lavapipe in CI). No adapter is a failure.
#![cfg(not(target_arch = "wasm32"))]

use rogs::gpu::scatter_add::{scatter_add_cpu, scatter_add_gpu};
use rogs::gpu::{AccumStrategy, GpuContext};
use rogs::render::probe::{blobs, dense_blend_cpu, DenseBlend};

fn ctx() -> GpuContext {
    match GpuContext::new_blocking() {
        Ok(c) => c,
        Err(e) => panic!("GPU tests need an adapter: {e}"),
    }
}

fn data(n: usize, bins: u32) -> (Vec<u32>, Vec<f32>) {
    // Squaring a uniform variate skews the bins: the first ones receive most of the
    // adds, the heavy contention a gradient buffer sees.
    let index = (0..n as u32)
        .map(|i| {
            let u = ((i.wrapping_mul(2654435761) >> 8) % 10_000) as f32 / 10_000.0;
            ((u * u * bins as f32) as u32).min(bins - 1)
        })
        .collect();
    let values = (0..n)
        .map(|i| ((i * 37 % 101) as f32 - 50.0) / 64.0)
        .collect();
    (index, values)
}

fn check(strategy: AccumStrategy) {
    let c = ctx();
    // More than 65535 workgroups of 256 exercise the 2D dispatch.
    let n = 65536 * 256 + 1000;
    let bins = 977;
    let (index, values) = data(n, bins);
    let gpu = pollster::block_on(scatter_add_gpu(
        &c,
        strategy,
        bins as usize,
        &index,
        &values,
    ))
    .expect("gpu");
    let cpu = scatter_add_cpu(bins as usize, &index, &values);
    let max_mag = cpu.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(max_mag > 10.0, "test data should give large sums");
    for (b, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        // f32 sums of ~17k values: order-dependent rounding, bounded relative to the magnitude.
        assert!((g - c).abs() <= 1e-3 * max_mag, "bin {b}: gpu {g} cpu {c}");
    }
}

#[test]
fn adapter_report_is_complete() {
    let c = ctx();
    assert!(!c.report.name.is_empty());
    assert!(c.report.max_storage_buffer_binding_size >= 128 << 20);
    assert!(c.report.max_compute_invocations_per_workgroup >= 256);
}

#[test]
fn scatter_add_cas_matches_cpu() {
    check(AccumStrategy::CasU32);
}

#[test]
fn scatter_add_native_atomics_match_cpu_where_available() {
    let c = ctx();
    if c.report.accumulation != AccumStrategy::NativeF32 {
        // The report must then say why: the feature is missing.
        assert!(!c.features.contains(wgpu::Features::SHADER_FLOAT32_ATOMIC));
        return;
    }
    check(AccumStrategy::NativeF32);
}

#[test]
fn the_platform_probe_matches_its_oracle() {
    let c = ctx();
    // An image size that is not a multiple of the 8×8 workgroup.
    let (w, h) = (37, 21);
    let list = blobs(w, h, 48);
    let gpu = pollster::block_on(DenseBlend::new(&c, w, h, &list).run(&c)).expect("gpu");
    let cpu = dense_blend_cpu(w, h, &list);
    assert_eq!(gpu.len(), cpu.len());
    // The blend covers the image: little transmittance is left anywhere.
    assert!(
        cpu.chunks(4).all(|p| p[3] < 0.9),
        "the probe's blobs cover the image"
    );
    for (i, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert!((g - c).abs() <= 1e-4, "value {i}: gpu {g} cpu {c}");
    }
}

/// `partial_sums` (the loss's and the regularisers' sums) against its oracle: strides
/// 2 and 3, a count that leaves the last run partial, and the guard raised by a NaN
/// only when asked for.
#[test]
fn partial_sums_match_their_oracle() {
    use rogs::gpu::partial_sums::{partial_sums_cpu, partial_sums_gpu};
    let c = ctx();
    for stride in [2u32, 3] {
        let n = 256 * 5 + 37;
        let values: Vec<f32> = (0..n * stride as usize)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) / 64.0)
            .collect();
        let (gpu, word) =
            pollster::block_on(partial_sums_gpu(&c, &values, stride, true)).expect("gpu");
        let cpu = partial_sums_cpu(&values, stride as usize);
        assert_eq!(gpu.len(), cpu.len(), "stride {stride}: 6 runs");
        assert_eq!(cpu.len(), 6 * stride as usize);
        for (i, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
            assert!(
                (g - c).abs() <= 1e-3,
                "stride {stride}, sum {i}: gpu {g} cpu {c}"
            );
        }
        assert_eq!(word, 0, "usable sums raise nothing");
        let mut bad = values.clone();
        bad[stride as usize * 300 + 1] = f32::NAN;
        for guard in [true, false] {
            let (_, word) =
                pollster::block_on(partial_sums_gpu(&c, &bad, stride, guard)).expect("gpu");
            assert_eq!(word, guard as u32, "stride {stride}, guard {guard}");
        }
    }
}
