//! `cylaov.write_shards` and `cylaov.shard_count`: the tar shards of `batch --format
//! webdataset` from Python, so any engine (Ray, Dask, a process pool) can map tars over
//! workers and get the command line's bytes.

use crate::convert::{aov_names, choice, kernel, names, parse_aovs};
use crate::errors::value_error;
use crate::pool::{run, run_stoppable};
use cylaov::dataset::batch::shards::{self, Member, ShardOptions, TarOutcome, TarSelection};
use cylaov::dataset::batch::{BatchOptions, ProgressMode};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// The number of tar shards the views of `input` make at `shard_size` views a tar.
#[pyfunction]
#[pyo3(signature = (input, shard_size = shards::DEFAULT_SHARD_SIZE))]
pub fn shard_count(py: Python<'_>, input: PathBuf, shard_size: usize) -> PyResult<usize> {
    run(py, None, || shards::shard_count(&input, shard_size))?.map_err(value_error)
}

/// Write the tar shards `shards` (indices; `None`: all) of the views of `input` into `out`,
/// as `cylaov batch INPUT --out OUT --format webdataset` does; a summary dict. `force`
/// replaces a dataset `out` holds with other settings instead of refusing.
#[pyfunction]
#[pyo3(signature = (input, out, shards = None, shard_size = shards::DEFAULT_SHARD_SIZE,
    aovs = None, members = None, precision = "f64", formula = "stable",
    depth_scale = 1000.0, threads = None, force = false))]
#[allow(clippy::too_many_arguments)]
pub fn write_shards<'py>(
    py: Python<'py>,
    input: PathBuf,
    out: PathBuf,
    shards: Option<Vec<usize>>,
    shard_size: usize,
    aovs: Option<&Bound<'py, PyAny>>,
    members: Option<&Bound<'py, PyAny>>,
    precision: &str,
    formula: &str,
    depth_scale: f64,
    threads: Option<usize>,
    force: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let k = kernel(precision, formula)?;
    let members = match members {
        None => Vec::new(),
        Some(m) => names(
            m,
            "members: \"exr\", \"depth.png\", \"ply\" or a sequence of them",
        )?,
    };
    let members = members
        .iter()
        .enumerate()
        .map(|(i, m)| choice::<Member>(m, &format!("members[{i}]")))
        .collect::<PyResult<Vec<_>>>()?;
    let opts = BatchOptions {
        aovs: aovs.map(|a| parse_aovs(&aov_names(a)?)).transpose()?,
        precision: k.precision,
        formula: k.formula,
        depth_scale,
        ..BatchOptions::default()
    };
    let sopts = ShardOptions {
        shard_size,
        members,
        force,
    };
    let selection = match shards {
        Some(list) => TarSelection::List(list),
        None => TarSelection::Shard(cylaov::dataset::batch::Shard::ALL),
    };
    let summary = run_stoppable(py, threads, |stop| {
        shards::write_shards_until(
            &input,
            &out,
            &selection,
            &opts,
            &sopts,
            ProgressMode::Off,
            stop,
            None,
        )
    })?
    .map_err(value_error)?;
    let d = PyDict::new(py);
    let pick = |o: TarOutcome| -> Vec<usize> {
        summary
            .outcomes
            .iter()
            .filter(|x| x.1 == o)
            .map(|x| x.0)
            .collect()
    };
    d.set_item("tars", summary.tars)?;
    d.set_item("written", pick(TarOutcome::Written))?;
    d.set_item("skipped", pick(TarOutcome::Skipped))?;
    let failed: Vec<(String, String)> = summary
        .failures
        .iter()
        .map(|f| (f.key.clone(), f.error.clone()))
        .collect();
    d.set_item("failed", failed)?;
    d.set_item("index_written", summary.index_written)?;
    d.set_item("problems", summary.problems.clone())?;
    Ok(d)
}

/// Add this file's functions to the module.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(shard_count, m)?)?;
    m.add_function(wrap_pyfunction!(write_shards, m)?)?;
    Ok(())
}
