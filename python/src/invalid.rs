//! Errors raised to Python: invalid arguments (with the usage line) and
//! frames that name no command. The exception classes live in
//! `lluav._errors`, so that they can subclass both `lluav.Error` and the
//! Python built-ins they resemble.

use lluav_core::{ArgError, Spec};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyType;

/// Why arguments were refused, before the command and its usage are known.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Invalid(String);

impl Invalid {
    /// A refusal with its reason.
    pub fn new(reason: String) -> Self {
        Invalid(reason)
    }

    /// `lluav.InvalidArguments(name, usage, reason)`.
    pub fn into_err(self, py: Python<'_>, spec: &Spec) -> PyErr {
        static CLASS: PyOnceLock<Py<PyType>> = PyOnceLock::new();
        match CLASS.import(py, "lluav._errors", "InvalidArguments") {
            Ok(class) => PyErr::from_type(class.clone(), (spec.name(), spec.usage, self.0)),
            Err(e) => e,
        }
    }
}

impl From<ArgError> for Invalid {
    fn from(e: ArgError) -> Self {
        Invalid(reason(e).to_owned())
    }
}

/// The core's reason in words.
fn reason(e: ArgError) -> &'static str {
    if let Some(reason) = e.reason() {
        return reason;
    }
    match e {
        ArgError::Missing => "an argument is missing or empty",
        ArgError::Unexpected => "unexpected arguments",
        ArgError::Malformed => "malformed (see the usage line for the allowed characters and separators)",
        ArgError::NotANumber => "not a decimal number (digits with an optional '-', fraction and exponent)",
        ArgError::NotFinite => "a number is not finite (NaN or infinite)",
        ArgError::NotAFlag => "a flag must be 0 or 1",
        ArgError::UnsafePath => {
            "not a safe name or relative path (no leading '/' or '.', no '\\', control or format \
             characters, empty or space-padded components; a name is at most 128 bytes)"
        }
        ArgError::BadText => {
            "text may not hold control or format characters (Unicode Cc, Cf) or end with a space"
        }
        ArgError::TooMany => "a list holds too many items",
        ArgError::BadJson => "the JSON payload is not well-formed (or nests too deeply)",
        ArgError::BadPassword => "a password is 1-32 printable ASCII characters without spaces",
        ArgError::WrongGrammar => "the arguments belong to another command",
        // ArgError may grow; a new variant still reads sensibly.
        #[allow(unreachable_patterns)]
        _ => "invalid arguments",
    }
}

/// `lluav.UnknownCommand(message)`, for a frame that names no command.
pub fn unknown(py: Python<'_>, message: String) -> PyErr {
    static CLASS: PyOnceLock<Py<PyType>> = PyOnceLock::new();
    match CLASS.import(py, "lluav._errors", "UnknownCommand") {
        Ok(class) => PyErr::from_type(class.clone(), (message,)),
        Err(e) => e,
    }
}
