//! Frame → [`Command`].
//!
//! This parser is designed for robustness and use together with
//! `-Cpanic=abort`: it never panics, on any input. It borrows from the frame
//! and copies nothing; the only storage it fills is the fixed-capacity
//! lists inside [`Args`], and overflowing one is an error, never a silent
//! truncation.
//!
//! Grammar (DESIGN.md, "Request grammar"): trailing spaces, `\r` and `\n`
//! are dropped; the name runs to the first space; the arguments are
//! everything after that one space, verbatim.

mod fields;
mod json;
pub(crate) mod rules;
mod scan;
mod validate;

pub use json::MAX_JSON_DEPTH;
pub use rules::{
    MAX_IDENT_LEN, MAX_NAME_LEN, MAX_PASSWORD_LEN, MAX_PATH_LEN, MAX_TASK_NAME_LEN, MAX_TEXT_LEN,
};

use crate::command::{Args, Command, LandPoint, Payload, Point, Pose};
use crate::error::{ArgError, ParseError};
use crate::table::{Grammar, Spec, lookup};

/// A frame cut into its name and its raw arguments.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Split<'a> {
    /// Everything before the first space.
    pub name: &'a str,
    /// Everything after the first space, if there is one.
    pub args: Option<&'a str>,
}

/// Cuts a frame into name and arguments; `None` for an empty or blank frame.
pub fn split(frame: &str) -> Option<Split<'_>> {
    let bytes = frame.as_bytes();
    let trailing = |b: &u8| matches!(b, b' ' | b'\r' | b'\n');
    // Mostly nothing to trim: look at the last byte before searching.
    let end = if bytes.last().is_some_and(trailing) {
        bytes.iter().rposition(|b| !trailing(b))? + 1
    } else {
        bytes.len()
    };
    let frame = frame.get(..end).filter(|f| !f.is_empty())?;
    let (name, args) = scan::cut(frame, b' ');
    Some(Split { name, args })
}

/// Parses one text frame into a [`Command`].
pub fn parse(frame: &str) -> Result<Command<'_>, ParseError<'_>> {
    let split = split(frame).ok_or(ParseError::Empty)?;
    let spec = lookup(split.name).ok_or(ParseError::Unknown(split.name))?;
    parse_args(spec, split.args)
}

/// Parses the arguments of a command whose name is already known.
pub fn parse_args<'a>(spec: &Spec, args: Option<&'a str>) -> Result<Command<'a>, ParseError<'a>> {
    arguments(spec.grammar, args)
        .map(|a| Command::from_parts(spec.id, a))
        .map_err(|e| ParseError::InvalidArgs(spec.id, e))
}

fn arguments(grammar: Grammar, args: Option<&str>) -> Result<Args<'_>, ArgError> {
    let Some(a) = args else {
        return match grammar {
            Grammar::None => Ok(Args::None),
            Grammar::OptCount => Ok(Args::OptCount(None)),
            Grammar::OptAmount => Ok(Args::OptAmount(None)),
            Grammar::OptName => Ok(Args::OptName(None)),
            Grammar::Override => Ok(Args::Override(false)),
            _ => Err(ArgError::Missing),
        };
    };
    Ok(match grammar {
        Grammar::None => return Err(ArgError::Unexpected),
        Grammar::Flag => Args::Flag(fields::flag(a)?),
        Grammar::OptCount => Args::OptCount(Some(fields::uint(a)?)),
        Grammar::Pwm => Args::Pwm(fields::pwm(a)?),
        Grammar::Amount => Args::Amount(rules::non_negative(fields::number(a)?)?),
        Grammar::OptAmount => Args::OptAmount(Some(rules::non_negative(fields::number(a)?)?)),
        Grammar::Angle => Args::Angle(rules::angle(fields::number(a)?)?),
        Grammar::Name => Args::Name(rules::name(a)?),
        Grammar::OptName => Args::OptName(Some(rules::name(a)?)),
        Grammar::Path => Args::Path(rules::path(a)?),
        Grammar::Text => Args::Text(rules::free_text(a)?),
        Grammar::TaskName => Args::TaskName(rules::task_name(a)?),
        Grammar::Secret => Args::Secret(rules::secret(a)?),
        Grammar::NewPassword => Args::NewPassword(rules::new_password(a)?),
        Grammar::ParamName => Args::ParamName(rules::param_name(a)?),
        Grammar::Setpoint => {
            let [x, y, z, yaw] = fields::numbers(a, ':')?;
            Args::Setpoint(rules::setpoint(Pose { x, y, z, yaw })?)
        }
        Grammar::Point => {
            let [x, y, z] = fields::numbers(a, ':')?;
            Args::Point(Point { x, y, z })
        }
        Grammar::Pose => {
            let [x, y, z, yaw] = fields::numbers(a, ',')?;
            Args::Pose(Pose { x, y, z, yaw })
        }
        Grammar::Zyhk => zyhk(a)?,
        Grammar::SetParam => {
            let (name, value) = fields::split_first(a, ':')?;
            Args::SetParam {
                name: rules::param_name(name)?,
                value: rules::text(value)?,
            }
        }
        Grammar::Mission => {
            let (ext_id, payload) = fields::split_first(a, ':')?;
            let payload = if payload.starts_with(['{', '[']) {
                Payload::Json(rules::json(payload)?)
            } else {
                Payload::Path(rules::path(payload)?)
            };
            Args::Mission {
                ext_id: fields::uint(ext_id)?,
                payload,
            }
        }
        Grammar::MwExec => {
            let (ext_id, ids) = fields::split_first(a, ':')?;
            Args::MwExec {
                ext_id: fields::uint(ext_id)?,
                wp_ids: fields::list(ids, ',', fields::uint)?,
            }
        }
        Grammar::Override => Args::Override(rules::override_word(a)?),
        Grammar::Ai1Mission => {
            let (task_id, file) = fields::split_first(a, ':')?;
            Args::Ai1Mission {
                task_id: rules::task_id(task_id)?,
                file: rules::path(file)?,
            }
        }
    })
}

/// `h1,h2,... [lx,ly,lyaw]`: heights, then optionally one space and a
/// landing point.
fn zyhk(a: &str) -> Result<Args<'_>, ArgError> {
    let (heights, land) = match fields::split_first(a, ' ') {
        Ok((heights, land)) => (heights, Some(land)),
        Err(_) => (a, None),
    };
    let land = match land {
        Some(l) => {
            let [x, y, yaw] = fields::numbers(l, ',')?;
            Some(LandPoint { x, y, yaw })
        }
        None => None,
    };
    Ok(Args::Zyhk {
        heights: fields::list(heights, ',', fields::float)?,
        land,
    })
}
