//! Owned values -> the core's [`Args`] of a grammar, and parsed [`Args`] ->
//! Python values, in the order of [`super::params`].

use lluav_core::{Args, Grammar, LandPoint, MAX_HEIGHTS, MAX_WAYPOINT_IDS, Payload, Point, Pose};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBool, PyFloat, PyList, PyString, PyTuple};

use super::Param;
use super::convert::Value;
use crate::invalid::Invalid;

/// The converted values of one call, read by parameter position; the
/// parameter names go into the reasons.
struct Values<'a> {
    params: &'a [Param],
    values: &'a [Value],
}

impl<'a> Values<'a> {
    fn name(&self, i: usize) -> &'static str {
        self.params.get(i).map_or("argument", |p| p.name)
    }

    /// A value of the wrong variant cannot come from `convert`; it is
    /// reported rather than trusted.
    fn mismatch(&self) -> Invalid {
        Invalid::new("internal error: argument kinds do not match the grammar".to_owned())
    }

    fn get(&self, i: usize) -> Result<&'a Value, Invalid> {
        self.values.get(i).ok_or_else(|| self.mismatch())
    }

    fn float(&self, i: usize) -> Result<f32, Invalid> {
        match self.get(i)? {
            Value::Float(v) => Ok(*v),
            _ => Err(self.mismatch()),
        }
    }

    fn opt_float(&self, i: usize) -> Result<Option<f32>, Invalid> {
        match self.get(i)? {
            Value::Absent => Ok(None),
            _ => self.float(i).map(Some),
        }
    }

    fn flag(&self, i: usize) -> Result<bool, Invalid> {
        match self.get(i)? {
            Value::Flag(on) => Ok(*on),
            _ => Err(self.mismatch()),
        }
    }

    fn opt_flag(&self, i: usize) -> Result<Option<bool>, Invalid> {
        match self.get(i)? {
            Value::Absent => Ok(None),
            _ => self.flag(i).map(Some),
        }
    }

    fn str(&self, i: usize) -> Result<&'a str, Invalid> {
        match self.get(i)? {
            Value::Str(s) => Ok(s),
            _ => Err(self.mismatch()),
        }
    }

    fn opt_str(&self, i: usize) -> Result<Option<&'a str>, Invalid> {
        match self.get(i)? {
            Value::Absent => Ok(None),
            _ => self.str(i).map(Some),
        }
    }

    fn u32(&self, i: usize) -> Result<u32, Invalid> {
        match self.get(i)? {
            Value::Int(v) => u32_of(self.name(i), *v),
            _ => Err(self.mismatch()),
        }
    }

    fn opt_u32(&self, i: usize) -> Result<Option<u32>, Invalid> {
        match self.get(i)? {
            Value::Absent => Ok(None),
            _ => self.u32(i).map(Some),
        }
    }

    fn pwm(&self, i: usize) -> Result<u16, Invalid> {
        match self.get(i)? {
            Value::Int(v) => {
                u16::try_from(*v).map_err(|_| Invalid::new(format!("{} must be 0..65535", self.name(i))))
            }
            _ => Err(self.mismatch()),
        }
    }

    fn pose(&self) -> Result<Pose, Invalid> {
        Ok(Pose {
            x: self.float(0)?,
            y: self.float(1)?,
            z: self.float(2)?,
            yaw: self.float(3)?,
        })
    }

    fn heights(&self, i: usize) -> Result<heapless::Vec<f32, MAX_HEIGHTS>, Invalid> {
        match self.get(i)? {
            Value::Floats(h) => list(self.name(i), h),
            _ => Err(self.mismatch()),
        }
    }

    fn land(&self, i: usize) -> Result<Option<LandPoint>, Invalid> {
        match self.get(i)? {
            Value::Land([x, y, yaw]) => Ok(Some(LandPoint {
                x: *x,
                y: *y,
                yaw: *yaw,
            })),
            Value::Absent => Ok(None),
            _ => Err(self.mismatch()),
        }
    }

    fn payload(&self, i: usize) -> Result<Payload<'a>, Invalid> {
        match self.get(i)? {
            Value::Json(j) => Ok(Payload::Json(j)),
            Value::Str(p) => Ok(Payload::Path(p)),
            _ => Err(self.mismatch()),
        }
    }

    fn wp_ids(&self, i: usize) -> Result<heapless::Vec<u32, MAX_WAYPOINT_IDS>, Invalid> {
        match self.get(i)? {
            Value::Ints(ids) => {
                let ids = ids
                    .iter()
                    .map(|&id| u32_of(self.name(i), id))
                    .collect::<Result<Vec<u32>, _>>()?;
                list(self.name(i), &ids)
            }
            _ => Err(self.mismatch()),
        }
    }
}

fn u32_of(name: &str, v: u64) -> Result<u32, Invalid> {
    u32::try_from(v).map_err(|_| Invalid::new(format!("{name} must fit 32 bits")))
}

fn list<T: Copy, const N: usize>(name: &str, values: &[T]) -> Result<heapless::Vec<T, N>, Invalid> {
    heapless::Vec::from_slice(values).map_err(|_| Invalid::new(format!("{name} holds more than {N} items")))
}

/// Builds the core's arguments of `grammar` from converted values, in the
/// order of `params`.
pub fn build<'a>(grammar: Grammar, params: &'a [Param], values: &'a [Value]) -> Result<Args<'a>, Invalid> {
    let v = Values { params, values };
    Ok(match grammar {
        Grammar::None => Args::None,
        Grammar::Flag => Args::Flag(v.flag(0)?),
        Grammar::OptCount => Args::OptCount(v.opt_u32(0)?),
        Grammar::Pwm => Args::Pwm(v.pwm(0)?),
        Grammar::Amount => Args::Amount(v.float(0)?.into()),
        Grammar::OptAmount => Args::OptAmount(v.opt_float(0)?.map(Into::into)),
        Grammar::Angle => Args::Angle(v.float(0)?),
        Grammar::Name => Args::Name(v.str(0)?),
        Grammar::OptName => Args::OptName(v.opt_str(0)?),
        Grammar::Path => Args::Path(v.str(0)?),
        Grammar::Text => Args::Text(v.str(0)?),
        Grammar::TaskName => Args::TaskName(v.str(0)?),
        Grammar::Secret => Args::Secret(v.str(0)?),
        Grammar::NewPassword => Args::NewPassword(v.str(0)?),
        Grammar::ParamName => Args::ParamName(v.str(0)?),
        Grammar::SetParam => Args::SetParam {
            name: v.str(0)?,
            value: v.str(1)?,
        },
        Grammar::Setpoint => Args::Setpoint(v.pose()?),
        Grammar::Pose => Args::Pose(v.pose()?),
        Grammar::Point => Args::Point(Point {
            x: v.float(0)?,
            y: v.float(1)?,
            z: v.float(2)?,
        }),
        Grammar::Zyhk => Args::Zyhk {
            heights: v.heights(0)?,
            land: v.land(1)?,
        },
        Grammar::Mission => Args::Mission {
            ext_id: v.u32(0)?,
            payload: v.payload(1)?,
        },
        Grammar::MwExec => Args::MwExec {
            ext_id: v.u32(0)?,
            wp_ids: v.wp_ids(1)?,
        },
        Grammar::Ai1Mission => Args::Ai1Mission {
            task_id: v.str(0)?,
            file: v.str(1)?,
        },
        Grammar::Override => Args::Override(v.opt_flag(0)?.unwrap_or(false)),
    })
}

/// An `f32` as the Python float whose shortest text is the same
/// (`0.1f32` becomes `0.1`, not `0.10000000149011612`).
fn py_float(v: f32) -> f64 {
    format!("{v}").parse().unwrap_or(f64::from(v))
}

fn json_loads<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    static LOADS: PyOnceLock<Py<PyAny>> = PyOnceLock::new();
    LOADS.import(py, "json", "loads")?.call1((text,))
}

/// The values of parsed arguments, one per parameter of [`super::params`], in order.
pub fn values<'py>(py: Python<'py>, args: &Args<'_>) -> PyResult<Vec<Bound<'py, PyAny>>> {
    let none = || py.None().into_bound(py);
    let float = |v: f32| PyFloat::new(py, py_float(v)).into_any();
    let floats = |vs: &[f32]| PyList::new(py, vs.iter().map(|&v| py_float(v))).map(Bound::into_any);
    let s = |v: &str| PyString::new(py, v).into_any();
    let int = |v: u64| v.into_pyobject(py).map(Bound::into_any);
    Ok(match args {
        Args::None => vec![],
        Args::Flag(on) => vec![PyBool::new(py, *on).to_owned().into_any()],
        Args::OptCount(n) => vec![n.map_or(Ok(none()), |n| int(n.into()))?],
        Args::Pwm(n) => vec![int((*n).into())?],
        Args::Amount(v) => vec![float(v.value())],
        Args::Angle(v) => vec![float(*v)],
        Args::OptAmount(v) => vec![v.map_or_else(none, |v| float(v.value()))],
        Args::Name(v)
        | Args::Path(v)
        | Args::Text(v)
        | Args::TaskName(v)
        | Args::Secret(v)
        | Args::NewPassword(v)
        | Args::ParamName(v) => vec![s(v)],
        Args::OptName(v) => vec![v.map_or_else(none, s)],
        Args::SetParam { name, value } => vec![s(name), s(value)],
        Args::Setpoint(p) | Args::Pose(p) => vec![float(p.x), float(p.y), float(p.z), float(p.yaw)],
        Args::Point(p) => vec![float(p.x), float(p.y), float(p.z)],
        Args::Zyhk { heights, land } => vec![
            floats(heights)?,
            match land {
                Some(l) => PyTuple::new(py, [py_float(l.x), py_float(l.y), py_float(l.yaw)])?.into_any(),
                None => none(),
            },
        ],
        Args::Mission { ext_id, payload } => vec![
            int((*ext_id).into())?,
            match payload {
                Payload::Json(j) => json_loads(py, j)?,
                Payload::Path(p) => s(p),
            },
        ],
        Args::MwExec { ext_id, wp_ids } => vec![
            int((*ext_id).into())?,
            PyList::new(py, wp_ids.iter().copied())?.into_any(),
        ],
        Args::Ai1Mission { task_id, file } => vec![s(task_id), s(file)],
        Args::Override(on) => vec![PyBool::new(py, *on).to_owned().into_any()],
    })
}
