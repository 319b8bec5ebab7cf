//! Row-major 4×4 rigid transforms as the bundle stores them: compose, invert, apply.

use super::Mat4Rows;

/// a · b.
pub fn mul(a: &Mat4Rows, b: &Mat4Rows) -> Mat4Rows {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..4).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// Inverse of a rigid transform: [Rᵀ | −Rᵀt].
pub fn inverse(a: &Mat4Rows) -> Mat4Rows {
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = a[j][i];
        }
        m[i][3] = -(0..3).map(|k| a[k][i] * a[k][3]).sum::<f64>();
    }
    m[3][3] = 1.0;
    m
}

/// The transform applied to a point.
pub fn apply(a: &Mat4Rows, p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[i][0] * p[0] + a[i][1] * p[1] + a[i][2] * p[2] + a[i][3])
}
