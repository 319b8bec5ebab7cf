//! Small dense least squares shared across stages: three-parameter fits (a plane
//! z = a + b·x + c·y, a pose's height and tilts) by their normal equations, kept as
//! the upper triangle of the symmetric 3×3 matrix.

use glam::{DMat3, DVec3};

/// Adds the weighted observation `y ≈ g · x` to normal equations kept as the upper
/// triangle of the symmetric matrix (row-major) and the right-hand side.
pub fn accumulate3(m: &mut [f64; 6], rhs: &mut [f64; 3], g: [f64; 3], w: f64, y: f64) {
    let mut k = 0;
    for p in 0..3 {
        for q in p..3 {
            m[k] += w * g[p] * g[q];
            k += 1;
        }
        rhs[p] += w * g[p] * y;
    }
}

/// Solves the symmetric 3×3 system stored as its upper triangle (row-major), when
/// its first diagonal entry (the weight of the data) reaches `min_weight`.
pub fn solve3(m: &[f64; 6], b: &[f64; 3], min_weight: f64) -> Option<[f64; 3]> {
    let a = DMat3::from_cols(
        DVec3::new(m[0], m[1], m[2]),
        DVec3::new(m[1], m[3], m[4]),
        DVec3::new(m[2], m[4], m[5]),
    );
    if m[0] < min_weight || a.determinant().abs() < 1e-9 * m[0].powi(3).max(1.0) {
        return None;
    }
    let x = a.inverse() * DVec3::from_array(*b);
    Some(x.to_array())
}
