//! The contract between the core and a vehicle.
//!
//! The core never does I/O: an adapter gives it a [`Backend`] (the vehicle:
//! armed state, command execution) and a [`Clock`] (for `ts` and
//! [`Context::now_ms`]). A backend that must wait for something outside —
//! an autopilot's acknowledgement — answers [`Step::Pending`] and is asked
//! to [`Backend::finish`] once the adapter has seen it become ready, so the
//! core never blocks and other sessions are served meanwhile.

use crate::authority::{Failsafe, Pilot};
use crate::command::Command;
use crate::error::Failure;
use crate::response::Fields;
pub use crate::session::Ticket;
use crate::session::{Role, SessionId};

/// What a backend knows about the request it runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Context<'a> {
    /// The request's time, in milliseconds since the Unix epoch, read once
    /// from the adapter's [`Clock`]: backends never read a clock themselves.
    pub now_ms: i64,
    /// Whether lock mode is on (e.g. for `state`'s `lock_mode`).
    pub lock_mode: bool,
    /// The session's role.
    pub role: Role,
    /// The session running the command.
    pub session: SessionId,
    /// The session in control of the flight, if any.
    pub pilot: Option<&'a Pilot>,
    /// The failsafe the backend reported at the request's time, if any.
    pub failsafe: Option<Failsafe>,
}

impl Context<'_> {
    /// A context with no pilot and no failsafe (for in-process callers and
    /// tests).
    pub fn new(now_ms: i64, lock_mode: bool, role: Role, session: SessionId) -> Self {
        Context {
            now_ms,
            lock_mode,
            role,
            session,
            pilot: None,
            failsafe: None,
        }
    }

    /// Writes the `state` members of flight authority: `"failsafe"` (the
    /// reason, `"<reason> (overridden)"`, or `null`) and `"control"` (as
    /// `control` answers it, without `you`, or `null`).
    pub fn write_authority(&self, state: &mut Fields<'_>) {
        match self.failsafe {
            Some(f) => {
                let [source, sep, detail] = f.reason_parts();
                let overridden = if f.overridden { " (overridden)" } else { "" };
                state.str_parts("failsafe", &[source, sep, detail, overridden])
            }
            None => state.null("failsafe"),
        };
        match self.pilot {
            Some(p) => state.object("control", |o| p.write(o, None)),
            None => state.null("control"),
        };
    }
}

/// How far a backend got with a command.
#[must_use]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Finished: the response fields are written.
    Done,
    /// Waiting for something outside; nothing is written yet. The adapter
    /// waits until the backend says this ticket is ready (how is the
    /// adapter's and backend's business) and calls
    /// [`crate::Server::resume`], which calls [`Backend::finish`].
    Pending(Ticket),
}

/// The vehicle behind the protocol.
///
/// The core runs `login`, `help`, `admin_lock`, `admin_unlock`, `control`,
/// `control_take`, `control_release` and the session side of `passwd`
/// itself; every other command reaches
/// [`Backend::execute`] only after all gates passed and its arguments were
/// validated.
pub trait Backend {
    /// Whether the vehicle is armed right now. Read at the moment of the
    /// armed-gate check, and only for commands the armed gate concerns.
    fn armed(&self) -> bool;

    /// Carries out `cmd` and writes its response fields, under the
    /// specification's field names, into `out`, or starts it and answers
    /// [`Step::Pending`]. On `Err`, whatever was written is discarded and
    /// the failure is answered instead.
    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure>;

    /// Finishes a command that [`Backend::execute`] left pending, writing
    /// its response fields like `execute` would. It may answer
    /// [`Step::Pending`] again if the ticket is not ready after all. A
    /// backend that never pends keeps the default, which reports a fault.
    fn finish(&mut self, ticket: Ticket, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let _ = (ticket, ctx, out);
        Err(Failure::unhandled())
    }

    /// Called by `passwd` before the new password takes effect, so that an
    /// adapter can persist it; an `Err` leaves the old password in place.
    fn password_changed(&mut self, new: &str) -> Result<(), Failure> {
        let _ = new;
        Ok(())
    }

    /// Called by `admin_lock`/`admin_unlock` before lock mode becomes `on`,
    /// so that an adapter can persist it (a daemon that restarts while an
    /// admin holds the lock comes back locked); an `Err` leaves lock mode
    /// as it was and is answered instead.
    fn lock_mode_changed(&mut self, on: bool) -> Result<(), Failure> {
        let _ = on;
        Ok(())
    }

    /// Called when a session's connection has ended (e.g. to stop streaming
    /// a setpoint that session set).
    fn session_closed(&mut self, session: SessionId) {
        let _ = session;
    }

    /// The failsafe that holds now, if any (DESIGN.md, "Flight authority":
    /// the vehicle acting on its own for safety). Read before every
    /// command and for `state`; a backend that cannot fly has none.
    fn failsafe(&self) -> Option<Failsafe> {
        None
    }

    /// The session in control overrides the current failsafe (`control_take
    /// failsafe`): from now on [`Backend::failsafe`] reports it overridden,
    /// until the vehicle is disarmed on the ground or another reason
    /// starts. An `Err` is answered and nothing changes.
    fn override_failsafe(&mut self) -> Result<(), Failure> {
        Ok(())
    }

    /// Whether a mission is running (so `abort_report` would stop it and
    /// counts as steering).
    fn mission_running(&self) -> bool {
        false
    }

    /// How long control lasts without a request from its session, ms
    /// (the vehicle's `control_timeout`).
    fn control_timeout_ms(&self) -> u32 {
        DEFAULT_CONTROL_TIMEOUT_MS
    }
}

/// The control timeout of a backend that has no parameter for it: 30 s.
pub const DEFAULT_CONTROL_TIMEOUT_MS: u32 = 30_000;

/// The source of `ts` and [`Context::now_ms`]: milliseconds since the Unix
/// epoch.
pub trait Clock {
    /// Now, in milliseconds since the Unix epoch.
    fn unix_ms(&self) -> i64;
}

impl<F: Fn() -> i64> Clock for F {
    fn unix_ms(&self) -> i64 {
        self()
    }
}
