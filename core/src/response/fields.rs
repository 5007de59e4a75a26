//! The builders a backend writes a response's members with: [`Fields`]
//! for an object's members, [`Items`] for an array's elements, both over
//! the [JSON writer](super::json).

use core::fmt;

use serde::Serialize;

use super::json::{Sink, put_all};
use crate::error::{Failure, Ret};
use crate::number;

/// Writes the members of a JSON object: the command-specific fields of a
/// response, or the members of a nested object.
///
/// Keys and string values are escaped; numbers are written exactly (floats
/// in their shortest round-trip form, non-finite ones as `null`).
pub struct Fields<'b> {
    sink: Sink<'b>,
    first: bool,
}

/// Writes the elements of a JSON array.
pub struct Items<'b> {
    sink: Sink<'b>,
    first: bool,
}

macro_rules! value_writers {
    ($ty:ident, $lead:ident, $scalar:ident ($($key:ident: &str)?)) => {
        impl $ty<'_> {
            /// A string.
            #[inline]
            pub fn str(&mut self, $($key: &str,)? v: &str) -> &mut Self {
                self.$lead($($key)?);
                self.sink.quoted(None, v, None);
                self
            }
            /// A signed integer.
            #[inline]
            pub fn i64(&mut self, $($key: &str,)? v: i64) -> &mut Self {
                self.$scalar($($key,)? |d| number::write_i64(v, d));
                self
            }
            /// An unsigned integer.
            #[inline]
            pub fn u64(&mut self, $($key: &str,)? v: u64) -> &mut Self {
                self.$scalar($($key,)? |d| number::write_u64(v, d));
                self
            }
            /// A double; NaN and infinities are written as `null`.
            #[inline]
            pub fn f64(&mut self, $($key: &str,)? v: f64) -> &mut Self {
                self.$scalar($($key,)? |d| write_f64(v, d));
                self
            }
            /// A float; NaN and infinities are written as `null`.
            #[inline]
            pub fn f32(&mut self, $($key: &str,)? v: f32) -> &mut Self {
                self.$scalar($($key,)? |d| write_f32(v, d));
                self
            }
            /// A boolean.
            #[inline]
            pub fn bool(&mut self, $($key: &str,)? v: bool) -> &mut Self {
                self.$scalar($($key,)? |d: &mut [u8; 5]| put_all(d, if v { b"true" } else { b"false" }));
                self
            }
            /// `null`.
            #[inline]
            pub fn null(&mut self $(, $key: &str)?) -> &mut Self {
                self.$scalar($($key,)? |d: &mut [u8; 4]| put_all(d, b"null"));
                self
            }
            /// Any serde-serialisable value, written by serde-json-core.
            pub fn serialize<T: Serialize + ?Sized>(&mut self, $($key: &str,)? v: &T) -> &mut Self {
                self.$lead($($key)?);
                self.sink.serialize(v);
                self
            }
            /// A nested object whose members `f` writes.
            pub fn object(&mut self, $($key: &str,)? f: impl FnOnce(&mut Fields<'_>)) -> &mut Self {
                self.$lead($($key)?);
                self.sink.byte(b'{');
                let mut inner = Fields { sink: self.sink.reborrow(), first: true };
                f(&mut inner);
                let state = inner.sink.state();
                self.sink.resume(state);
                self.sink.byte(b'}');
                self
            }
            /// A nested array whose elements `f` writes.
            pub fn array(&mut self, $($key: &str,)? f: impl FnOnce(&mut Items<'_>)) -> &mut Self {
                self.$lead($($key)?);
                self.sink.byte(b'[');
                let mut inner = Items { sink: self.sink.reborrow(), first: true };
                f(&mut inner);
                let state = inner.sink.state();
                self.sink.resume(state);
                self.sink.byte(b']');
                self
            }
        }
    };
}

value_writers!(Fields, member, field(key: &str));
value_writers!(Items, element, item());

/// Values this close to zero are written `0`: a response carries no float
/// noise (a yaw of 3.3e-16 left over from arithmetic is 0; DESIGN.md).
const NOISE: f64 = 1e-6;

/// [`NOISE`] as an `f32`, compared without widening (the same verdict for
/// every `f32`).
const NOISE_F32: f32 = 1e-6;

/// Shortest round-trip text (`0.1`, `-10.0`, `1e30`: [`crate::number`],
/// the same text as Ryu), `-0` and noise written as 0 (`0.0`); JSON has no NaN or
/// infinity, so those are `null`.
fn write_f32(v: f32, out: &mut [u8; number::MAX_LEN]) -> usize {
    if v.abs() <= NOISE_F32 {
        number::write_f32(0.0, out)
    } else if v.is_finite() {
        number::write_f32(v, out)
    } else {
        put_all(out, b"null")
    }
}

/// Shortest round-trip text by Ryu (`1.5`, `-10.0`, `1e300`), `-0` and
/// noise written as 0 (`0.0`), or `null`.
/// Only host backends write doubles; a firmware that never does links
/// none of Ryu.
fn write_f64(v: f64, out: &mut [u8; 24]) -> usize {
    if v.abs() <= NOISE {
        put_all(out, ryu::Buffer::new().format_finite(0.0).as_bytes())
    } else if v.is_finite() {
        put_all(out, ryu::Buffer::new().format_finite(v).as_bytes())
    } else {
        put_all(out, b"null")
    }
}

impl<'b> Fields<'b> {
    /// A writer for the members of the response to `cmd` at `ts`, written
    /// into `buf` after the head `{"ret":0,"cmd":..,"ts":..`, which it
    /// writes first ([`super::finish`] corrects `ret` if the command fails), so
    /// that a successful response is never moved.
    pub(crate) fn after_head(buf: &'b mut [u8], cmd: u8, ts: i64) -> Self {
        let mut sink = Sink::new(buf, 0);
        sink.head(Ret::Ok, cmd, ts);
        sink.origin = sink.len;
        Fields { sink, first: false }
    }

    /// Fails the command with `ret` and a message written whole into the
    /// response buffer (cut at a character boundary only if the buffer
    /// cannot hold it), discarding every field written so far; return the
    /// result from [`crate::Backend::execute`]. Unlike [`Failure::new`],
    /// the message is not limited to
    /// [`crate::error::FAILURE_MSG_CAPACITY`] bytes.
    pub fn fail(&mut self, ret: Ret, msg: fmt::Arguments<'_>) -> Failure {
        self.sink.failure(msg);
        Failure::written(ret)
    }

    /// As [`Fields::fail`], the message in parts (no `core::fmt`, which a
    /// firmware would otherwise link for it).
    pub fn fail_parts(&mut self, ret: Ret, parts: &[&str]) -> Failure {
        self.sink.failure_parts(parts);
        Failure::written(ret)
    }

    /// A string member made of `parts`, escaped.
    pub fn str_parts(&mut self, key: &str, parts: &[&str]) -> &mut Self {
        self.member(key);
        self.sink.string(parts);
        self
    }

    /// A string member holding what `text` formats to (escaped), for text
    /// built from parts without a buffer of its own.
    pub fn display(&mut self, key: &str, text: fmt::Arguments<'_>) -> &mut Self {
        self.member(key);
        self.sink.display(text);
        self
    }

    /// The end of the failure message [`Fields::fail`] wrote, if it did.
    pub(crate) fn failure_end(&self) -> Option<usize> {
        self.sink.failed_at
    }

    fn member(&mut self, key: &str) {
        let lead = (!core::mem::take(&mut self.first)).then_some(b',');
        self.sink.quoted(lead, key, Some(b':'));
    }

    #[inline]
    fn field<const MAX: usize>(&mut self, key: &str, value: impl FnOnce(&mut [u8; MAX]) -> usize) {
        let comma = !core::mem::take(&mut self.first);
        self.sink.scalar(comma, Some(key), value);
    }

    /// Whether everything written so far fitted.
    pub fn fits(&self) -> bool {
        !self.sink.overflow
    }

    /// The end of what was written, or `None` if something did not fit.
    pub(crate) fn end(&self) -> Option<usize> {
        self.fits().then_some(self.sink.len)
    }
}

impl Items<'_> {
    fn element(&mut self) {
        if !core::mem::take(&mut self.first) {
            self.sink.byte(b',');
        }
    }

    #[inline]
    fn item<const MAX: usize>(&mut self, value: impl FnOnce(&mut [u8; MAX]) -> usize) {
        let comma = !core::mem::take(&mut self.first);
        self.sink.scalar(comma, None, value);
    }
}
