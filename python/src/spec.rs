//! The command table as Python objects: `lluav.COMMANDS` holds one
//! [`PySpec`] per row of the core's `TABLE`, in id order.

use lluav_core::{Spec, TABLE};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use crate::grammar::{self, Param};

/// One parameter of a command's Python method.
#[pyclass(name = "Param", module = "lluav", frozen, eq)]
#[derive(Clone, PartialEq, Eq)]
pub struct PyParam {
    /// Its name.
    #[pyo3(get)]
    name: &'static str,
    /// Its type annotation, e.g. `float` or `Sequence[int]`.
    #[pyo3(get)]
    annotation: &'static str,
    /// Whether it may be left out (it then defaults to `None`).
    #[pyo3(get)]
    optional: bool,
}

impl From<&Param> for PyParam {
    fn from(p: &Param) -> Self {
        PyParam {
            name: p.name,
            annotation: p.kind.annotation(),
            optional: p.optional,
        }
    }
}

#[pymethods]
impl PyParam {
    fn __repr__(&self) -> String {
        format!(
            "Param(name={:?}, annotation={:?}, optional={})",
            self.name,
            self.annotation,
            if self.optional { "True" } else { "False" }
        )
    }
}

/// One command of the protocol: a row of lluav-core's command table.
#[pyclass(name = "Spec", module = "lluav", frozen)]
pub struct PySpec {
    spec: &'static Spec,
    params: Py<PyTuple>,
}

impl PySpec {
    /// The core's row.
    pub fn spec(&self) -> &'static Spec {
        self.spec
    }
}

#[pymethods]
impl PySpec {
    /// The name on the wire, and of the client method.
    #[getter]
    fn name(&self) -> &'static str {
        self.spec.name()
    }

    /// The stable id sent back as `cmd`.
    #[getter]
    fn id(&self) -> u8 {
        self.spec.id.into()
    }

    /// The usage line, e.g. `set_sp_ned x:y:z:yaw`.
    #[getter]
    fn usage(&self) -> &'static str {
        self.spec.usage
    }

    /// One line saying what the command does.
    #[getter]
    fn summary(&self) -> &'static str {
        self.spec.summary()
    }

    /// The heading it stands under in the specification's Command
    /// Reference, as the core names it (`Flight`, `Mission`, ...).
    #[getter]
    fn section(&self) -> String {
        format!("{:?}", self.spec.section)
    }

    /// The core's grammar name (`Setpoint`, `MwExec`, ...).
    #[getter]
    fn grammar(&self) -> String {
        format!("{:?}", self.spec.grammar)
    }

    /// `runOnArm`: whether it may run while the vehicle is armed.
    #[getter]
    fn run_on_arm(&self) -> bool {
        self.spec.flags.run_on_arm()
    }

    /// `runInLock`: whether a non-admin session may run it in lock mode.
    #[getter]
    fn run_in_lock(&self) -> bool {
        self.spec.flags.run_in_lock()
    }

    /// Whether only an admin session may run it.
    #[getter]
    fn admin_only(&self) -> bool {
        self.spec.flags.admin_only()
    }

    /// The parameters of its client method, in order.
    #[getter]
    fn params(&self, py: Python<'_>) -> Py<PyTuple> {
        self.params.clone_ref(py)
    }

    fn __repr__(&self) -> String {
        format!(
            "<Spec {} (id {}): {}>",
            self.spec.name(),
            u8::from(self.spec.id),
            self.spec.usage
        )
    }
}

/// Every row of the table as a tuple of `Spec`, in id order.
pub fn table(py: Python<'_>) -> PyResult<Bound<'_, PyTuple>> {
    let specs = TABLE
        .iter()
        .map(|spec| {
            let params = grammar::params(spec);
            let params = PyTuple::new(py, params.iter().map(PyParam::from))?.unbind();
            Bound::new(py, PySpec { spec, params })
        })
        .collect::<PyResult<Vec<_>>>()?;
    PyTuple::new(py, specs)
}
