//! The contract between the core and a vehicle.
//!
//! The core never does I/O: an adapter gives it a [`Backend`] (the vehicle:
//! armed state, command execution) and a [`Clock`] (for `ts`).

use crate::command::Command;
use crate::error::Failure;
use crate::response::Fields;

/// What a backend may want to know about the session running a command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Context {
    /// Whether lock mode is on (e.g. for `state`'s `lock_mode`).
    pub lock_mode: bool,
    /// Whether the session is admin.
    pub admin: bool,
}

/// The vehicle behind the protocol.
///
/// The core runs `login`, `help`, `admin_lock`, `admin_unlock` and the
/// session side of `passwd` itself; every other command reaches
/// [`Backend::execute`] only after all gates passed and its arguments were
/// validated.
pub trait Backend {
    /// Whether the vehicle is armed right now. Read at the moment of the
    /// armed-gate check, and only for commands the armed gate concerns.
    fn armed(&self) -> bool;

    /// Carries out `cmd` and writes its response fields, under the
    /// specification's field names, into `out`. On `Err`, whatever was
    /// written is discarded and the failure is answered instead.
    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<(), Failure>;

    /// Called by `passwd` before the new password takes effect, so that an
    /// adapter can persist it; an `Err` leaves the old password in place.
    fn password_changed(&mut self, new: &str) -> Result<(), Failure> {
        let _ = new;
        Ok(())
    }
}

/// The source of `ts`: milliseconds since the Unix epoch.
pub trait Clock {
    /// Now, in milliseconds since the Unix epoch.
    fn unix_ms(&self) -> i64;
}

impl<F: Fn() -> i64> Clock for F {
    fn unix_ms(&self) -> i64 {
        self()
    }
}
