//! Geometry: the float abstraction and the ray–cylinder kernels. No IO, no scene files.

pub mod cylinder;
pub(crate) mod packet;
pub mod real;
pub(crate) mod wide;

pub use cylinder::{BasicHit, Cylinder, Formula, Literal, Prepared, Stable, Surface};
pub use real::Real;
