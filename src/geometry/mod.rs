//! Geometry: the float abstraction and the ray–cylinder kernels. No IO, no scene files.

pub mod cylinder;
pub mod packet;
pub mod real;
pub mod wide;

pub use cylinder::{BasicHit, Cylinder, Formula, Literal, Prepared, Stable, Surface};
pub use packet::{LANES, NO_HIT, Packet};
pub use real::Real;
