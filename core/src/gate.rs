//! The gates, in DESIGN.md's order: login → (name lookup) → admin-only →
//! armed → lock. Admins skip the lock gate.
//!
//! The safety invariant — `land`, `rtl`, `mrtl`, `tether_land`, `disarm`
//! and `set_sp_ned` are never refused by the armed or lock gate — follows
//! from their table flags and is proven by the tests.

use crate::error::Refusal;
use crate::session::{Auth, Session};
use crate::table::Flags;
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
    if flags.admin_only && !session.admin() {
        return Err(Refusal::AdminOnly);
    }
    if !flags.run_on_arm && armed() {
        return Err(Refusal::Armed);
    }
    if !flags.run_in_lock && auth.lock_mode() && !session.admin() {
        return Err(Refusal::Locked);
    }
    Ok(())
}
