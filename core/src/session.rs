//! Sessions and the vehicle-wide login state.
//!
//! A [`Session`] is one connection: its [`Role`], the [`Peer`] it came
//! from, how many wrong passwords it sent in a row, and the command it
//! waits for, if any. [`Auth`] is shared by every session of a vehicle: the
//! password, the two special login values, lock mode and the [`Throttle`].
//! Passwords are compared in constant time.

use crate::authority::Label;
use crate::error::ArgError;
use crate::password::MAX_PASSWORD_LEN;
pub use crate::password::{DEFAULT_ADMIN_PASSWORD, DEFAULT_LOGOUT_PASSWORD};
use crate::table::CommandId;
use crate::throttle::{DefaultSlots, Slots, Throttle};
pub use crate::throttle::{MAX_WRONG_PASSWORDS, Peer};

/// What a session may do.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Role {
    /// Not logged in (on a vehicle without a password, it may still run
    /// every command that is not admin-only).
    #[default]
    Anonymous,
    /// Logged in with the vehicle's password.
    User,
    /// Logged in with the admin value.
    Admin,
}

// Defined beside the control it names, so that `authority` needs nothing
// of this module.
pub use crate::authority::SessionId;

/// A command the backend has started and will finish later: the session
/// waits for it ([`Session::pending`]), the backend answered
/// [`Step::Pending`](crate::Step::Pending) with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Ticket(pub u32);

/// One connection's login state.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Session {
    id: SessionId,
    peer: Option<Peer>,
    label: Label,
    role: Role,
    wrong_passwords: u8,
    pending: Option<Pending>,
}

/// A command the session waits for, and whether it takes control of the
/// flight once it answers 0 (it steered, or brought the vehicle down).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Pending {
    pub(crate) ticket: Ticket,
    pub(crate) id: CommandId,
    pub(crate) takes_control: bool,
}

impl Session {
    /// A session with no peer (in-process use and tests; its wrong passwords
    /// count for this session only. Adapters use [`crate::Server::open`] so
    /// that login throttling sees the peer).
    pub const fn new() -> Self {
        Session::with(SessionId(0), None)
    }

    pub(crate) const fn with(id: SessionId, peer: Option<Peer>) -> Self {
        Session {
            id,
            peer,
            label: Label::EMPTY,
            role: Role::Anonymous,
            wrong_passwords: 0,
            pending: None,
        }
    }

    /// This session's id.
    pub fn id(&self) -> SessionId {
        self.id
    }

    /// Who the client is, as the adapter gave it.
    pub fn peer(&self) -> Option<Peer> {
        self.peer
    }

    /// Who the session is, as `control` names it.
    pub fn label(&self) -> &Label {
        &self.label
    }

    pub(crate) fn set_label(&mut self, label: Label) {
        self.label = label;
    }

    /// What the session may do.
    pub fn role(&self) -> Role {
        self.role
    }

    /// Whether the session has logged in with a valid password.
    pub fn logged_in(&self) -> bool {
        self.role != Role::Anonymous
    }

    /// Whether the session has admin rights.
    pub fn admin(&self) -> bool {
        self.role == Role::Admin
    }

    /// Wrong passwords sent in a row.
    pub fn wrong_passwords(&self) -> u8 {
        self.wrong_passwords
    }

    /// The command the session waits for the backend to finish, if any.
    pub fn pending(&self) -> Option<(Ticket, CommandId)> {
        self.pending.map(|p| (p.ticket, p.id))
    }

    pub(crate) fn take_pending(&mut self) -> Option<Pending> {
        self.pending.take()
    }

    pub(crate) fn set_pending(&mut self, pending: Pending) {
        self.pending = Some(pending);
    }
}

/// A password held in a fixed buffer so comparisons can run over the whole
/// buffer whatever the attempt's content.
#[derive(Clone, PartialEq, Eq)]
struct Secret {
    bytes: [u8; MAX_PASSWORD_LEN],
    len: usize,
}

impl core::fmt::Debug for Secret {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Secret(..)")
    }
}

impl Secret {
    fn new(s: &str) -> Result<Self, ArgError> {
        crate::password::chars(s)?;
        let mut bytes = [0u8; MAX_PASSWORD_LEN];
        bytes
            .get_mut(..s.len())
            .ok_or(ArgError::BadPassword)?
            .copy_from_slice(s.as_bytes());
        Ok(Secret { bytes, len: s.len() })
    }

    /// Constant time in the attempt's content: every byte of the buffer is
    /// compared, and no branch depends on where a difference lies.
    fn matches(&self, attempt: &[u8]) -> bool {
        let mut diff = self.len ^ attempt.len();
        for (i, b) in self.bytes.iter().enumerate() {
            diff |= usize::from(b ^ attempt.get(i).copied().unwrap_or(0));
        }
        core::hint::black_box(diff) == 0
    }

    fn as_str(&self) -> &str {
        self.bytes
            .get(..self.len)
            .and_then(|b| core::str::from_utf8(b).ok())
            .unwrap_or("")
    }
}

/// What a login attempt did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoginOutcome {
    /// Logged in as a standard user.
    User,
    /// Logged in as admin.
    Admin,
    /// Logged out (the logout value).
    LoggedOut,
    /// Wrong password; `close` once the session has sent
    /// [`MAX_WRONG_PASSWORDS`] in a row.
    Wrong {
        /// Whether the connection must now be closed with 1008.
        close: bool,
    },
    /// The session's address is locked out: the attempt was not checked.
    Throttled {
        /// Whole seconds until a password from this peer may be checked
        /// again (at least 1), as far as the throttle can tell now.
        retry_after_s: u32,
    },
}

/// Vehicle-wide login state, shared by all sessions; `S` is the storage of
/// the [`Throttle`]'s table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Auth<S = DefaultSlots> {
    password: Option<Secret>,
    admin: Secret,
    logout: Secret,
    lock_mode: bool,
    throttle: Throttle<S>,
}

/// Why an [`Auth`] could not be configured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AuthError {
    /// A password breaks the rules: 1–32 printable ASCII characters, no space.
    BadPassword,
    /// The password equals one of the special login values, or the two
    /// special values are equal.
    Ambiguous,
}

impl Auth {
    /// Login state with an optional password and the default special values.
    /// Without a password every command runs without login.
    pub fn new(password: Option<&str>) -> Result<Self, AuthError> {
        Auth::with_specials(password, DEFAULT_ADMIN_PASSWORD, DEFAULT_LOGOUT_PASSWORD)
    }

    /// Login state with operator-chosen special values.
    pub fn with_specials(password: Option<&str>, admin: &str, logout: &str) -> Result<Self, AuthError> {
        let secret = |s: &str| Secret::new(s).map_err(|_| AuthError::BadPassword);
        let auth = Auth {
            password: password.map(secret).transpose()?,
            admin: secret(admin)?,
            logout: secret(logout)?,
            lock_mode: false,
            throttle: Throttle::default(),
        };
        if auth.admin == auth.logout {
            return Err(AuthError::Ambiguous);
        }
        if let Some(p) = &auth.password {
            auth.check_not_special(p.as_str())?;
        }
        Ok(auth)
    }
}

impl<S: Slots> Auth<S> {
    /// The same login state with `throttle` (its table, lockouts and
    /// budget) in place of the current one.
    pub fn with_throttle<T: Slots>(self, throttle: Throttle<T>) -> Auth<T> {
        Auth {
            password: self.password,
            admin: self.admin,
            logout: self.logout,
            lock_mode: self.lock_mode,
            throttle,
        }
    }

    fn check_not_special(&self, candidate: &str) -> Result<(), AuthError> {
        let special = self.admin.matches(candidate.as_bytes()) | self.logout.matches(candidate.as_bytes());
        if special {
            Err(AuthError::Ambiguous)
        } else {
            Ok(())
        }
    }

    /// Whether sessions must log in before running commands.
    pub fn password_required(&self) -> bool {
        self.password.is_some()
    }

    /// The current password, for an adapter that persists it.
    pub fn password(&self) -> Option<&str> {
        self.password.as_ref().map(Secret::as_str)
    }

    /// Whether lock mode is on.
    pub fn lock_mode(&self) -> bool {
        self.lock_mode
    }

    /// Turns lock mode on or off (what `admin_lock`/`admin_unlock` do).
    pub fn set_lock_mode(&mut self, on: bool) {
        self.lock_mode = on;
    }

    /// Whether `new` may become the password: the password rules, and not
    /// one of the special login values.
    pub fn check_password(&self, new: &str) -> Result<(), AuthError> {
        Secret::new(new).map_err(|_| AuthError::BadPassword)?;
        self.check_not_special(new)
    }

    /// Replaces the password (what `passwd` does once the backend agreed).
    pub fn set_password(&mut self, new: &str) -> Result<(), AuthError> {
        self.check_password(new)?;
        self.password = Secret::new(new).ok();
        Ok(())
    }

    /// Sets how long an address is locked out after
    /// [`MAX_WRONG_PASSWORDS`] wrong passwords in a row: `base_ms` the first
    /// time, doubling with each further lockout up to `max_ms`.
    pub fn with_lockout(mut self, base_ms: u32, max_ms: u32) -> Self {
        self.throttle = self.throttle.with_lockout(base_ms, max_ms);
        self
    }

    /// Checks a login attempt at `now_ms` and updates the session and the
    /// peer's record. Every secret is compared, in constant time, whatever
    /// the attempt; nothing is compared while the throttle refuses the
    /// session's peer (locked out, no room for its record, or the budget
    /// of wrong passwords spent).
    pub fn login(&mut self, session: &mut Session, attempt: &str, now_ms: i64) -> LoginOutcome {
        if let Some(wait_ms) = session.peer.and_then(|peer| self.throttle.wait(&peer, now_ms)) {
            return LoginOutcome::Throttled {
                retry_after_s: wait_ms.div_ceil(1000),
            };
        }
        let a = attempt.as_bytes();
        let is_admin = self.admin.matches(a);
        let is_logout = self.logout.matches(a);
        let is_user = self.password.as_ref().is_some_and(|p| p.matches(a));
        let role = if is_admin {
            Role::Admin
        } else if is_logout {
            // Public, so it must not buy more guesses: the counts stay.
            session.role = Role::Anonymous;
            return LoginOutcome::LoggedOut;
        } else if is_user {
            Role::User
        } else {
            session.wrong_passwords = session.wrong_passwords.saturating_add(1);
            if let Some(peer) = session.peer {
                self.throttle.wrong(&peer, now_ms);
            }
            return LoginOutcome::Wrong {
                close: session.wrong_passwords >= MAX_WRONG_PASSWORDS,
            };
        };
        session.wrong_passwords = 0;
        if let Some(peer) = session.peer {
            self.throttle.granted(&peer);
        }
        session.role = role;
        if role == Role::Admin {
            LoginOutcome::Admin
        } else {
            LoginOutcome::User
        }
    }

    /// Marks a session logged in as a user, unless it is admin already (the
    /// session that set the password with `passwd` knows it).
    pub(crate) fn admit(&self, session: &mut Session) {
        if session.role == Role::Anonymous {
            session.role = Role::User;
        }
    }
}
