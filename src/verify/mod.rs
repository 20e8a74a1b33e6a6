//! Verification: the tools that check the product. [`compare`] is the per-pixel rule that
//! every check uses (identity by cylinder and part, seams, float32 conditioning bounds);
//! [`reference`](mod@reference) is the one check against Mitsuba 3 behind `cylaov verify`,
//! `batch --verify-fraction` and the reference tests; [`oracle`] is the double-double answer
//! that [`stress`] measures the kernels against and [`arbiter`] decides disagreements by.

pub mod arbiter;
pub mod compare;
pub mod oracle;
pub mod reference;
pub mod report;
pub mod repro;
pub mod stress;
