//! Why the companion computer refused or failed a command, and the `ret`
//! each answer carries (DESIGN.md, "Errors"). The text a client sees is the
//! `Display` of these variants, written whole into the response.

use lluav_core::Ret;

use crate::files;
use crate::vehicle::Refusal;

/// A command about the companion computer that was not carried out.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The data directory refused a path or failed.
    #[error(transparent)]
    Files(#[from] files::Error),
    /// `passwd` while `--password`, `LLUAV_PASSWORD` or the config file
    /// pins the password.
    #[error("Password is set by the daemon's configuration")]
    PasswordPinned,
    /// `rm_map` of the map in use: localisation would be left on a map
    /// that is gone.
    #[error("Map {0} is in use: set_mappath another map first")]
    MapInUse(String),
    /// A command the companion does not own reached it: a routing bug,
    /// answered as a fault.
    #[error("Unhandled exception")]
    NotOwned(&'static str),
}

impl Error {
    /// An I/O failure while doing `what`.
    pub(crate) fn io(what: impl Into<String>, err: std::io::Error) -> Self {
        files::Error::io(what, err).into()
    }

    /// An I/O failure about `name` (see [`files::Error::about`]).
    pub(crate) fn about(what: &str, name: &str, err: std::io::Error) -> Self {
        files::Error::about(what, name, err).into()
    }

    /// Something a client named does not exist.
    pub(crate) fn not_found(what: String) -> Self {
        files::Error::NotFound(what).into()
    }
}

impl Refusal for Error {
    fn ret(&self) -> Ret {
        match self {
            Error::Files(e) => e.ret(),
            Error::PasswordPinned | Error::MapInUse(_) => Ret::Failed,
            Error::NotOwned(_) => Ret::Unhandled,
        }
    }
}

/// The companion's result type.
pub type Result<T = (), E = Error> = std::result::Result<T, E>;
