//! Geometry: the float abstraction and the ray–cylinder kernels. No IO, no scene files.

pub mod cylinder;
pub mod kernel;
pub(crate) mod packet;
pub mod real;
pub(crate) mod wide;

pub use cylinder::{BasicHit, Cylinder, Formula, FormulaKind, Literal, Prepared, Stable, Surface};
pub use kernel::Kernel;
pub use real::{Precision, Real};
