//! Datasets: [`generate`] makes seeded scene files, [`batch`] renders folders or manifests
//! of them into a resumable, shardable dataset.

pub mod batch;
pub mod generate;
