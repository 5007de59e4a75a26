//! Why the companion computer refused or failed a command, and the `ret`
//! each answer carries (DESIGN.md, "Errors"). The text a client sees is the
//! `Display` of these variants, written whole into the response.

use lluav_core::Ret;

use crate::onboard::Refusal;

/// A command about the companion computer that was not carried out.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A named file or directory does not exist.
    #[error("Not found: {0}")]
    NotFound(String),
    /// A client path resolves outside the data directory (through a link).
    #[error("Refused: {0} leaves the data directory")]
    Escapes(String),
    /// A value the companion cannot use (a file too large, not UTF-8).
    #[error("Invalid arguments: {0}")]
    Invalid(String),
    /// `passwd` while `--password`, `LLUAV_PASSWORD` or the config file
    /// pins the password.
    #[error("Password is set by the daemon's configuration")]
    PasswordPinned,
    /// A command the companion does not own reached it: a routing bug,
    /// answered as a fault.
    #[error("Unhandled exception")]
    NotOwned(&'static str),
    /// A system call or disk I/O failed.
    #[error("{what}: {err}")]
    Io {
        /// What was being done.
        what: String,
        /// The error.
        err: std::io::Error,
    },
}

impl Error {
    /// An I/O failure while doing `what`.
    pub(crate) fn io(what: impl Into<String>, err: std::io::Error) -> Self {
        Error::Io {
            what: what.into(),
            err,
        }
    }

    /// An I/O failure about `name`: not-found is the client's business
    /// (-1), anything else failed on this machine (-3).
    pub(crate) fn about(what: &str, name: &str, err: std::io::Error) -> Self {
        if err.kind() == std::io::ErrorKind::NotFound {
            Error::NotFound(name.to_owned())
        } else {
            Error::io(format!("{what} {name}"), err)
        }
    }
}

impl Refusal for Error {
    fn ret(&self) -> Ret {
        match self {
            Error::NotFound(_) | Error::Escapes(_) | Error::PasswordPinned => Ret::Failed,
            Error::Invalid(_) => Ret::InvalidArgs,
            Error::Io { .. } => Ret::SystemCall,
            Error::NotOwned(_) => Ret::Unhandled,
        }
    }
}

/// The companion's result type.
pub type Result<T = (), E = Error> = std::result::Result<T, E>;
