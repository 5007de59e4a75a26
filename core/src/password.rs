//! What a password is (DESIGN.md, "Login"): the characters the parser
//! accepts in `login` and `passwd` and the login state stores, and the two
//! special login values. Its own module so that the parser and the
//! sessions share it without depending on each other.

use crate::error::ArgError;

/// Longest login password.
pub const MAX_PASSWORD_LEN: usize = 32;
/// The login value that grants admin, unless configured otherwise.
pub const DEFAULT_ADMIN_PASSWORD: &str = "1025";
/// The login value that logs the session out, unless configured otherwise.
pub const DEFAULT_LOGOUT_PASSWORD: &str = "0315";

/// The characters of a password: 1–32 printable ASCII characters, no
/// space (the special login values included).
pub(crate) fn chars(s: &str) -> Result<&str, ArgError> {
    let ok = !s.is_empty() && s.len() <= MAX_PASSWORD_LEN && s.bytes().all(|b| b.is_ascii_graphic());
    if ok { Ok(s) } else { Err(ArgError::BadPassword) }
}
