//! Value rules shared by the parser and [`crate::Command::new`], so that a
//! hand-built command and a parsed one obey exactly the same limits.

use crate::error::ArgError;

/// Longest single path component, as POSIX `NAME_MAX`.
pub const MAX_NAME_LEN: usize = 255;
/// Longest relative path.
pub const MAX_PATH_LEN: usize = 1024;
/// Longest parameter name and task id.
pub const MAX_IDENT_LEN: usize = 64;
/// Longest login password.
pub const MAX_PASSWORD_LEN: usize = 32;

pub(crate) fn finite(v: f32) -> Result<f32, ArgError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ArgError::NotFinite)
    }
}

pub(crate) fn non_negative(v: f32) -> Result<f32, ArgError> {
    if finite(v)? >= 0.0 {
        Ok(v)
    } else {
        Err(ArgError::OutOfRange)
    }
}

pub(crate) fn angle(v: f32) -> Result<f32, ArgError> {
    if (-90.0..=90.0).contains(&finite(v)?) {
        Ok(v)
    } else {
        Err(ArgError::OutOfRange)
    }
}

fn is_control(c: char) -> bool {
    c.is_control()
}

/// A single path component: it cannot name a parent, a separator, or carry
/// bytes a filesystem or a log would treat specially.
pub(crate) fn name(s: &str) -> Result<&str, ArgError> {
    let bad = s.is_empty()
        || s.len() > MAX_NAME_LEN
        || s == "."
        || s == ".."
        || s.starts_with(' ')
        || s.ends_with(' ')
        || s.chars().any(|c| c == '/' || c == '\\' || is_control(c));
    if bad { Err(ArgError::UnsafePath) } else { Ok(s) }
}

/// A relative path whose every component is a [`name`]: no leading `/`,
/// no empty, `.` or `..` component, so it can never leave its directory.
pub(crate) fn path(s: &str) -> Result<&str, ArgError> {
    if s.len() > MAX_PATH_LEN {
        return Err(ArgError::UnsafePath);
    }
    s.split('/').try_for_each(|c| name(c).map(|_| ()))?;
    Ok(s)
}

/// Free text: non-empty, no control characters, and no trailing space (the
/// frame's trailing spaces are not part of it, so it could not round-trip).
pub(crate) fn text(s: &str) -> Result<&str, ArgError> {
    if s.is_empty() {
        Err(ArgError::Missing)
    } else if s.ends_with(' ') || s.chars().any(is_control) {
        Err(ArgError::BadText)
    } else {
        Ok(s)
    }
}

/// A login attempt is text; whether it matches is the session's business.
pub(crate) fn secret(s: &str) -> Result<&str, ArgError> {
    text(s)
}

/// DESIGN.md: 1–32 printable ASCII characters, no space. (That it is
/// neither special login value depends on configuration: [`crate::Auth`]
/// checks it.)
pub(crate) fn new_password(s: &str) -> Result<&str, ArgError> {
    let ok = !s.is_empty() && s.len() <= MAX_PASSWORD_LEN && s.bytes().all(|b| b.is_ascii_graphic());
    if ok { Ok(s) } else { Err(ArgError::BadPassword) }
}

fn ident<'a>(s: &'a str, extra: &[u8]) -> Result<&'a str, ArgError> {
    let ok = !s.is_empty()
        && s.len() <= MAX_IDENT_LEN
        && s.bytes().all(|b| b.is_ascii_alphanumeric() || extra.contains(&b));
    if ok { Ok(s) } else { Err(ArgError::Malformed) }
}

/// A parameter name: `[A-Za-z0-9_.-]{1,64}`.
pub(crate) fn param_name(s: &str) -> Result<&str, ArgError> {
    ident(s, b"_.-")
}

/// An AI1 task id: `[A-Za-z0-9_-]{1,64}`.
pub(crate) fn task_id(s: &str) -> Result<&str, ArgError> {
    ident(s, b"_-")
}

/// A JSON payload: well-formed, validated without allocating.
pub(crate) fn json(s: &str) -> Result<&str, ArgError> {
    super::json::validate(s).map(|()| s)
}
