//! Eight lanes of f32 or f64 as one value, so the packet kernel is written once.
//!
//! [`Lanes`] is the portable form (arrays and loops, for any CPU). On x86-64, `Avx32`
//! (one 256-bit register of f32) and `Avx64` (two of f64) use AVX intrinsics. Their safety
//! is a fact of the types: every constructor takes an [`Avx2`] token, and only the run-time
//! feature check ([`Avx2::detect`]) makes one, so no AVX value exists on a CPU without AVX2. Every
//! operation is the single IEEE operation the scalar kernel performs (add, sub, mul, div,
//! sqrt, ordered compares, sign-bit logic), so all forms give the same bits.

use super::real::Real;
use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Lanes of a [`Wide`] value; a packet's rays are one lane each: eight pixels of a tile row.
pub(crate) const LANES: usize = 8;

/// Eight lanes of `T`, with the operations the packet kernel needs.
pub(crate) trait Wide<T>:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// What building a value takes: nothing for [`Lanes`], an [`Avx2`] token for the AVX
    /// forms, so AVX values exist only where the CPU was checked. The token also tests
    /// eight boxes at once ([`Slabs8`]) in the same registers.
    type Token: Slabs8;
    /// A lane mask, as produced by the comparisons.
    type Mask: Copy
        + BitAnd<Output = Self::Mask>
        + BitOr<Output = Self::Mask>
        + Not<Output = Self::Mask>;
    /// Every lane `x`.
    fn splat(tok: Self::Token, x: T) -> Self;
    /// The lanes of `a`.
    fn load(tok: Self::Token, a: &[T; LANES]) -> Self;
    fn store(self, a: &mut [T; LANES]);
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    /// +1 or -1 with the sign bit of each lane (`sign(0) = +1`, as [`Real::sign`]).
    fn sign(self) -> Self;
    fn lt(self, o: Self) -> Self::Mask;
    fn le(self, o: Self) -> Self::Mask;
    fn gt(self, o: Self) -> Self::Mask;
    fn ge(self, o: Self) -> Self::Mask;
    fn eq(self, o: Self) -> Self::Mask;
    /// Per lane, `a` where `m` is set, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
    /// Bit `l` set where lane `l` of `m` is.
    fn bits(m: Self::Mask) -> u8;
    /// Every lane set to `b`.
    fn all(tok: Self::Token, b: bool) -> Self::Mask;
    /// Bit `l` set where `x <= a[l]`: f64 lanes, for the bookkeeping that stays in f64
    /// whatever the kernel's precision.
    fn le_bits(tok: Self::Token, x: f64, a: &[f64; LANES]) -> u8;
}

/// The portable form: an array, one loop per operation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lanes<T>([T; LANES]);

/// A mask of [`Lanes`]: one bit per lane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Bits(u8);

impl BitAnd for Bits {
    type Output = Bits;
    fn bitand(self, o: Bits) -> Bits {
        Bits(self.0 & o.0)
    }
}
impl BitOr for Bits {
    type Output = Bits;
    fn bitor(self, o: Bits) -> Bits {
        Bits(self.0 | o.0)
    }
}
impl Not for Bits {
    type Output = Bits;
    fn not(self) -> Bits {
        Bits(!self.0)
    }
}

macro_rules! lanes_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl<T: Real> $tr for Lanes<T> {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                Lanes(std::array::from_fn(|l| self.0[l] $op o.0[l]))
            }
        }
    };
}
lanes_op!(Add, add, +);
lanes_op!(Sub, sub, -);
lanes_op!(Mul, mul, *);
lanes_op!(Div, div, /);

impl<T: Real> Neg for Lanes<T> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        Lanes(self.0.map(|x| -x))
    }
}

impl<T: Real> Lanes<T> {
    #[inline(always)]
    fn cmp(self, o: Self, f: impl Fn(T, T) -> bool) -> Bits {
        Bits((0..LANES).fold(0, |m, l| m | ((f(self.0[l], o.0[l]) as u8) << l)))
    }
}

impl<T: Real> Wide<T> for Lanes<T> {
    type Token = ();
    type Mask = Bits;
    #[inline(always)]
    fn splat(_: (), x: T) -> Self {
        Lanes([x; LANES])
    }
    #[inline(always)]
    fn load(_: (), a: &[T; LANES]) -> Self {
        Lanes(*a)
    }
    #[inline(always)]
    fn store(self, a: &mut [T; LANES]) {
        *a = self.0;
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Lanes(self.0.map(T::sqrt))
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Lanes(self.0.map(T::abs))
    }
    #[inline(always)]
    fn sign(self) -> Self {
        Lanes(self.0.map(T::sign))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> Bits {
        self.cmp(o, |a, b| a < b)
    }
    #[inline(always)]
    fn le(self, o: Self) -> Bits {
        self.cmp(o, |a, b| a <= b)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Bits {
        self.cmp(o, |a, b| a > b)
    }
    #[inline(always)]
    fn ge(self, o: Self) -> Bits {
        self.cmp(o, |a, b| a >= b)
    }
    #[inline(always)]
    fn eq(self, o: Self) -> Bits {
        self.cmp(o, |a, b| a == b)
    }
    #[inline(always)]
    fn select(m: Bits, a: Self, b: Self) -> Self {
        Lanes(std::array::from_fn(|l| {
            if m.0 & (1 << l) != 0 { a.0[l] } else { b.0[l] }
        }))
    }
    #[inline(always)]
    fn bits(m: Bits) -> u8 {
        m.0
    }
    #[inline(always)]
    fn all(_: (), b: bool) -> Bits {
        Bits(if b { u8::MAX } else { 0 })
    }
    #[inline(always)]
    fn le_bits(_: (), x: f64, a: &[f64; LANES]) -> u8 {
        (0..LANES).fold(0, |m, l| m | (((x <= a[l]) as u8) << l))
    }
}

/// Proof that this CPU has AVX2, and the bit-count instructions every AVX2 processor has
/// (POPCNT, LZCNT, BMI1: the traversal counts and finds lanes with them; without them a
/// count of a lane mask is a chain of multiplies): [`Avx2::detect`] is the only safe way to get one, and
/// every AVX value is built from one (`Wide::splat`, `load`, `all`, `le_bits` take it), so
/// the safe methods of `Avx32`/`Avx64`, which execute AVX instructions, can run only where
/// the check succeeded. Zero-sized: passing it costs nothing.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Avx2(());

impl Avx2 {
    /// The token, when the CPU running this process has AVX2, POPCNT, LZCNT and BMI1.
    pub(crate) fn detect() -> Option<Avx2> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("popcnt")
            && std::arch::is_x86_feature_detected!("lzcnt")
            && std::arch::is_x86_feature_detected!("bmi1")
        {
            return Some(Avx2(()));
        }
        None
    }

    /// The token without the check.
    ///
    /// # Safety
    /// The CPU must have what [`Avx2::detect`] checks (AVX2, POPCNT, LZCNT, BMI1): call it
    /// only from code that runs after `detect` succeeded (for instance a
    /// `#[target_feature(enable = "avx2,popcnt,lzcnt,bmi1")]` function, whose own contract
    /// is the same).
    #[cfg(target_arch = "x86_64")]
    pub(crate) unsafe fn new_unchecked() -> Avx2 {
        Avx2(())
    }
}

/// One ray as the eight-box slab test reads it: per axis the reciprocal direction, for
/// entries, and the same widened by the exit factor, for exits, and which rows of a node's
/// planes are the near and the far face (the ray's sign picks them, so `near <= far` per
/// axis without a min/max, and an empty lane, +inf..-inf, is a miss whatever the sign).
/// Made only by [`SlabRay::new`], so every row starts at most 40 f32 into the planes.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SlabRay {
    /// `1/d` per axis: ±inf along an axis the ray is parallel to, never 0 or NaN.
    inv: [f32; 3],
    /// `inv · grow` per axis: an exit is `plane · inv_far`, one product from the plane (the
    /// next node waits for this test, so a second product would lengthen every step).
    inv_far: [f32; 3],
    /// Per axis, where the row of the plane the ray enters by, `axis` (min) or `axis + 3`
    /// (max), starts in a node's planes read as one array of f32 (8 per row; an offset
    /// rather than a row index: x86 scales it in the load's address for free).
    near_row: [usize; 3],
    /// Per axis, where the row it leaves by starts.
    far_row: [usize; 3],
    /// The segment's start: no entry is reported before it.
    tmin: f32,
}

impl SlabRay {
    /// The ray `t·d` from the boxes' origin, entries reported from `tmin` on, exits
    /// widened by the factor `grow`.
    ///
    /// An exit `plane · (inv · grow)` takes three roundings of relative size at most
    /// u = 2⁻²⁴ (the reciprocal, its product by `grow`, the product by the plane), as
    /// `(plane · inv) · grow` does; so with pbrt's `grow = 1 + 2γ₃` the computed exit of a
    /// box ahead is at least its exact exit, and its computed entry (two roundings) at most
    /// `(1 + u)²` times its exact entry: a box the exact ray meets is still met.
    #[inline(always)]
    pub(crate) fn new(d: [f32; 3], tmin: f32, grow: f32) -> SlabRay {
        // 1/±0 = ±inf: a ray parallel to a slab is in it for every t or for none (the BVH
        // stores no plane at ±0, so no 0·inf = NaN; and one would only widen the test: the
        // max and min keep their second operand on NaN, and the tmin and tmax terms are
        // never NaN).
        let inv = d.map(|x| 1.0 / x);
        // A ray going towards -x enters a box by its max x face, and so on.
        let neg = inv.map(|x| (x < 0.0) as usize);
        let (near_row, far_row) = rows_of(neg[0] | neg[1] << 1 | neg[2] << 2);
        SlabRay {
            inv,
            inv_far: inv.map(|x| x * grow),
            near_row,
            far_row,
            tmin,
        }
    }

    /// The ray's octant: bit `a` set where it goes towards −axis `a`.
    #[inline(always)]
    pub(crate) fn octant(&self) -> usize {
        (0..3).fold(0, |o, a| o | ((self.near_row[a] >= 24) as usize) << a)
    }

    /// The near and far rows, fixed at compile time for a ray of octant `OCT` (so a walk
    /// that knows its rays' octant reads no offsets), read from the ray for [`ANY_OCTANT`].
    #[inline(always)]
    fn rows<const OCT: usize>(&self) -> ([usize; 3], [usize; 3]) {
        debug_assert!(OCT == ANY_OCTANT || OCT == self.octant());
        if OCT < ANY_OCTANT {
            rows_of(OCT)
        } else {
            (self.near_row, self.far_row)
        }
    }
}

/// Not an octant: a slab test for `OCT = ANY_OCTANT` reads the rows from its ray.
pub(crate) const ANY_OCTANT: usize = 8;

/// Where the near and far rows start (in f32, at most 40) for a ray of `octant`.
#[inline(always)]
const fn rows_of(octant: usize) -> ([usize; 3], [usize; 3]) {
    let neg = [octant & 1, octant >> 1 & 1, octant >> 2 & 1];
    (
        [8 * 3 * neg[0], 8 * (1 + 3 * neg[1]), 8 * (2 + 3 * neg[2])],
        [
            8 * (3 - 3 * neg[0]),
            8 * (4 - 3 * neg[1]),
            8 * (5 - 3 * neg[2]),
        ],
    )
}

/// The slab test of eight boxes against one ray at once, portable (`()`) or in AVX
/// registers ([`Avx2`]), with the children to descend into packed for a traversal stack.
/// Both perform the same IEEE operations per lane (products by `inv` and `inv_far`,
/// ordered max and min), so they report the same lanes and pack the same children.
pub(crate) trait Slabs8: Copy {
    /// For boxes `planes` (rows min x, y, z, max x, y, z; lane `l` is box `l`): `met`, bit
    /// `l` set where the ray meets box `l` within `[ray.tmin, tmax]` (entry
    /// `max(tmin, near face · inv over the axes)` at most the widened exit), and `packed`,
    /// the met lanes whose `child` has its top bit clear. Their children are written to
    /// the first `packed.count_ones()` entries of `out`, in lane order; the other entries
    /// of `out` are written with no meaning. `OCT` is the ray's octant, or [`ANY_OCTANT`].
    fn slabs8<const OCT: usize>(
        self,
        planes: &[[f32; 8]; 6],
        child: &[u32; 8],
        ray: &SlabRay,
        tmax: f32,
        out: &mut [u32; 8],
    ) -> Met8;
}

/// What [`Slabs8::slabs8`] found: lane masks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Met8 {
    /// Lanes whose box the ray meets.
    pub met: u8,
    /// Met lanes whose child went to `out`.
    pub packed: u8,
}

/// Per lane mask, its set lanes in order, one byte each (the rest 0): the shuffle that
/// packs the lanes of a mask to the front.
const PACK: [u64; 256] = {
    let mut t = [0u64; 256];
    let mut m = 0;
    while m < 256 {
        let (mut k, mut l) = (0, 0);
        while l < 8 {
            if (m >> l) & 1 != 0 {
                t[m] |= (l as u64) << (8 * k);
                k += 1;
            }
            l += 1;
        }
        m += 1;
    }
    t
};

impl Slabs8 for () {
    #[inline(always)]
    fn slabs8<const OCT: usize>(
        self,
        planes: &[[f32; 8]; 6],
        child: &[u32; 8],
        ray: &SlabRay,
        tmax: f32,
        out: &mut [u32; 8],
    ) -> Met8 {
        let max = |a: f32, b: f32| if a > b { a } else { b };
        let min = |a: f32, b: f32| if a < b { a } else { b };
        let planes = planes.as_flattened();
        let met = (0..8).fold(0u8, |met, l| {
            let t = |row: usize, a: usize| planes[row + l] * ray.inv[a];
            let (n, f) = ray.rows::<OCT>();
            let enter = max(max(t(n[0], 0), t(n[1], 1)), max(t(n[2], 2), ray.tmin));
            let g = |row: usize, a: usize| planes[row + l] * ray.inv_far[a];
            let leave = min(min(g(f[0], 0), g(f[1], 1)), min(g(f[2], 2), tmax));
            met | ((enter <= leave) as u8) << l
        });
        let tops = (0..8).fold(0u8, |m, l| m | (((child[l] >> 31) as u8) << l));
        let packed = met & !tops;
        let order = PACK[packed as usize].to_le_bytes();
        for (o, l) in out.iter_mut().zip(order) {
            *o = child[l as usize];
        }
        Met8 { met, packed }
    }
}

/// A precision with an AVX lane type, built only with an [`Avx2`] token.
pub(crate) trait Simd: Real {
    /// Eight lanes of this precision in AVX registers.
    #[cfg(target_arch = "x86_64")]
    type Avx: Wide<Self, Token = Avx2>;
}

#[cfg(target_arch = "x86_64")]
impl Simd for f32 {
    type Avx = avx::Avx32;
}

#[cfg(target_arch = "x86_64")]
impl Simd for f64 {
    type Avx = avx::Avx64;
}

#[cfg(not(target_arch = "x86_64"))]
impl Simd for f32 {}

#[cfg(not(target_arch = "x86_64"))]
impl Simd for f64 {}

/// AVX forms. Each method is a handful of intrinsics; callers must run on a CPU with
/// AVX2 and be compiled with it enabled (`render` checks at run time).
#[cfg(target_arch = "x86_64")]
mod avx {
    use super::{Avx2, LANES, Wide};
    use std::arch::x86_64::*;
    use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

    /// Eight f32 lanes in one register.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx32(__m256);
    /// Eight f64 lanes in two registers.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx64([__m256d; 2]);
    #[derive(Clone, Copy, Debug)]
    pub struct Mask32(__m256);
    #[derive(Clone, Copy, Debug)]
    pub struct Mask64([__m256d; 2]);

    // SAFETY (every `unsafe` block below without a note of its own): AVX intrinsics on
    // values in registers. The CPU has AVX2: every value of these types was built from an
    // `Avx2` token, which only the run-time check (or an unsafe caller vouching for it) makes.
    macro_rules! binops {
        ($t:ident, $m:ident, $w:ident: $($tr:ident $f:ident $intr:ident),*) => {$(
            impl $tr for $t {
                type Output = $t;
                #[inline(always)]
                fn $f(self, o: $t) -> $t {
                    unsafe { $t(binops!(@apply $w, $intr, self.0, o.0)) }
                }
            }
        )*};
        (@apply one, $intr:ident, $a:expr, $b:expr) => { $intr($a, $b) };
        (@apply two, $intr:ident, $a:expr, $b:expr) => { [$intr($a[0], $b[0]), $intr($a[1], $b[1])] };
    }
    binops!(Avx32, Mask32, one: Add add _mm256_add_ps, Sub sub _mm256_sub_ps, Mul mul _mm256_mul_ps, Div div _mm256_div_ps);
    binops!(Mask32, Mask32, one: BitAnd bitand _mm256_and_ps, BitOr bitor _mm256_or_ps);
    binops!(Avx64, Mask64, two: Add add _mm256_add_pd, Sub sub _mm256_sub_pd, Mul mul _mm256_mul_pd, Div div _mm256_div_pd);
    binops!(Mask64, Mask64, two: BitAnd bitand _mm256_and_pd, BitOr bitor _mm256_or_pd);

    impl Not for Mask32 {
        type Output = Mask32;
        #[inline(always)]
        fn not(self) -> Mask32 {
            unsafe {
                Mask32(_mm256_xor_ps(
                    self.0,
                    _mm256_castsi256_ps(_mm256_set1_epi32(-1)),
                ))
            }
        }
    }
    impl Not for Mask64 {
        type Output = Mask64;
        #[inline(always)]
        fn not(self) -> Mask64 {
            unsafe {
                let ones = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
                Mask64([
                    _mm256_xor_pd(self.0[0], ones),
                    _mm256_xor_pd(self.0[1], ones),
                ])
            }
        }
    }
    impl Neg for Avx32 {
        type Output = Avx32;
        #[inline(always)]
        fn neg(self) -> Avx32 {
            unsafe { Avx32(_mm256_xor_ps(self.0, _mm256_set1_ps(-0.0))) }
        }
    }
    impl Neg for Avx64 {
        type Output = Avx64;
        #[inline(always)]
        fn neg(self) -> Avx64 {
            let s = unsafe { _mm256_set1_pd(-0.0) };
            unsafe { Avx64([_mm256_xor_pd(self.0[0], s), _mm256_xor_pd(self.0[1], s)]) }
        }
    }

    /// [`Wide::le_bits`] with AVX: two compares and two sign masks.
    #[inline(always)]
    fn le_bits_avx(x: f64, a: &[f64; LANES]) -> u8 {
        // SAFETY: two unaligned loads of 4 f64 from `a`, which holds exactly 8; AVX2 is
        // there (the callers hold an `Avx2` token).
        unsafe {
            let x = _mm256_set1_pd(x);
            let lo = _mm256_cmp_pd::<_CMP_LE_OQ>(x, _mm256_loadu_pd(a.as_ptr()));
            let hi = _mm256_cmp_pd::<_CMP_LE_OQ>(x, _mm256_loadu_pd(a.as_ptr().add(4)));
            (_mm256_movemask_pd(lo) | (_mm256_movemask_pd(hi) << 4)) as u8
        }
    }

    /// The ordered comparisons (false with a NaN, as Rust's `<`), as AVX compares.
    macro_rules! cmps {
        ($m:ident: $f:ident) => {
            cmps!($m: $f, lt _CMP_LT_OQ, le _CMP_LE_OQ, gt _CMP_GT_OQ, ge _CMP_GE_OQ, eq _CMP_EQ_OQ);
        };
        (Mask32: $f:ident, $($name:ident $p:ident),*) => {$(
            #[inline(always)]
            fn $name(self, o: Self) -> Mask32 {
                unsafe { Mask32($f::<$p>(self.0, o.0)) }
            }
        )*};
        (Mask64: $f:ident, $($name:ident $p:ident),*) => {$(
            #[inline(always)]
            fn $name(self, o: Self) -> Mask64 {
                Mask64(halves!($f::<$p>(self.0, o.0)))
            }
        )*};
    }

    impl Wide<f32> for Avx32 {
        type Token = Avx2;
        type Mask = Mask32;
        #[inline(always)]
        fn splat(_: Avx2, x: f32) -> Self {
            unsafe { Avx32(_mm256_set1_ps(x)) }
        }
        #[inline(always)]
        fn load(_: Avx2, a: &[f32; LANES]) -> Self {
            // SAFETY: an unaligned load of 8 f32 from `a`, which holds exactly 8.
            unsafe { Avx32(_mm256_loadu_ps(a.as_ptr())) }
        }
        #[inline(always)]
        fn store(self, a: &mut [f32; LANES]) {
            // SAFETY: an unaligned store of 8 f32 into `a`, which holds exactly 8.
            unsafe { _mm256_storeu_ps(a.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            unsafe { Avx32(_mm256_sqrt_ps(self.0)) }
        }
        #[inline(always)]
        fn abs(self) -> Self {
            unsafe { Avx32(_mm256_andnot_ps(_mm256_set1_ps(-0.0), self.0)) }
        }
        #[inline(always)]
        fn sign(self) -> Self {
            unsafe {
                let s = _mm256_and_ps(self.0, _mm256_set1_ps(-0.0));
                Avx32(_mm256_or_ps(s, _mm256_set1_ps(1.0)))
            }
        }
        cmps!(Mask32: _mm256_cmp_ps);
        #[inline(always)]
        fn select(m: Mask32, a: Self, b: Self) -> Self {
            unsafe { Avx32(_mm256_blendv_ps(b.0, a.0, m.0)) }
        }
        #[inline(always)]
        fn bits(m: Mask32) -> u8 {
            unsafe { _mm256_movemask_ps(m.0) as u8 }
        }
        #[inline(always)]
        fn all(_: Avx2, b: bool) -> Mask32 {
            unsafe { Mask32(_mm256_castsi256_ps(_mm256_set1_epi32(-(b as i32)))) }
        }
        #[inline(always)]
        fn le_bits(_: Avx2, x: f64, a: &[f64; LANES]) -> u8 {
            le_bits_avx(x, a)
        }
    }

    /// `Avx64` method bodies: `$f` applied to both halves (no closures, so nothing
    /// stands between the intrinsic and the AVX2 code it is inlined into).
    macro_rules! halves {
        ($f:ident($($a:expr),*)) => {
            unsafe { [$f($($a[0]),*), $f($($a[1]),*)] }
        };
        ($f:ident::<$p:ident>($($a:expr),*)) => {
            unsafe { [$f::<$p>($($a[0]),*), $f::<$p>($($a[1]),*)] }
        };
    }

    impl Wide<f64> for Avx64 {
        type Token = Avx2;
        type Mask = Mask64;
        #[inline(always)]
        fn splat(_: Avx2, x: f64) -> Self {
            unsafe { Avx64([_mm256_set1_pd(x); 2]) }
        }
        #[inline(always)]
        fn load(_: Avx2, a: &[f64; LANES]) -> Self {
            // SAFETY: two unaligned loads of 4 f64 from `a`, which holds exactly 8.
            unsafe {
                Avx64([
                    _mm256_loadu_pd(a.as_ptr()),
                    _mm256_loadu_pd(a.as_ptr().add(4)),
                ])
            }
        }
        #[inline(always)]
        fn store(self, a: &mut [f64; LANES]) {
            // SAFETY: two unaligned stores of 4 f64 into `a`, which holds exactly 8.
            unsafe {
                _mm256_storeu_pd(a.as_mut_ptr(), self.0[0]);
                _mm256_storeu_pd(a.as_mut_ptr().add(4), self.0[1]);
            }
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            Avx64(halves!(_mm256_sqrt_pd(self.0)))
        }
        #[inline(always)]
        fn abs(self) -> Self {
            let s = [unsafe { _mm256_set1_pd(-0.0) }; 2];
            Avx64(halves!(_mm256_andnot_pd(s, self.0)))
        }
        #[inline(always)]
        fn sign(self) -> Self {
            let (s, one) = unsafe { ([_mm256_set1_pd(-0.0); 2], [_mm256_set1_pd(1.0); 2]) };
            let signs = halves!(_mm256_and_pd(self.0, s));
            Avx64(halves!(_mm256_or_pd(signs, one)))
        }
        cmps!(Mask64: _mm256_cmp_pd);
        #[inline(always)]
        fn select(m: Mask64, a: Self, b: Self) -> Self {
            Avx64(halves!(_mm256_blendv_pd(b.0, a.0, m.0)))
        }
        #[inline(always)]
        fn bits(m: Mask64) -> u8 {
            unsafe { (_mm256_movemask_pd(m.0[0]) | (_mm256_movemask_pd(m.0[1]) << 4)) as u8 }
        }
        #[inline(always)]
        fn all(_: Avx2, b: bool) -> Mask64 {
            unsafe { Mask64([_mm256_castsi256_pd(_mm256_set1_epi64x(-(b as i64))); 2]) }
        }
        #[inline(always)]
        fn le_bits(_: Avx2, x: f64, a: &[f64; LANES]) -> u8 {
            le_bits_avx(x, a)
        }
    }

    impl super::Slabs8 for Avx2 {
        #[inline(always)]
        fn slabs8<const OCT: usize>(
            self,
            planes: &[[f32; 8]; 6],
            child: &[u32; 8],
            ray: &super::SlabRay,
            tmax: f32,
            out: &mut [u32; 8],
        ) -> super::Met8 {
            // SAFETY: the token proves AVX2; each load reads one row of 8 f32 of `planes`
            // (a row of a `SlabRay` starts at most 40 f32 in, of 48) or the 8 u32 of `child`, the store
            // writes the 8 u32 of `out` (all unaligned forms). No closure calls an
            // intrinsic that is not inlined into the AVX2 code this is inlined into.
            unsafe {
                let (n, f) = ray.rows::<OCT>();
                let (ix, iy, iz) = (
                    _mm256_set1_ps(ray.inv[0]),
                    _mm256_set1_ps(ray.inv[1]),
                    _mm256_set1_ps(ray.inv[2]),
                );
                // At most 40 f32 in (`SlabRay::new` makes every offset), so in bounds.
                let row = |r: usize| planes.as_flattened().as_ptr().add(r);
                let nx = _mm256_mul_ps(_mm256_loadu_ps(row(n[0])), ix);
                let ny = _mm256_mul_ps(_mm256_loadu_ps(row(n[1])), iy);
                let nz = _mm256_mul_ps(_mm256_loadu_ps(row(n[2])), iz);
                let (gx, gy, gz) = (
                    _mm256_set1_ps(ray.inv_far[0]),
                    _mm256_set1_ps(ray.inv_far[1]),
                    _mm256_set1_ps(ray.inv_far[2]),
                );
                let fx = _mm256_mul_ps(_mm256_loadu_ps(row(f[0])), gx);
                let fy = _mm256_mul_ps(_mm256_loadu_ps(row(f[1])), gy);
                let fz = _mm256_mul_ps(_mm256_loadu_ps(row(f[2])), gz);
                let enter = _mm256_max_ps(
                    _mm256_max_ps(nx, ny),
                    _mm256_max_ps(nz, _mm256_set1_ps(ray.tmin)),
                );
                let leave = _mm256_min_ps(
                    _mm256_min_ps(fx, fy),
                    _mm256_min_ps(fz, _mm256_set1_ps(tmax)),
                );
                let met = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(enter, leave)) as u8;
                let kids = _mm256_loadu_si256(child.as_ptr() as *const __m256i);
                let tops = _mm256_movemask_ps(_mm256_castsi256_ps(kids)) as u8;
                let packed = met & !tops;
                let order = super::PACK[packed as usize] as i64;
                let order = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(order));
                let kids = _mm256_permutevar8x32_epi32(kids, order);
                _mm256_storeu_si256(out.as_mut_ptr() as *mut __m256i, kids);
                super::Met8 { met, packed }
            }
        }
    }
}
