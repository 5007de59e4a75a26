//! The gates, in DESIGN.md's order: login → (name lookup) → admin-only →
//! armed → lock → failsafe → control. Admins skip the lock gate.
//!
//! The safety invariant — `land`, `rtl`, `mrtl`, `tether_land` and `disarm`
//! are never refused by the armed, lock or control gate, nor by the
//! failsafe gate except `rtl`/`mrtl` while a failsafe lands the vehicle —
//! follows from their table flags and class and is proven by the tests.
//! `set_sp_ned` is never refused by the armed or lock gate; who may steer
//! is the control gate's business.

use crate::authority::{Control, Failsafe, Pilot};
use crate::error::{Failure, Refusal, Ret, messages};
use crate::number::Digits;
use crate::response::Fields;
use crate::session::{Auth, Session};
use crate::table::{Class, Flags};
use crate::throttle::Slots;

/// The login gate: with a password set, only a logged-in session passes.
/// (`login` itself is exempt; the caller knows which command it is.)
pub fn login<S: Slots>(session: &Session, auth: &Auth<S>) -> Result<(), Refusal> {
    if auth.password_required() && !session.logged_in() {
        Err(Refusal::LoginFirst)
    } else {
        Ok(())
    }
}

/// The admin, armed and lock gates for a command with `flags`. `armed` is
/// asked only when the answer matters, at the moment of the check.
pub fn command<S: Slots>(
    flags: &Flags,
    session: &Session,
    auth: &Auth<S>,
    armed: impl FnOnce() -> bool,
) -> Result<(), Refusal> {
    if flags.admin_only() && !session.admin() {
        return Err(Refusal::AdminOnly);
    }
    if !flags.run_on_arm() && armed() {
        return Err(Refusal::Armed);
    }
    if !flags.run_in_lock() && auth.lock_mode() && !session.admin() {
        return Err(Refusal::Locked);
    }
    Ok(())
}

/// Why the failsafe or control gate refused a command (DESIGN.md, "Flight
/// authority").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Held<'a> {
    /// A failsafe holds and the command would steer.
    Failsafe(Failsafe),
    /// A failsafe lands the vehicle and the command would climb.
    Landing(Failsafe),
    /// Another session is in control and the command would steer.
    Flown(&'a Pilot),
}

impl Held<'_> {
    /// Writes the refusal's message into the response (-1).
    pub fn fail(&self, out: &mut Fields<'_>) -> Failure {
        match self {
            Held::Failsafe(f) | Held::Landing(f) => {
                let [source, sep, detail] = f.reason_parts();
                let tail = match self {
                    Held::Landing(_) => messages::FAILSAFE_LANDING,
                    _ => messages::FAILSAFE_MOTION,
                };
                out.fail_parts(Ret::Failed, &[messages::FAILSAFE_OPEN, source, sep, detail, tail])
            }
            Held::Flown(p) => {
                let since = Digits::of(p.since_ms());
                let parts = [
                    messages::FLOWN_BY,
                    p.label(),
                    messages::FLOWN_SINCE,
                    since.as_str(),
                    messages::FLOWN_TAKE,
                ];
                out.fail_parts(Ret::Failed, &parts)
            }
        }
    }
}

/// The failsafe gate: while a failsafe holds (not overridden), commands
/// that steer are refused, and so are those that climb to return home
/// while it lands the vehicle. `steers` is whether this command would
/// steer now ([`Class::steers`]).
pub fn failsafe(class: Class, steers: bool, failsafe: Option<Failsafe>) -> Result<(), Held<'static>> {
    match failsafe {
        Some(f) if f.holds() && steers => Err(Held::Failsafe(f)),
        Some(f) if f.holds() && f.landing() && class == Class::Return => Err(Held::Landing(f)),
        _ => Ok(()),
    }
}

/// The control gate: a command that steers runs only from the session in
/// control, or from any session while control is free.
pub fn control<'c>(steers: bool, session: &Session, control: &'c Control) -> Result<(), Held<'c>> {
    match control.pilot() {
        Some(p) if steers && p.session() != session.id() => Err(Held::Flown(p)),
        _ => Ok(()),
    }
}
