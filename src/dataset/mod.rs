//! Datasets: [`generate`] makes seeded scene files, [`batch`] renders folders or manifests
//! of them into a resumable, shardable dataset; [`names`] lists every file name cylaov
//! writes.

pub mod batch;
pub mod generate;
pub mod names;
