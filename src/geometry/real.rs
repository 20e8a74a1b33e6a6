//! One small trait that lets the kernels be written once for f32 and f64.
//!
//! f32 uses glam's `Vec3A` (16-byte, SIMD-friendly), f64 uses `DVec3`. Only what the
//! kernels need is here; everything crosses into and out of it through f64 (`DVec3`).

use glam::{DVec3, Vec3A};
use std::fmt::Debug;
use std::ops::{Add, Div, Mul, Neg, Sub};

crate::choice_enum! {
    /// Kernel precision.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
    pub enum Precision default F64 {
        /// IEEE single precision: eight lanes to an AVX register.
        F32 = "f32",
        /// IEEE double precision: the accuracy reference.
        F64 = "f64",
    }
}

impl Precision {
    /// `f32` or `f64`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }
}

/// A floating-point precision the kernels can run in.
pub trait Real:
    Copy
    + Debug
    + PartialOrd
    + Send
    + Sync
    + 'static
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// The 3-vector of this precision.
    type V3: Copy
        + Debug
        + Send
        + Sync
        + Add<Output = Self::V3>
        + Sub<Output = Self::V3>
        + Mul<Self, Output = Self::V3>
        + Neg<Output = Self::V3>;
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// 2.
    const TWO: Self;
    /// +∞ (an unbounded `tmax`).
    const INFINITY: Self;
    /// Unit roundoff (half the machine epsilon).
    const UNIT_ROUNDOFF: f64;
    /// Name for tables: `f32` or `f64`.
    const NAME: &'static str;
    /// The same, as the kernel choice names it.
    const PRECISION: Precision;

    /// Round an f64 to this precision (identity for f64).
    fn from_f64(x: f64) -> Self;
    /// Widen to f64 (exact).
    fn to_f64(self) -> f64;
    /// Correctly rounded square root.
    fn sqrt(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// +1 or -1 with the sign of `self`; never 0 (`sign(0) = +1`: the stable root needs ±1).
    fn sign(self) -> Self;
    /// Neither NaN nor ±∞.
    fn is_finite(self) -> bool;
    /// The smaller of two (IEEE `min`).
    fn min(self, o: Self) -> Self;
    /// The larger of two (IEEE `max`).
    fn max(self, o: Self) -> Self;

    /// Round an f64 vector to this precision.
    fn v3(v: DVec3) -> Self::V3;
    /// Widen a vector to f64 (exact).
    fn v3_to_f64(v: Self::V3) -> DVec3;
    /// A vector from its components.
    fn v3_new(x: Self, y: Self, z: Self) -> Self::V3;
    /// The components `[x, y, z]`.
    fn v3_parts(v: Self::V3) -> [Self; 3];
    /// Dot product, in the order `x·x + y·y + z·z` (the SIMD lanes use the same order).
    fn dot(a: Self::V3, b: Self::V3) -> Self;
    /// Cross product.
    fn cross(a: Self::V3, b: Self::V3) -> Self::V3;
    /// Unit vector along `v`; `v` must be non-zero.
    fn normalize(v: Self::V3) -> Self::V3;
}

macro_rules! impl_real {
    ($t:ty, $v:ty, $name:literal, $precision:expr, $from:expr, $to:expr) => {
        impl Real for $t {
            type V3 = $v;
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const TWO: Self = 2.0;
            const INFINITY: Self = <$t>::INFINITY;
            const UNIT_ROUNDOFF: f64 = <$t>::EPSILON as f64 / 2.0;
            const NAME: &'static str = $name;
            const PRECISION: Precision = $precision;

            #[inline(always)]
            fn from_f64(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn sign(self) -> Self {
                <$t>::copysign(1.0, self)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline(always)]
            fn min(self, o: Self) -> Self {
                <$t>::min(self, o)
            }
            #[inline(always)]
            fn max(self, o: Self) -> Self {
                <$t>::max(self, o)
            }
            #[inline(always)]
            fn v3(v: DVec3) -> Self::V3 {
                $from(v)
            }
            #[inline(always)]
            fn v3_to_f64(v: Self::V3) -> DVec3 {
                $to(v)
            }
            #[inline(always)]
            fn v3_new(x: Self, y: Self, z: Self) -> Self::V3 {
                <$v>::new(x, y, z)
            }
            #[inline(always)]
            fn v3_parts(v: Self::V3) -> [Self; 3] {
                v.to_array()
            }
            #[inline(always)]
            fn dot(a: Self::V3, b: Self::V3) -> Self {
                a.dot(b)
            }
            #[inline(always)]
            fn cross(a: Self::V3, b: Self::V3) -> Self::V3 {
                a.cross(b)
            }
            #[inline(always)]
            fn normalize(v: Self::V3) -> Self::V3 {
                v.normalize()
            }
        }
    };
}

impl_real!(
    f64,
    DVec3,
    "f64",
    Precision::F64,
    |v: DVec3| v,
    |v: DVec3| v
);
impl_real!(
    f32,
    Vec3A,
    "f32",
    Precision::F32,
    |v: DVec3| Vec3A::new(v.x as f32, v.y as f32, v.z as f32),
    |v: Vec3A| DVec3::new(v.x as f64, v.y as f64, v.z as f64)
);
