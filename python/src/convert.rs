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
            "{field}: unknown AOV {}; one of {}",
            shorten(&format!("{name:?}")),
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
/// A long value is shortened, as every message of the package shortens what it echoes.
pub(crate) fn choice<T: cylaov::choice::Choice>(name: &str, keyword: &str) -> PyResult<T> {
    T::parse(name)
        .map_err(|e| PyValueError::new_err(format!("{keyword}: {}", shorten(&e.to_string()))))
}

/// `text` with long runs cut ([`cylaov::scene::strict::shorten`]), so a value echoed in a
/// message cannot flood the terminal.
pub(crate) fn shorten(text: &str) -> String {
    cylaov::scene::strict::shorten(text)
}

/// Optional `str` argument `name` (`None`: absent), else a `TypeError` naming it and the
/// value: pyo3's own refusal names neither.
pub(crate) fn opt_text(obj: Option<&Bound<'_, PyAny>>, name: &str) -> PyResult<Option<String>> {
    match obj {
        None => Ok(None),
        Some(o) if o.is_none() => Ok(None),
        Some(o) => o.extract::<String>().map(Some).map_err(|_| {
            PyTypeError::new_err(format!("{name}: must be a str, got {}", described(o)))
        }),
    }
}

/// Optional `bool` argument `name` (`None`: absent): a `bool` (or numpy's), not a number
/// standing for one; else a `TypeError` naming it and the value.
pub(crate) fn opt_flag(obj: Option<&Bound<'_, PyAny>>, name: &str) -> PyResult<Option<bool>> {
    match obj {
        None => Ok(None),
        Some(o) if o.is_none() => Ok(None),
        Some(o) => o.extract::<bool>().map(Some).map_err(|_| {
            PyTypeError::new_err(format!("{name}: must be a bool, got {}", described(o)))
        }),
    }
}

/// Real-number argument `name` (an `int`, a `float`, a numpy real; not a string), else a
/// `TypeError` naming it and the value.
pub(crate) fn real(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f64> {
    let text = obj.is_instance_of::<pyo3::types::PyString>()
        || obj.is_instance_of::<pyo3::types::PyBytes>();
    match obj.extract::<f64>() {
        Ok(x) if !text => Ok(x),
        _ => Err(PyTypeError::new_err(format!(
            "{name}: must be a real number, got {}",
            described(obj)
        ))),
    }
}

/// Integer argument `name` within `lo..=hi`, taken as Python's `operator.index` takes it
/// (an `int`, a numpy integer, a `bool`; not a float, whose fraction would be dropped, nor
/// a string). pyo3's own conversion to an unsigned type raises `OverflowError` or a
/// `TypeError` that name neither the argument nor the value:
/// `shard_size: must be >= 1, got -1`, `shard_size: must be an integer, got float 1.5`.
pub(crate) fn integer(obj: &Bound<'_, PyAny>, name: &str, lo: i128, hi: i128) -> PyResult<i128> {
    let py = obj.py();
    let int = py
        .import("operator")?
        .getattr("index")?
        .call1((obj,))
        .map_err(|_| {
            PyTypeError::new_err(format!(
                "{name}: must be an integer, got {}",
                described(obj)
            ))
        })?;
    let v = int.extract::<i128>().ok();
    if let Some(v) = v
        && (lo..=hi).contains(&v)
    {
        return Ok(v);
    }
    // Beyond i128 is beyond any bound, on the side of its sign.
    let below = match v {
        Some(v) => v < lo,
        None => int.lt(0)?,
    };
    // As the library words its bounds (`threads: must be in 1..=1024, got 0`).
    let want = if hi <= i128::from(u32::MAX) {
        format!("in {lo}..={hi}")
    } else if below {
        format!(">= {lo}")
    } else {
        format!("<= {hi}")
    };
    // Python refuses to print an int of more than 4300 digits.
    let got = match int.str() {
        Ok(s) => cylaov::scene::strict::shorten(&s.to_string_lossy()),
        Err(_) => format!("an integer of {} bits", int.call_method0("bit_length")?),
    };
    Err(PyValueError::new_err(format!(
        "{name}: must be {want}, got {got}"
    )))
}

/// [`integer`] as a `usize`, `lo` and up.
pub(crate) fn size(obj: &Bound<'_, PyAny>, name: &str, lo: usize) -> PyResult<usize> {
    // `usize` fits in i128 and back on every target.
    Ok(integer(obj, name, lo as i128, usize::MAX as i128)? as usize)
}

/// A `camera=` argument (`#[pyo3(from_py_with = camera_arg)]`): an index >= 0; one past
/// the scene's cameras is refused where the scene is at hand (`IndexError`).
pub(crate) fn camera_arg(obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    size(obj, "camera", 0)
}

/// A seed (`#[pyo3(from_py_with = seed_arg)]`): any integer of 64 bits, >= 0.
pub(crate) fn seed_arg(obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    Ok(integer(obj, "seed", 0, i128::from(u64::MAX))? as u64)
}

/// A value for a message: its type and its (shortened) repr, `float 1.5`, `str '3'`.
pub(crate) fn described(obj: &Bound<'_, PyAny>) -> String {
    let ty = obj.get_type().name().map_or_else(
        |_| "object".to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    match obj.repr() {
        Ok(r) => format!(
            "{ty} {}",
            cylaov::scene::strict::shorten(&r.to_string_lossy())
        ),
        Err(_) => ty,
    }
}

pub(crate) fn kernel(precision: &str, formula: &str) -> PyResult<Kernel> {
    Ok(Kernel::new(
        choice(formula, "formula")?,
        choice(precision, "precision")?,
    ))
}
