//! [`Command`] → canonical text: the mirror image of [`crate::parse()`].
//!
//! Floats are written as responses write them ([`crate::number`]: the
//! shortest text that reads back as the same `f32`), so `parse(encode(c))
//! == c` holds for every command (a property test proves it). Encoding never allocates: it writes into any [`fmt::Write`], such
//! as a `heapless::String` on a microcontroller or a `String` on a host.

use core::fmt::{self, Display, Write};

use crate::command::{Args, Command, Payload};
use crate::number::{Number, format_f32};

impl Command<'_> {
    /// Writes the frame for this command.
    pub fn encode<W: Write>(&self, w: &mut W) -> fmt::Result {
        w.write_str(self.id().name())?;
        let arg = |w: &mut W| w.write_char(' ');
        match self.args() {
            Args::None
            | Args::OptCount(None)
            | Args::OptAmount(None)
            | Args::OptName(None)
            | Args::Override(false) => Ok(()),
            Args::Override(true) => w.write_str(" failsafe"),
            Args::Flag(on) => {
                arg(w)?;
                w.write_char(if *on { '1' } else { '0' })
            }
            Args::OptCount(Some(n)) => write!(w, " {n}"),
            Args::Pwm(n) => write!(w, " {n}"),
            Args::Amount(n) | Args::OptAmount(Some(n)) => {
                arg(w)?;
                sent(w, n)
            }
            Args::Angle(v) => {
                arg(w)?;
                float(w, *v)
            }
            Args::Name(s)
            | Args::OptName(Some(s))
            | Args::Path(s)
            | Args::Text(s)
            | Args::TaskName(s)
            | Args::Secret(s)
            | Args::NewPassword(s)
            | Args::ParamName(s) => {
                arg(w)?;
                w.write_str(s)
            }
            Args::SetParam { name, value } => {
                arg(w)?;
                write!(w, "{name}:{value}")
            }
            Args::Setpoint(p) => {
                arg(w)?;
                floats(w, ':', &[p.x, p.y, p.z, p.yaw])
            }
            Args::Point(p) => {
                arg(w)?;
                floats(w, ':', &[p.x, p.y, p.z])
            }
            Args::Pose(p) => {
                arg(w)?;
                floats(w, ',', &[p.x, p.y, p.z, p.yaw])
            }
            Args::Zyhk { heights, land } => {
                arg(w)?;
                floats(w, ',', heights)?;
                match land {
                    Some(l) => {
                        w.write_char(' ')?;
                        floats(w, ',', &[l.x, l.y, l.yaw])
                    }
                    None => Ok(()),
                }
            }
            Args::Mission { ext_id, payload } => {
                arg(w)?;
                write!(w, "{ext_id}:")?;
                match payload {
                    Payload::Json(s) | Payload::Path(s) => w.write_str(s),
                }
            }
            Args::MwExec { ext_id, wp_ids } => {
                arg(w)?;
                write!(w, "{ext_id}:")?;
                joined(w, ',', wp_ids)
            }
            Args::Ai1Mission { task_id, file } => {
                arg(w)?;
                write!(w, "{task_id}:{file}")
            }
        }
    }
}

/// A number as it was sent, so that the range a backend checks is the
/// same; one made from an `f32`, in its shortest form.
fn sent<W: Write>(w: &mut W, n: &Number<'_>) -> fmt::Result {
    match n.text() {
        Some(text) => w.write_str(text),
        None => float(w, n.value()),
    }
}

/// An `f32` in its shortest form, `-0` written `0`.
fn float<W: Write>(w: &mut W, v: f32) -> fmt::Result {
    w.write_str(format_f32(v + 0.0).as_str())
}

fn floats<W: Write>(w: &mut W, sep: char, items: &[f32]) -> fmt::Result {
    for (i, item) in items.iter().enumerate() {
        if i > 0 {
            w.write_char(sep)?;
        }
        float(w, *item)?;
    }
    Ok(())
}

fn joined<W: Write, T: Display>(w: &mut W, sep: char, items: &[T]) -> fmt::Result {
    for (i, item) in items.iter().enumerate() {
        if i > 0 {
            w.write_char(sep)?;
        }
        write!(w, "{item}")?;
    }
    Ok(())
}

/// The frame text, as [`Command::encode`] writes it.
impl Display for Command<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.encode(f)
    }
}
