//! `lluav.parse(frame)`: a frame read by the core, as a Python object.

use lluav_core::{Command, ParseError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::grammar;
use crate::invalid::{self, Invalid};

/// A frame parsed by lluav-core: which command, and its arguments under
/// the names of the client method's parameters.
#[pyclass(name = "Command", module = "lluav", frozen)]
pub struct PyCommand {
    /// The command's name.
    #[pyo3(get)]
    name: &'static str,
    /// The command's id.
    #[pyo3(get)]
    id: u8,
    /// The arguments, by parameter name (absent optional ones are `None`).
    #[pyo3(get)]
    args: Py<PyDict>,
    /// The canonical frame for this command (what the client would send).
    #[pyo3(get)]
    frame: String,
}

#[pymethods]
impl PyCommand {
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let args = self.args.bind(py).repr()?;
        Ok(format!(
            "Command(name={:?}, id={}, args={args})",
            self.name, self.id
        ))
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        match other.cast::<PyCommand>() {
            Ok(o) => {
                let o = o.get();
                Ok(self.id == o.id && self.frame == o.frame)
            }
            Err(_) => Ok(false),
        }
    }

    fn __hash__(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        self.frame.hash(&mut h);
        h.finish()
    }
}

/// The Python object for a command the core has parsed.
pub fn to_python(py: Python<'_>, command: &Command<'_>) -> PyResult<PyCommand> {
    let spec = command.id().spec();
    let names = grammar::params(spec);
    let values = grammar::args::values(py, command.args())?;
    let args = PyDict::new(py);
    for (param, value) in names.iter().zip(values) {
        args.set_item(param.name, value)?;
    }
    Ok(PyCommand {
        name: spec.name(),
        id: spec.id.into(),
        args: args.unbind(),
        frame: command.to_string(),
    })
}

/// Parses a frame exactly as the server will.
pub fn parse(py: Python<'_>, frame: &str) -> PyResult<PyCommand> {
    match lluav_core::parse(frame) {
        Ok(command) => to_python(py, &command),
        Err(ParseError::InvalidArgs(id, why)) => Err(Invalid::from(why).into_err(py, id.spec())),
        // An empty frame or an unknown name (and whatever else the core may
        // one day refuse before it knows the command).
        Err(e) => Err(invalid::unknown(py, e.to_string())),
    }
}
