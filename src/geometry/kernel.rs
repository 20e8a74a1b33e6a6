//! Which kernel traces the rays: a formulation ([`FormulaKind`]) in a precision
//! ([`Precision`]). One type for every command that chooses one (render, batch, verify,
//! bench, stress), one printed name (`stable-f64`, …), and one place, `Kernel::dispatch`,
//! that turns the run-time choice into the types the generic code is compiled for.

use super::cylinder::{Formula, FormulaKind, Literal, Stable};
use super::packet::PacketFormula;
use super::real::{Precision, Real};
use super::wide::Simd;
use std::fmt;

/// One ray–cylinder kernel. Prints as `stable-f64`, `literal-f32`, ….
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Kernel {
    /// The formulation.
    pub formula: FormulaKind,
    /// The precision it computes in.
    pub precision: Precision,
}

impl Kernel {
    /// The default and accuracy reference.
    pub const STABLE_F64: Kernel = Kernel::new(FormulaKind::Stable, Precision::F64);
    /// The stable kernel in f32.
    pub const STABLE_F32: Kernel = Kernel::new(FormulaKind::Stable, Precision::F32);
    /// The textbook formulas in f64.
    pub const LITERAL_F64: Kernel = Kernel::new(FormulaKind::Literal, Precision::F64);
    /// The textbook formulas in f32.
    pub const LITERAL_F32: Kernel = Kernel::new(FormulaKind::Literal, Precision::F32);
    /// Every kernel, the reference first: the order of every table.
    pub const ALL: [Kernel; 4] = [
        Kernel::STABLE_F64,
        Kernel::STABLE_F32,
        Kernel::LITERAL_F64,
        Kernel::LITERAL_F32,
    ];

    /// `formula` in `precision`.
    pub const fn new(formula: FormulaKind, precision: Precision) -> Kernel {
        Kernel { formula, precision }
    }

    /// The kernel the types `T`, `F` are compiled for.
    pub fn of<T: Real, F: Formula>() -> Kernel {
        Kernel::new(F::KIND, T::PRECISION)
    }

    /// Whether it computes in f32.
    pub fn is_f32(self) -> bool {
        self.precision == Precision::F32
    }

    /// Unit roundoff of its precision.
    pub fn eps(self) -> f64 {
        match self.precision {
            Precision::F32 => f32::UNIT_ROUNDOFF,
            Precision::F64 => f64::UNIT_ROUNDOFF,
        }
    }

    /// Run `f` compiled for this kernel's types: the one `match` from the run-time choice
    /// to the generic code.
    pub(crate) fn dispatch<K: KernelFn>(self, f: K) -> K::Output {
        match (self.formula, self.precision) {
            (FormulaKind::Stable, Precision::F64) => f.call::<f64, Stable>(),
            (FormulaKind::Stable, Precision::F32) => f.call::<f32, Stable>(),
            (FormulaKind::Literal, Precision::F64) => f.call::<f64, Literal>(),
            (FormulaKind::Literal, Precision::F32) => f.call::<f32, Literal>(),
        }
    }
}

impl fmt::Display for Kernel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // `pad`, so that table columns (`{:<11}`) line up.
        f.pad(&format!(
            "{}-{}",
            self.formula.name(),
            self.precision.name()
        ))
    }
}

/// Code generic over the kernel's precision `T` and formulation `F`, run through
/// [`Kernel::dispatch`].
pub(crate) trait KernelFn {
    /// What the code returns.
    type Output;
    /// Run it for `T`, `F`.
    fn call<T: Simd, F: PacketFormula>(self) -> Self::Output;
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Names;
    impl KernelFn for Names {
        type Output = (&'static str, &'static str);
        fn call<T: Simd, F: PacketFormula>(self) -> Self::Output {
            (F::NAME, T::NAME)
        }
    }

    #[test]
    fn dispatch_names_and_of_agree() {
        let printed: Vec<String> = Kernel::ALL.iter().map(|k| k.to_string()).collect();
        assert_eq!(
            printed,
            ["stable-f64", "stable-f32", "literal-f64", "literal-f32"]
        );
        for k in Kernel::ALL {
            let (formula, precision) = k.dispatch(Names);
            assert_eq!(format!("{formula}-{precision}"), k.to_string());
        }
        assert_eq!(Kernel::of::<f32, Literal>(), Kernel::LITERAL_F32);
        assert_eq!(Kernel::of::<f64, Stable>(), Kernel::STABLE_F64);
        assert_eq!(Kernel::default(), Kernel::STABLE_F64);
        assert_eq!(format!("[{:<12}]", Kernel::STABLE_F32), "[stable-f32  ]");
    }
}
