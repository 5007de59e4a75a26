//! Why a client path or a file in the data directory was refused or could
//! not be read or written. The text a client sees is the `Display` of
//! these variants, written whole into the response, with [`Error::ret`].

use lluav_core::Ret;

/// A file operation under the data directory that was not carried out.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A named file or directory does not exist, or is not what the
    /// command needs: the reason.
    #[error("Invalid arguments: {0}")]
    NotFound(String),
    /// A client path leads, through a link, outside the areas clients may
    /// reach (`maps/`, `images/`, `bags/`, `logs/`, `missions/`).
    #[error("Invalid arguments: {0} leads outside maps/, images/, bags/, logs/ and missions/")]
    Escapes(String),
    /// A value that cannot be used (a file too large, not UTF-8).
    #[error("Invalid arguments: {0}")]
    Invalid(String),
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

    /// The `ret` it is answered with (DESIGN.md, "Errors").
    pub fn ret(&self) -> Ret {
        match self {
            Error::NotFound(_) | Error::Escapes(_) | Error::Invalid(_) => Ret::InvalidArgs,
            Error::Io { .. } => Ret::SystemCall,
        }
    }

    /// An I/O failure about `name`: not-found is a wrong request (-2),
    /// anything else failed on this machine (-3).
    pub(crate) fn about(what: &str, name: &str, err: std::io::Error) -> Self {
        if err.kind() == std::io::ErrorKind::NotFound {
            Error::NotFound(format!("{name} does not exist"))
        } else {
            Error::io(format!("{what} {name}"), err)
        }
    }
}

/// The data directory's result type.
pub type Result<T = (), E = Error> = std::result::Result<T, E>;
