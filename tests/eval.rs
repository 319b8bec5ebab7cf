//! Metrics: perfect against themselves, and equal to values computed by hand for
//! hand-made perturbations. Invalid pixels never count.
#![cfg(not(target_arch = "wasm32"))]

use rogs::eval::{
    elevation_datum, elevation_vs_points, elevation_vs_raster, error_stats, miou, paper_psnr, psnr,
    BevRaster,
};

/// 10×10 raster at 0.1 m: left half class 0 (grey 100), right half class 1 (white
/// 200), elevation 1.0 m; the last row is invalid.
fn raster() -> BevRaster {
    let mut r = BevRaster::empty([0.0, 1.0], 0.1, 10, 10);
    for row in 0..10 {
        for col in 0..10 {
            let right = col >= 5;
            r.rgb.put_pixel(
                col,
                row,
                image::Rgb(if right { [200; 3] } else { [100; 3] }),
            );
            r.class_ids.put_pixel(col, row, image::Luma([right as u8]));
            r.valid
                .put_pixel(col, row, image::Luma([if row == 9 { 0 } else { 255 }]));
        }
    }
    r.elevation.fill(1.0);
    r
}

#[test]
fn truth_against_itself_is_perfect() {
    let t = raster();
    assert_eq!(psnr(&t, &t), Some(f64::INFINITY));
    assert_eq!(miou(&t, &t, &[0, 1]), Some(1.0));
    let pts: Vec<[f64; 3]> = (0..9).map(|i| [0.05 + 0.1 * i as f64, 0.55, 1.0]).collect();
    let e = elevation_vs_raster(&pts, &t).unwrap();
    assert_eq!((e.rmse, e.mae, e.p95, e.count), (0.0, 0.0, 0.0, 9));
}

#[test]
fn psnr_of_a_perturbation_equals_hand_computation() {
    let t = raster();
    let mut p = raster();
    // One valid pixel off by 51 in every channel: MSE = (51/255)² · 3 / (90 · 3).
    p.rgb.put_pixel(2, 3, image::Rgb([151; 3]));
    // Invalid pixels do not count, however wrong.
    p.rgb.put_pixel(4, 9, image::Rgb([0; 3]));
    let mse = (0.2f64 * 0.2) / 90.0;
    let expected = -10.0 * mse.log10();
    assert!((psnr(&p, &t).unwrap() - expected).abs() < 1e-9);
    // Averaging masked zeros in (the original code's quirk) would give 100 pixels.
    let quirk = -10.0 * ((0.2f64 * 0.2) / 100.0).log10();
    assert!((psnr(&p, &t).unwrap() - quirk).abs() > 0.3);
}

#[test]
fn the_papers_psnr_equals_hand_computation_of_its_quirks() {
    // The reference: grey 90 on the valid cells (the last row invalid); the map:
    // grey 102 everywhere and not covering column 0 either.
    let mut t = raster();
    let mut p = raster();
    for row in 0..10 {
        for col in 0..10 {
            t.rgb.put_pixel(col, row, image::Rgb([90; 3]));
            p.rgb.put_pixel(col, row, image::Rgb([102; 3]));
        }
        p.valid.put_pixel(0, row, image::Luma([0]));
    }
    // Shared cells: 9 rows × 9 columns = 81; the paper divides by all 100 cells and
    // reads the reference over 225: error 102/255 − 90/225 = 0.4 − 0.4 = 0 per
    // channel: its floor, 100 dB.
    assert!((paper_psnr(&p, &t).unwrap() - 100.0).abs() < 1e-9);
    // Corrected: over the 81 shared cells, both over 255: (12/255)².
    let d = 12.0f64 / 255.0;
    assert!((psnr(&p, &t).unwrap() - -10.0 * (d * d).log10()).abs() < 1e-9);
    // A map at 0 where the reference reads 45 (0.2 over 225): the paper's mean is
    // 81 · 3 · 0.04 / (100 · 3), the corrected one 0.04.
    for row in 0..10 {
        for col in 0..10 {
            t.rgb.put_pixel(col, row, image::Rgb([45; 3]));
            p.rgb.put_pixel(col, row, image::Rgb([0; 3]));
        }
    }
    let paper = -10.0 * (0.04f64 * 81.0 / 100.0).log10();
    assert!((paper_psnr(&p, &t).unwrap() - paper).abs() < 1e-9);
    let d = 45.0f64 / 255.0;
    assert!((psnr(&p, &t).unwrap() - -10.0 * (d * d).log10()).abs() < 1e-9);
    // Nothing shared: no figure.
    p.valid.fill(0);
    assert_eq!(paper_psnr(&p, &t), None);
}

#[test]
fn miou_of_a_perturbation_equals_hand_computation() {
    let t = raster();
    let mut p = raster();
    // Predict class 1 on 9 valid pixels of class 0 (one column).
    for row in 0..9 {
        p.class_ids.put_pixel(4, row, image::Luma([1]));
    }
    // Class 0: intersection 36, union 45. Class 1: intersection 45, union 54.
    let expected = (36.0 / 45.0 + 45.0 / 54.0) / 2.0;
    assert!((miou(&p, &t, &[0, 1, 2]).unwrap() - expected).abs() < 1e-12);
    // Class 2 is absent from both and does not count; a non-road class is not scored.
    assert!((miou(&p, &t, &[0]).unwrap() - 36.0 / 45.0).abs() < 1e-12);
    let per = rogs::eval::class_iou(&p, &t, &[0, 1, 2]);
    assert_eq!(per.len(), 2);
    assert_eq!(per[0].0, 0);
    assert!((per[0].1 - 36.0 / 45.0).abs() < 1e-12 && (per[1].1 - 45.0 / 54.0).abs() < 1e-12);
}

#[test]
fn elevation_errors_equal_hand_computation() {
    let t = raster();
    // Errors 0.1, -0.2, 0.3, 0 (points over valid pixels); one over an invalid row.
    let pts = [
        [0.05, 0.95, 1.1],
        [0.15, 0.95, 0.8],
        [0.55, 0.55, 1.3],
        [0.85, 0.25, 1.0],
        [0.5, 0.05, 9.0],
    ];
    let e = elevation_vs_raster(&pts, &t).unwrap();
    assert_eq!(e.count, 4);
    assert!((e.rmse - ((0.01 + 0.04 + 0.09) / 4.0f64).sqrt()).abs() < 1e-6);
    assert!((e.mae - 0.6 / 4.0).abs() < 1e-6);
    assert!((e.p95 - 0.3).abs() < 1e-6);
    let mut errs: Vec<f64> = (1..=100).map(|i| i as f64).collect();
    assert_eq!(error_stats(&mut errs).unwrap().p95, 95.0);
}

#[test]
fn the_elevation_datum_is_the_plane_under_the_errors() {
    // Errors: a plane (2 cm, +1 mm/m east, -2 mm/m north about the centroid) plus a
    // ±5 mm checkerboard, which no plane fits on an even grid: the fit returns the
    // plane and the checkerboard's 5 mm.
    let (mut xy, mut e) = (Vec::new(), Vec::new());
    for i in 0..10 {
        for j in 0..10 {
            let (x, y) = (100.0 + i as f64, 50.0 + j as f64);
            xy.push([x, y]);
            let sign = if (i + j) % 2 == 0 { 1.0 } else { -1.0 };
            e.push(0.02 + 0.001 * (x - 104.5) - 0.002 * (y - 54.5) + 0.005 * sign);
        }
    }
    let d = elevation_datum(&xy, &e).unwrap();
    assert!((d.offset_m - 0.02).abs() < 1e-9, "{d:?}");
    assert!((d.slope_x - 0.001).abs() < 1e-9 && (d.slope_y + 0.002).abs() < 1e-9);
    assert!((d.rmse_m - 0.005).abs() < 1e-9);
    // Through the raster: a constant error has a zero datum-free error.
    let t = raster();
    let pts: Vec<[f64; 3]> = (0..9)
        .map(|k| [0.05 + 0.1 * k as f64, 0.95 - 0.1 * (k % 3) as f64, 1.03])
        .collect();
    let s = elevation_vs_raster(&pts, &t).unwrap();
    let d = s.datum.unwrap();
    assert!((s.rmse - 0.03).abs() < 1e-6 && (d.offset_m - 0.03).abs() < 1e-6);
    assert!(d.rmse_m < 1e-6, "{d:?}");
    // Points on one line leave the tilt across it unknown: no datum.
    assert!(elevation_datum(&xy[..10], &e[..10]).is_none());
}

#[test]
fn elevation_against_points_uses_nearest_within_radius() {
    let reference = [[0.0, 0.0, 1.0], [0.05, 0.0, 2.0], [1.0, 1.0, 5.0]];
    // Nearest to (0.04, 0) is the second point (error 0.5); (0.5, 0.5) has none within 0.1 m.
    let e = elevation_vs_points(&[[0.04, 0.0, 2.5], [0.5, 0.5, 0.0]], &reference, 0.1).unwrap();
    assert_eq!(e.count, 1);
    assert!((e.rmse - 0.5).abs() < 1e-12);
}
