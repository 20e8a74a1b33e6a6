//! `cylaov.write_shards` and `cylaov.shard_count`: the tar shards of `batch --format
//! webdataset` from Python, so any engine (Ray, Dask, a process pool) can map tars over
//! workers and get the command line's bytes.

use crate::convert::{aov_names, choice, described, integer, kernel, names, parse_aovs, size};
use crate::errors::value_error;
use crate::pool::{run, run_stoppable, threads_arg};
use cylaov::dataset::batch::shards::{self, Member, ShardOptions, TarOutcome, TarSelection};
use cylaov::dataset::batch::{BatchOptions, ProgressMode};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyString};
use std::path::PathBuf;

// The signatures spell the default out: a literal is what `inspect.signature` can show
// (a constant's name shows as `...`).
const _: () = assert!(shards::DEFAULT_SHARD_SIZE == 1000);

/// The number of tar shards the views of `input` make at `shard_size` views a tar.
#[pyfunction]
#[pyo3(signature = (input, shard_size = 1000))]
pub fn shard_count(
    py: Python<'_>,
    input: PathBuf,
    #[pyo3(from_py_with = shard_size_arg)] shard_size: usize,
) -> PyResult<usize> {
    run(py, None, || shards::shard_count(&input, shard_size))?.map_err(value_error)
}

/// Write the tar shards `shards` (indices; `None`: all) of the views of `input` into `out`,
/// as `cylaov batch INPUT --out OUT --format webdataset` does; a summary dict. `force`
/// replaces a dataset `out` holds with other settings instead of refusing.
#[pyfunction]
#[pyo3(signature = (input, out, shards = None, shard_size = 1000,
    aovs = None, members = None, precision = "f64", formula = "stable",
    depth_scale = 1000.0, threads = None, force = false))]
#[allow(clippy::too_many_arguments)]
pub fn write_shards<'py>(
    py: Python<'py>,
    input: PathBuf,
    out: PathBuf,
    #[pyo3(from_py_with = shards_arg)] shards: Option<Vec<usize>>,
    #[pyo3(from_py_with = shard_size_arg)] shard_size: usize,
    aovs: Option<&Bound<'py, PyAny>>,
    members: Option<&Bound<'py, PyAny>>,
    precision: &str,
    formula: &str,
    depth_scale: f64,
    #[pyo3(from_py_with = threads_arg)] threads: Option<usize>,
    force: bool,
) -> PyResult<Bound<'py, PyDict>> {
    // The command line refuses an empty `--out`; here it would be the working folder.
    if out.as_os_str().is_empty() {
        return Err(PyValueError::new_err(
            "out: must name a folder, got '' (use '.' for the working folder)",
        ));
    }
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

/// `shard_size=`: views a tar, >= 1.
fn shard_size_arg(obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    size(obj, "shard_size", 1)
}

/// `shards=`: `None` (every tar) or tar indices, each once (the library refuses an empty
/// list, and names the failures file by the sorted tars whatever the list's order).
fn shards_arg(obj: &Bound<'_, PyAny>) -> PyResult<Option<Vec<usize>>> {
    if obj.is_none() {
        return Ok(None);
    }
    let what = || {
        PyTypeError::new_err(format!(
            "shards: a sequence of tar indices or None, got {}",
            described(obj)
        ))
    };
    if obj.is_instance_of::<PyString>() || obj.is_instance_of::<PyBytes>() {
        return Err(what());
    }
    let mut list = Vec::new();
    for (i, item) in obj.try_iter().map_err(|_| what())?.enumerate() {
        let j = integer(&item?, &format!("shards[{i}]"), 0, usize::MAX as i128)?;
        list.push(j as usize);
    }
    list.sort_unstable();
    let mut twice: Vec<usize> = list
        .windows(2)
        .filter(|w| w[0] == w[1])
        .map(|w| w[0])
        .collect();
    if !twice.is_empty() {
        twice.dedup();
        let named: Vec<String> = twice.iter().map(|j| j.to_string()).collect();
        return Err(PyValueError::new_err(format!(
            "shards: tar {} listed more than once",
            named.join(", ")
        )));
    }
    Ok(Some(list))
}

/// Add this file's functions to the module.
pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(shard_count, m)?)?;
    m.add_function(wrap_pyfunction!(write_shards, m)?)?;
    Ok(())
}
