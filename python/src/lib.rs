//! `lluav._core`: lluav-core for Python.
//!
//! The Python SDK (`import lluav`) takes every fact about commands from
//! here: the command table, the mapping of each grammar to Python
//! parameters, argument validation and encoding (by the core's own
//! `Command::new` and `encode`, checked by parsing the frame back with the
//! core's `parse`), so the SDK cannot disagree with a server built on the
//! same core.

mod command;
mod grammar;
mod invalid;
mod spec;

use lluav_core::table::lookup;
use lluav_core::{Command, CommandId};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString, PyTuple};

use crate::grammar::MAX_PARAMS;
use crate::grammar::convert::{self, Value};
use crate::invalid::Invalid;

/// Binds positional and keyword arguments to a command's parameters, in
/// parameter order (`None` where nothing was given).
fn bind<'py>(
    params: &[grammar::Param],
    args: &Bound<'py, PyTuple>,
    kwargs: Option<&Bound<'py, PyDict>>,
) -> Result<[Option<Bound<'py, PyAny>>; MAX_PARAMS], Invalid> {
    let mut slots: [Option<Bound<'py, PyAny>>; MAX_PARAMS] = Default::default();
    if args.len() > params.len() {
        return Err(Invalid::new(format!(
            "takes {} argument{}, {} given",
            params.len(),
            if params.len() == 1 { "" } else { "s" },
            args.len()
        )));
    }
    for (slot, arg) in slots.iter_mut().zip(args.iter()) {
        *slot = Some(arg);
    }
    for (key, value) in kwargs.into_iter().flat_map(|kw| kw.iter()) {
        let key = key
            .cast_into::<PyString>()
            .map_err(|_| Invalid::new("keywords must be str".to_owned()))?;
        let key = key
            .to_cow()
            .map_err(|_| Invalid::new("keywords must be valid text".to_owned()))?;
        let index = params
            .iter()
            .position(|p| p.name == key)
            .ok_or_else(|| Invalid::new(format!("unexpected argument '{key}'")))?;
        match slots.get_mut(index) {
            Some(slot @ None) => *slot = Some(value),
            _ => return Err(Invalid::new(format!("got two values for '{key}'"))),
        }
    }
    Ok(slots)
}

/// Validates and encodes a call of command `id` with Python arguments.
fn encode_command(
    id: CommandId,
    args: &Bound<'_, PyTuple>,
    kwargs: Option<&Bound<'_, PyDict>>,
) -> Result<String, Invalid> {
    let spec = id.spec();
    let params = grammar::params(spec);
    let slots = bind(params, args, kwargs)?;
    let values = params
        .iter()
        .zip(slots.iter())
        .map(|(param, slot)| convert::convert(param, slot.as_ref()))
        .collect::<Result<Vec<Value>, _>>()?;
    let command = Command::new(id, grammar::args::build(spec.grammar, params, &values)?)?;
    let frame = command.to_string();
    // The server reads the frame, not our values: it must parse back to
    // exactly this command (a str payload that looks like JSON would not).
    match lluav_core::parse(&frame) {
        Ok(back) if back == command => Ok(frame),
        _ => Err(Invalid::new(format!(
            "encodes to a frame the server would read differently: {:?}{}",
            cut(&frame, 80),
            grammar::misread_hint(spec.grammar)
        ))),
    }
}

fn cut(s: &str, max: usize) -> &str {
    let mut end = max.min(s.len());
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    s.get(..end).unwrap_or(s)
}

/// The `lluav._core` extension module.
#[pymodule]
mod _core {
    use super::*;

    #[pymodule_export]
    use crate::command::PyCommand;
    #[pymodule_export]
    use crate::spec::{PyParam, PySpec};

    /// Validates a call of command `id` and returns its frame; raises
    /// `lluav.InvalidArguments` (with the usage line) otherwise.
    #[pyfunction]
    #[pyo3(signature = (id, args, kwargs=None))]
    fn encode(
        py: Python<'_>,
        id: u8,
        args: &Bound<'_, PyTuple>,
        kwargs: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<String> {
        let id = CommandId::from_u8(id)
            .ok_or_else(|| pyo3::exceptions::PyValueError::new_err(format!("no command has id {id}")))?;
        encode_command(id, args, kwargs).map_err(|e| e.into_err(py, id.spec()))
    }

    /// Parses a frame exactly as the server will; raises
    /// `lluav.InvalidArguments` or `lluav.UnknownCommand`.
    #[pyfunction]
    fn parse(py: Python<'_>, frame: &str) -> PyResult<PyCommand> {
        crate::command::parse(py, frame)
    }

    /// The id of the command a frame names, 0 for none (the `cmd` the
    /// server answers an unknown or empty frame with).
    #[pyfunction]
    fn command_id(frame: &str) -> u8 {
        lluav_core::parse::split(frame)
            .and_then(|s| lookup(s.name))
            .map_or(0, |spec| spec.id.into())
    }

    #[pymodule_init]
    fn init(m: &Bound<'_, PyModule>) -> PyResult<()> {
        m.add("TABLE", crate::spec::table(m.py())?)
    }
}
