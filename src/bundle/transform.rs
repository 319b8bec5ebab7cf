//! Row-major 4×4 rigid transforms as the bundle stores them: compose, invert, apply,
//! build from a rotation (Rodrigues) and a translation.

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

/// A rigid transform from a rotation matrix and a translation.
pub fn mat(r: [[f64; 3]; 3], t: [f64; 3]) -> Mat4Rows {
    [
        [r[0][0], r[0][1], r[0][2], t[0]],
        [r[1][0], r[1][1], r[1][2], t[1]],
        [r[2][0], r[2][1], r[2][2], t[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// Rodrigues: rotation matrix of the axis-angle vector w (radians).
pub fn exp_so3(w: [f64; 3]) -> [[f64; 3]; 3] {
    let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
    if th < 1e-15 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = w.map(|v| v / th);
    let (s, c) = (th.sin(), th.cos());
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            let kk = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
            let k2: f64 = (0..3).map(|m| kk[i][m] * kk[m][j]).sum();
            *v = if i == j { 1.0 } else { 0.0 } + s * kk[i][j] + (1.0 - c) * k2;
        }
    }
    r
}
