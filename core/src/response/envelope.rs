//! The reply envelope: `{"ret":..,"cmd":..,"ts":..` around a response's
//! members, `ret` rewritten in place when a command fails, and whole error
//! replies.

use super::json::{Sink, put, put_all};
use crate::error::Ret;
use crate::number;

/// The longest head, `{"ret":..,"cmd":..,"ts":..`.
const HEAD_RESERVE: usize = r#"{"ret":-100,"cmd":255,"ts":-9223372036854775808"#.len();

/// The smallest response buffer every error response fits in: the longest
/// head, `,"msg":"`, the longest message (an unknown name of 32 bytes that
/// are all escaped as `\u00XX`) and `"}`.
pub const MIN_RESPONSE_CAPACITY: usize =
    HEAD_RESERVE + r#","msg":"Unsupported command: "}"#.len() + 6 * crate::error::messages::UNKNOWN_NAME_ECHO;

/// Whether `reply`, a reply this crate wrote, is a success: its head
/// starts `{"ret":0,` (a failure's `ret` is rewritten in place, never left
/// 0). For a reader that needs no more of it than that.
pub fn is_success(reply: &[u8]) -> bool {
    reply.starts_with(br#"{"ret":0,"#)
}

impl Sink<'_> {
    /// `{"ret":..,"cmd":..,"ts":..`: in one piece when there is room for
    /// the longest (always, but in a buffer too small for any response).
    pub(super) fn head(&mut self, ret: Ret, cmd: u8, ts: i64) {
        let room = self
            .buf
            .get_mut(self.len..)
            .and_then(|rest| rest.first_chunk_mut::<HEAD_ROOM>());
        let Some(dst) = room.filter(|_| !self.overflow) else {
            self.bytes(br#"{"ret":"#);
            self.int(i64::from(ret.code()));
            self.bytes(br#","cmd":"#);
            self.int(i64::from(cmd));
            self.bytes(br#","ts":"#);
            self.int(ts);
            return;
        };
        let mut at = put_all(dst, br#"{"ret":"#);
        at = small_int(dst, at, i32::from(ret.code()));
        at += put_all(dst.get_mut(at..).unwrap_or_default(), br#","cmd":"#);
        at = small_int(dst, at, i32::from(cmd));
        at += put_all(dst.get_mut(at..).unwrap_or_default(), br#","ts":"#);
        if let Some(digits) = dst
            .get_mut(at..)
            .and_then(|rest| rest.first_chunk_mut::<{ number::INT_ROOM }>())
        {
            at += number::write_i64(ts, digits);
        }
        self.len += at;
    }
}

/// Writes `{"ret":..,"cmd":..,"ts":..` and returns the head's length, or
/// `None` if `buf` is too short.
fn head(buf: &mut [u8], ret: Ret, cmd: u8, ts: i64) -> Option<usize> {
    let mut s = Sink::new(buf, 0);
    s.head(ret, cmd, ts);
    (!s.overflow).then_some(s.len)
}

/// Room for the longest head and the spare bytes of its digit stores.
const HEAD_ROOM: usize = HEAD_RESERVE + 8;

/// Writes `v` (-999..=999) at `at`; returns where it ends.
#[inline]
fn small_int(dst: &mut [u8], at: usize, v: i32) -> usize {
    put(dst, at, b'-');
    let at = at + usize::from(v < 0);
    let v = v.unsigned_abs();
    let hundreds = v / 100;
    put(dst, at, b'0' + (hundreds % 10) as u8);
    let at = at + usize::from(hundreds > 0);
    let [tens, units] = number::pair(v % 100);
    put(dst, at, tens);
    let at = at + usize::from(v >= 10);
    put(dst, at, units);
    at + 1
}

/// How much longer the head gets when `ret` 0 is rewritten as a failure's
/// (`-100` at most).
pub(super) const RET_GROWTH: usize = 3;

/// Completes a response whose head [`Fields::after_head`] wrote with `ret`
/// 0 and whose members (the command's fields, or the `msg` of
/// [`Fields::fail`]) end at `body_end`: closes the object, after rewriting
/// the head with `ret` if that is not 0. Returns the response length, or
/// `None` if it does not fit.
pub(crate) fn finish(buf: &mut [u8], ret: Ret, cmd: u8, ts: i64, body_end: usize) -> Option<usize> {
    if ret == Ret::Ok {
        *buf.get_mut(body_end)? = b'}';
        return Some(body_end + 1);
    }
    // A failure with a message written in place: the head grows by up to
    // RET_GROWTH bytes, so the message moves right (rare, and short).
    let mut old = [0u8; HEAD_RESERVE];
    let old_len = head(&mut old, Ret::Ok, cmd, ts)?;
    let mut new = [0u8; HEAD_RESERVE];
    let new_len = head(&mut new, ret, cmd, ts)?;
    let shift = new_len.checked_sub(old_len)?;
    let end = body_end + shift;
    buf.get(end)?;
    for i in (old_len..body_end).rev() {
        let b = *buf.get(i)?;
        *buf.get_mut(i + shift)? = b;
    }
    buf.get_mut(..new_len)?.copy_from_slice(new.get(..new_len)?);
    *buf.get_mut(end)? = b'}';
    Some(end + 1)
}

/// Writes a whole error response `{"ret":..,"cmd":..,"ts":..,"msg":".."}`
/// whose message is `parts` concatenated. `None` if `buf` is too short.
pub(crate) fn write_error(buf: &mut [u8], ret: Ret, cmd: u8, ts: i64, parts: &[&str]) -> Option<usize> {
    let len = head(buf, ret, cmd, ts)?;
    let mut s = Sink::new(buf, len);
    s.bytes(br#","msg":"#);
    s.string(parts);
    s.byte(b'}');
    (!s.overflow).then_some(s.len)
}

/// Adds `retry_after_s` to the error response of `end` bytes in `buf` (a
/// login the throttle refused says when to try again); the new length.
pub(crate) fn retry_after(buf: &mut [u8], end: usize, secs: u32) -> Option<usize> {
    // Over the closing brace.
    let mut s = Sink::new(buf, end.checked_sub(1)?);
    s.bytes(br#","retry_after_s":"#);
    s.int(i64::from(secs));
    s.byte(b'}');
    (!s.overflow).then_some(s.len)
}
