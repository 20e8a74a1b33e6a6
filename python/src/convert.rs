//! Python values to and from what the library takes: JSON, AOV names, option values.

use cylaov::geometry::Kernel;
use cylaov::scene::Aov;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

/// A JSON value as Python objects (dicts, lists, floats, ints, strings, None).
pub(crate) fn json_to_py<'py>(
    py: Python<'py>,
    v: &serde_json::Value,
) -> PyResult<Bound<'py, PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Number(n) => match (n.as_u64(), n.as_i64()) {
            (Some(u), _) => u.into_pyobject(py)?.into_any(),
            (None, Some(i)) => i.into_pyobject(py)?.into_any(),
            _ => n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any(),
        },
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Array(a) => {
            let l = PyList::empty(py);
            for x in a {
                l.append(json_to_py(py, x)?)?;
            }
            l.into_any()
        }
        Value::Object(o) => {
            let d = PyDict::new(py);
            for (k, x) in o {
                d.set_item(k, json_to_py(py, x)?)?;
            }
            d.into_any()
        }
    })
}

/// A Python object as JSON text, through the standard `json` module (NaN refused).
pub(crate) fn py_to_json(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<String> {
    let json = obj.py().import("json")?;
    let kw = PyDict::new(obj.py());
    kw.set_item("allow_nan", false)?;
    json.call_method("dumps", (obj,), Some(&kw))
        .map_err(|e| PyValueError::new_err(format!("{what}: not JSON data: {e}")))?
        .extract()
}

pub(crate) fn parse_aov(name: &str, field: &str) -> PyResult<Aov> {
    Aov::parse(name).ok_or_else(|| {
        let all: Vec<_> = Aov::ALL.iter().map(|a| a.name()).collect();
        PyValueError::new_err(format!(
            "{field}: unknown AOV {name:?}; one of {}",
            all.join(", ")
        ))
    })
}

pub(crate) fn parse_aovs(aovs: &[String]) -> PyResult<Vec<Aov>> {
    let mut out = Vec::new();
    for (i, a) in aovs.iter().enumerate() {
        let aov = parse_aov(a, &format!("aovs[{i}]"))?;
        if !out.contains(&aov) {
            out.push(aov);
        }
    }
    if out.is_empty() {
        return Err(PyValueError::new_err("aovs: name at least one AOV"));
    }
    Ok(out)
}

/// `aovs=` as a list of names: one string is one name (as `cast_rays` takes it).
pub(crate) fn aov_names(obj: &Bound<'_, PyAny>) -> PyResult<Vec<String>> {
    names(obj, "aovs: an AOV name or a sequence of AOV names")
}

/// A parameter that takes one name or a sequence of names, as a list; else a `TypeError`
/// saying `what`.
pub(crate) fn names(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<String>> {
    if let Ok(s) = obj.extract::<String>() {
        return Ok(vec![s]);
    }
    obj.extract()
        .map_err(|_| PyTypeError::new_err(what.to_string()))
}

/// The value of keyword `keyword` named `name`; the library's refusal under Python's
/// spelling of the option (`precision: unknown value "f16": expected one of f32, f64`).
pub(crate) fn choice<T: cylaov::choice::Choice>(name: &str, keyword: &str) -> PyResult<T> {
    T::parse(name).map_err(|e| PyValueError::new_err(format!("{keyword}: {e}")))
}

pub(crate) fn kernel(precision: &str, formula: &str) -> PyResult<Kernel> {
    Ok(Kernel::new(
        choice(formula, "formula")?,
        choice(precision, "precision")?,
    ))
}
