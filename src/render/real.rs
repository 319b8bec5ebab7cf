//! The scalar type of the CPU oracle: f32 to compare with the GPU bit for bit in
//! spirit (same operations, same order), f64 to check gradients against finite
//! differences without rounding noise.

use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

pub trait Real:
    Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + std::fmt::Debug
    + Default
{
    fn of(v: f64) -> Self;
    fn to_f64(self) -> f64;
    fn exp(self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn min(self, o: Self) -> Self;
    fn max(self, o: Self) -> Self;
    fn floor(self) -> Self;
    fn big() -> Self;
}

macro_rules! real {
    ($t:ty) => {
        impl Real for $t {
            fn of(v: f64) -> Self {
                v as $t
            }
            fn to_f64(self) -> f64 {
                self as f64
            }
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            fn min(self, o: Self) -> Self {
                <$t>::min(self, o)
            }
            fn max(self, o: Self) -> Self {
                <$t>::max(self, o)
            }
            fn floor(self) -> Self {
                <$t>::floor(self)
            }
            fn big() -> Self {
                1e30 as $t
            }
        }
    };
}
real!(f32);
real!(f64);

pub type V3<R> = [R; 3];

pub fn dot<R: Real>(a: V3<R>, b: V3<R>) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn sub<R: Real>(a: V3<R>, b: V3<R>) -> V3<R> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn scale<R: Real>(a: V3<R>, s: R) -> V3<R> {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub fn add<R: Real>(a: V3<R>, b: V3<R>) -> V3<R> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Rotation matrix columns (tangent u, tangent v, normal) of a quaternion (w, x, y, z),
/// normalised first.
pub fn quat_columns<R: Real>(q: [R; 4]) -> [V3<R>; 3] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let (w, x, y, z) = (q[0] / n, q[1] / n, q[2] / n, q[3] / n);
    let one = R::of(1.0);
    let two = R::of(2.0);
    [
        [
            one - two * (y * y + z * z),
            two * (x * y + w * z),
            two * (x * z - w * y),
        ],
        [
            two * (x * y - w * z),
            one - two * (x * x + z * z),
            two * (y * z + w * x),
        ],
        [
            two * (x * z + w * y),
            two * (y * z - w * x),
            one - two * (x * x + y * y),
        ],
    ]
}

pub fn sigmoid<R: Real>(x: R) -> R {
    R::of(1.0) / (R::of(1.0) + (-x).exp())
}
