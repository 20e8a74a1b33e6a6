//! Verification: the tools that check the product. [`compare`] is the per-pixel rule that
//! every check uses; [`reference`](mod@reference) renders a view with Mitsuba 3 and compares; [`oracle`]
//! is the double-double answer that [`stress`] measures the kernels against.

pub mod compare;
pub mod oracle;
pub mod reference;
pub mod stress;
