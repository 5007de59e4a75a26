//! Python arguments -> owned Rust values, one parameter at a time, with
//! the type checks a Python caller expects (no str for a number, no bool for
//! an int).

use pyo3::exceptions::PyOverflowError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use super::{Kind, Param};
use crate::invalid::Invalid;

/// A Python argument converted to owned Rust data, before it is borrowed
/// into [`Args`](lluav_core::Args).
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// An optional parameter left out (or given as `None`).
    Absent,
    /// A number.
    Float(f32),
    /// A non-negative integer (range-checked later, per grammar).
    Int(u64),
    /// A flag.
    Flag(bool),
    /// Text.
    Str(String),
    /// Numbers.
    Floats(Vec<f32>),
    /// Integers.
    Ints(Vec<u64>),
    /// A landing point.
    Land([f32; 3]),
    /// A JSON payload (serialised).
    Json(String),
}

fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map_or_else(|_| "object".to_owned(), |n| n.to_string())
}

/// A number: a float, an int, or anything else with `__float__` (numpy's
/// scalars), but not a bool or text.
fn float(name: &str, obj: &Bound<'_, PyAny>) -> Result<f32, Invalid> {
    let wrong_type = || Invalid::new(format!("{name} must be a number, not {}", type_name(obj)));
    if obj.is_instance_of::<PyBool>() || obj.is_instance_of::<PyString>() {
        return Err(wrong_type());
    }
    match obj.extract::<f64>() {
        // The protocol carries f32; a value beyond its range becomes
        // infinite and is refused by the core as not finite.
        #[allow(clippy::cast_possible_truncation)]
        Ok(v) => Ok(v as f32),
        Err(e) if e.is_instance_of::<PyOverflowError>(obj.py()) => {
            Err(Invalid::new(format!("{name} is too large")))
        }
        Err(_) => Err(wrong_type()),
    }
}

/// A non-negative integer: an int or anything else with `__index__`
/// (numpy's integers), but not a bool or a float.
fn int(name: &str, obj: &Bound<'_, PyAny>) -> Result<u64, Invalid> {
    let wrong_type = || Invalid::new(format!("{name} must be an int, not {}", type_name(obj)));
    if obj.is_instance_of::<PyBool>() {
        return Err(wrong_type());
    }
    match obj.extract::<u64>() {
        Ok(v) => Ok(v),
        Err(e) if e.is_instance_of::<PyOverflowError>(obj.py()) => Err(Invalid::new(format!(
            "{name} must be an integer >= 0 that fits 32 bits"
        ))),
        Err(_) => Err(wrong_type()),
    }
}

fn text(name: &str, obj: &Bound<'_, PyAny>) -> Result<String, Invalid> {
    match obj.cast::<PyString>() {
        Ok(s) => s
            .to_cow()
            .map(|c| c.into_owned())
            .map_err(|_| Invalid::new(format!("{name} is not valid text"))),
        Err(_) => Err(Invalid::new(format!(
            "{name} must be a str, not {}",
            type_name(obj)
        ))),
    }
}

fn flag(name: &str, obj: &Bound<'_, PyAny>) -> Result<bool, Invalid> {
    if obj.is_instance_of::<PyBool>() {
        return obj
            .extract()
            .map_err(|_| Invalid::new(format!("{name} must be a bool")));
    }
    match obj.extract::<i64>() {
        Ok(0) if obj.is_instance_of::<PyInt>() => Ok(false),
        Ok(1) if obj.is_instance_of::<PyInt>() => Ok(true),
        _ => Err(Invalid::new(format!("{name} must be True or False"))),
    }
}

/// A parameter value as the text the backend reads: booleans as the
/// protocol's `1`/`0`, numbers in their shortest round-trip form.
fn param_value(name: &str, obj: &Bound<'_, PyAny>) -> Result<String, Invalid> {
    if obj.is_instance_of::<PyBool>() {
        Ok(if flag(name, obj)? { "1" } else { "0" }.to_owned())
    } else if obj.is_instance_of::<PyInt>() {
        let v: i128 = obj
            .extract()
            .map_err(|_| Invalid::new(format!("{name} is too large")))?;
        Ok(v.to_string())
    } else if obj.is_instance_of::<PyFloat>() {
        let v: f64 = obj
            .extract()
            .map_err(|_| Invalid::new(format!("{name} must be a number")))?;
        if v.is_finite() {
            Ok(format!("{v:?}"))
        } else {
            Err(Invalid::new(format!("{name} must be a finite number")))
        }
    } else {
        text(name, obj).map_err(|_| {
            Invalid::new(format!(
                "{name} must be a str, int, float or bool, not {}",
                type_name(obj)
            ))
        })
    }
}

/// The items of a list, tuple or other iterable that is not text or a mapping.
fn items<'py>(name: &str, obj: &Bound<'py, PyAny>, what: &str) -> Result<Vec<Bound<'py, PyAny>>, Invalid> {
    let not_sequence = obj.is_instance_of::<PyString>() || obj.is_instance_of::<PyDict>();
    let iter = match obj.try_iter() {
        Ok(iter) if !not_sequence => iter,
        _ => {
            return Err(Invalid::new(format!(
                "{name} must be a sequence of {what}, not {}",
                type_name(obj)
            )));
        }
    };
    iter.collect::<PyResult<Vec<_>>>()
        .map_err(|_| Invalid::new(format!("{name} could not be iterated")))
}

fn land_point(name: &str, obj: &Bound<'_, PyAny>) -> Result<[f32; 3], Invalid> {
    let items = items(name, obj, "numbers")?;
    match items.as_slice() {
        [x, y, yaw] => Ok([float(name, x)?, float(name, y)?, float(name, yaw)?]),
        _ => Err(Invalid::new(format!("{name} must be three numbers (x, y, yaw)"))),
    }
}

/// `json.dumps`, compact, refusing NaN and infinities (which JSON has not).
fn json_dumps(py: Python<'_>, obj: &Bound<'_, PyAny>) -> PyResult<String> {
    static DUMPS: PyOnceLock<Py<PyAny>> = PyOnceLock::new();
    let dumps = DUMPS.import(py, "json", "dumps")?;
    let kwargs = PyDict::new(py);
    kwargs.set_item("separators", (",", ":"))?;
    kwargs.set_item("allow_nan", false)?;
    kwargs.set_item("ensure_ascii", false)?;
    dumps.call((obj,), Some(&kwargs))?.extract()
}

fn payload(name: &str, obj: &Bound<'_, PyAny>) -> Result<Value, Invalid> {
    if obj.is_instance_of::<PyString>() {
        return text(name, obj).map(Value::Str);
    }
    if obj.is_instance_of::<PyDict>() || obj.is_instance_of::<PyList>() || obj.is_instance_of::<PyTuple>() {
        return json_dumps(obj.py(), obj)
            .map(Value::Json)
            .map_err(|e| Invalid::new(format!("{name} cannot be sent as JSON: {e}")));
    }
    Err(Invalid::new(format!(
        "{name} must be a dict or list (sent as JSON) or a str (a path), not {}",
        type_name(obj)
    )))
}

/// Converts one Python argument (`None` for an optional one left out).
pub fn convert(param: &Param, obj: Option<&Bound<'_, PyAny>>) -> Result<Value, Invalid> {
    let name = param.name;
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return if param.optional {
            Ok(Value::Absent)
        } else {
            Err(Invalid::new(format!("{name} is required")))
        };
    };
    Ok(match param.kind {
        Kind::Float => Value::Float(float(name, obj)?),
        Kind::Int => Value::Int(int(name, obj)?),
        Kind::Flag => Value::Flag(flag(name, obj)?),
        Kind::Str => Value::Str(text(name, obj)?),
        Kind::Value => Value::Str(param_value(name, obj)?),
        Kind::Floats => Value::Floats(
            items(name, obj, "numbers")?
                .iter()
                .map(|o| float(name, o))
                .collect::<Result<_, _>>()?,
        ),
        Kind::Ints => Value::Ints(
            items(name, obj, "integers")?
                .iter()
                .map(|o| int(name, o))
                .collect::<Result<_, _>>()?,
        ),
        Kind::LandPoint => Value::Land(land_point(name, obj)?),
        Kind::Payload => payload(name, obj)?,
    })
}
