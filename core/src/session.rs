//! Sessions and the vehicle-wide login state.
//!
//! A [`Session`] is one connection: logged in or not, admin or not, and how
//! many wrong passwords it sent in a row. [`Auth`] is shared by every
//! session of a vehicle: the password, the two special login values and
//! lock mode. Passwords are compared in constant time.

use crate::error::ArgError;
use crate::parse::MAX_PASSWORD_LEN;

/// The login value that grants admin, unless configured otherwise.
pub const DEFAULT_ADMIN_PASSWORD: &str = "1025";
/// The login value that logs the session out, unless configured otherwise.
pub const DEFAULT_LOGOUT_PASSWORD: &str = "0315";
/// Wrong passwords in a row after which the session is closed (1008).
pub const MAX_WRONG_PASSWORDS: u8 = 5;

/// One connection's login state.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Session {
    logged_in: bool,
    admin: bool,
    wrong_passwords: u8,
}

impl Session {
    /// A new connection: not logged in, not admin.
    pub const fn new() -> Self {
        Session {
            logged_in: false,
            admin: false,
            wrong_passwords: 0,
        }
    }

    /// Whether the session has logged in with a valid password.
    pub fn logged_in(&self) -> bool {
        self.logged_in
    }

    /// Whether the session has admin rights.
    pub fn admin(&self) -> bool {
        self.admin
    }

    /// Wrong passwords sent in a row.
    pub fn wrong_passwords(&self) -> u8 {
        self.wrong_passwords
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
        crate::parse::rules::new_password(s)?;
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
}

/// Vehicle-wide login state, shared by all sessions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Auth {
    password: Option<Secret>,
    admin: Secret,
    logout: Secret,
    lock_mode: bool,
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
        };
        if auth.admin == auth.logout {
            return Err(AuthError::Ambiguous);
        }
        if let Some(p) = &auth.password {
            auth.check_not_special(p.as_str())?;
        }
        Ok(auth)
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

    /// Checks a login attempt and updates the session. Every secret is
    /// compared, in constant time, whatever the attempt.
    pub fn login(&self, session: &mut Session, attempt: &str) -> LoginOutcome {
        let a = attempt.as_bytes();
        let is_admin = self.admin.matches(a);
        let is_logout = self.logout.matches(a);
        let is_user = self.password.as_ref().is_some_and(|p| p.matches(a));
        let outcome = if is_admin {
            LoginOutcome::Admin
        } else if is_logout {
            LoginOutcome::LoggedOut
        } else if is_user {
            LoginOutcome::User
        } else {
            session.wrong_passwords = session.wrong_passwords.saturating_add(1);
            return LoginOutcome::Wrong {
                close: session.wrong_passwords >= MAX_WRONG_PASSWORDS,
            };
        };
        session.wrong_passwords = 0;
        session.logged_in = outcome != LoginOutcome::LoggedOut;
        session.admin = outcome == LoginOutcome::Admin;
        outcome
    }

    /// Marks a session logged in as a user (the session that set the
    /// password with `passwd` knows it).
    pub(crate) fn admit(&self, session: &mut Session) {
        session.logged_in = true;
    }
}
