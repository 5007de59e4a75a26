//! Value rules shared by the parser and [`crate::Command::new`], so that a
//! hand-built command and a parsed one obey exactly the same limits.

use core::cmp::Ordering;

use crate::command::Pose;
use crate::error::{ArgError, Bound};
use crate::number::{Exact, Number};
pub use crate::password::MAX_PASSWORD_LEN;
use crate::password::{DEFAULT_ADMIN_PASSWORD, DEFAULT_LOGOUT_PASSWORD};

/// Longest name that becomes a file, in bytes (so that a temporary name
/// beside it still fits a filesystem's 255).
pub const MAX_NAME_LEN: usize = 128;
/// Longest relative path.
pub const MAX_PATH_LEN: usize = 1024;
/// Longest parameter name and task id.
pub const MAX_IDENT_LEN: usize = 64;
/// Longest free text (a plan), in bytes: `state` reports it, and the MCU's
/// frame is 4 KiB.
pub const MAX_TEXT_LEN: usize = 4096;
/// Longest task name, in bytes (`state` reports it).
pub const MAX_TASK_NAME_LEN: usize = 256;

pub(crate) fn finite(v: f32) -> Result<f32, ArgError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ArgError::NotFinite)
    }
}

/// A number ≥ 0 as sent (`-1e-50` is below 0, though its `f32` is -0).
pub(crate) fn non_negative(n: Number<'_>) -> Result<Number<'_>, ArgError> {
    finite(n.value())?;
    if n.cmp_exact(&Exact::ZERO, 0.0) == Some(Ordering::Less) {
        Err(ArgError::OutOfRange(Bound::NonNegative))
    } else {
        Ok(n)
    }
}

/// An angle in -90..=90 as sent (`90.000001` is out, though its `f32` is
/// 90).
pub(crate) fn angle(n: Number<'_>) -> Result<f32, ArgError> {
    let v = finite(n.value())?;
    if n.cmp_exact(&Exact::MINUS_NINETY, -90.0) == Some(Ordering::Less)
        || n.cmp_exact(&Exact::NINETY, 90.0) == Some(Ordering::Greater)
    {
        Err(ArgError::OutOfRange(Bound::Angle))
    } else {
        Ok(v)
    }
}

/// A setpoint above the ground: `z < 0` (NED from home) as the vehicle
/// would fly it, so `-0` and `-1e-50` (the `f32` -0) are at the ground.
pub(crate) fn setpoint(p: Pose) -> Result<Pose, ArgError> {
    [p.x, p.y, p.z, p.yaw]
        .into_iter()
        .try_for_each(|v| finite(v).map(|_| ()))?;
    if p.z < 0.0 {
        Ok(p)
    } else {
        Err(ArgError::AtOrBelowGround)
    }
}

fn is_control(c: char) -> bool {
    c.is_control()
}

/// `first..=last` as one word: the first code point (every Cf one is
/// below 2^24) and, in the top byte, how many follow it.
const fn span(first: u32, last: u32) -> u32 {
    (last - first) << 24 | first
}

/// The Unicode format characters (general category Cf, Unicode 16):
/// invisible, and some reorder what follows (U+202E shows
/// `evil\u{202E}gpj.exe` as `evilexe.jpg`).
const FORMAT: [u32; 21] = [
    span(0xAD, 0xAD),
    span(0x600, 0x605),
    span(0x61C, 0x61C),
    span(0x6DD, 0x6DD),
    span(0x70F, 0x70F),
    span(0x890, 0x891),
    span(0x8E2, 0x8E2),
    span(0x180E, 0x180E),
    span(0x200B, 0x200F),
    span(0x202A, 0x202E),
    span(0x2060, 0x2064),
    span(0x2066, 0x206F),
    span(0xFEFF, 0xFEFF),
    span(0xFFF9, 0xFFFB),
    span(0x110BD, 0x110BD),
    span(0x110CD, 0x110CD),
    span(0x13430, 0x1343F),
    span(0x1BCA0, 0x1BCA3),
    span(0x1D173, 0x1D17A),
    span(0xE0001, 0xE0001),
    span(0xE0020, 0xE007F),
];

/// Whether `c` is a Unicode format character (Cf).
fn is_format(c: char) -> bool {
    let c = u32::from(c);
    FORMAT.iter().any(|&e| c.wrapping_sub(e & 0xFF_FFFF) <= e >> 24)
}

/// A name that becomes a file: a single path component (no `/`, `\`),
/// not hidden (no leading `.`, so neither `.` nor `..`), no control or
/// format characters (Unicode Cc, Cf), no leading or trailing space, at
/// most [`MAX_NAME_LEN`] bytes.
pub(crate) fn name(s: &str) -> Result<&str, ArgError> {
    let bad = s.is_empty()
        || s.len() > MAX_NAME_LEN
        || matches!(s.as_bytes().first(), Some(b'.' | b' '))
        || s.ends_with(' ')
        || s.chars()
            .any(|c| c == '/' || c == '\\' || is_control(c) || is_format(c));
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

/// Text: non-empty, no control or format characters (Unicode Cc, Cf: a
/// console showing stored text must not be spoofed, and U+202E turns
/// `a\u{202E}b` around), and no trailing space (the frame's trailing
/// spaces are not part of it, so it could not round-trip).
pub(crate) fn text(s: &str) -> Result<&str, ArgError> {
    if s.is_empty() {
        Err(ArgError::Missing)
    } else if s.ends_with(' ') || s.chars().any(|c| is_control(c) || is_format(c)) {
        Err(ArgError::BadText)
    } else {
        Ok(s)
    }
}

/// Free text (a plan): [`text`] of at most [`MAX_TEXT_LEN`] bytes.
pub(crate) fn free_text(s: &str) -> Result<&str, ArgError> {
    at_most(text(s)?, MAX_TEXT_LEN, Bound::Text)
}

/// A task name: [`text`] of at most [`MAX_TASK_NAME_LEN`] bytes.
pub(crate) fn task_name(s: &str) -> Result<&str, ArgError> {
    at_most(text(s)?, MAX_TASK_NAME_LEN, Bound::TaskName)
}

fn at_most(s: &str, max: usize, bound: Bound) -> Result<&str, ArgError> {
    if s.len() > max {
        Err(ArgError::OutOfRange(bound))
    } else {
        Ok(s)
    }
}

/// A login attempt is text (no password holds a Cc or Cf character);
/// whether it matches is the session's business.
pub(crate) fn secret(s: &str) -> Result<&str, ArgError> {
    text(s)
}

/// DESIGN.md: 1–32 printable ASCII characters, no space, not `1025` or
/// `0315`. (A daemon may choose other special values; [`crate::Auth`]
/// refuses those too.)
pub(crate) fn new_password(s: &str) -> Result<&str, ArgError> {
    match crate::password::chars(s)? {
        DEFAULT_ADMIN_PASSWORD | DEFAULT_LOGOUT_PASSWORD => Err(ArgError::SpecialPassword),
        s => Ok(s),
    }
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

/// `control_take`'s argument: exactly the word `failsafe`.
pub(crate) fn override_word(s: &str) -> Result<bool, ArgError> {
    if s == "failsafe" {
        Ok(true)
    } else {
        Err(ArgError::Malformed)
    }
}

/// A JSON payload: well-formed, validated without allocating.
pub(crate) fn json(s: &str) -> Result<&str, ArgError> {
    super::json::validate(s).map(|()| s)
}
