//! The JSON writer under every response: a [`Sink`] over the caller's
//! buffer that writes bytes, escaped strings (RFC 8259) and scalar values,
//! lends itself to nested objects and arrays, and stops for good at the
//! first write that does not fit (overflow is sticky), so that a response
//! is whole or replaced.

use core::fmt;

use serde::Serialize;

use super::envelope::RET_GROWTH;
use crate::number;

/// Room for the longest scalar value: an f64 by Ryu, and an integer's
/// spare bytes.
const SCRATCH: usize = 24;

/// The bytes written so far and whether anything failed to fit.
pub(super) struct Sink<'b> {
    pub(super) buf: &'b mut [u8],
    pub(super) len: usize,
    pub(super) overflow: bool,
    /// Where the response's members start (for [`Fields::fail`]).
    pub(super) origin: usize,
    /// The end of a failure message written by [`Fields::fail`]; once set,
    /// nothing else is written.
    pub(super) failed_at: Option<usize>,
}

/// What a nested writer hands back to its parent.
pub(super) type SinkState = (usize, bool, Option<usize>);

impl<'b> Sink<'b> {
    /// A writer whose response's members start at `len`, what is already
    /// in `buf` before it kept.
    pub(super) fn new(buf: &'b mut [u8], len: usize) -> Self {
        Sink {
            buf,
            len,
            overflow: false,
            origin: len,
            failed_at: None,
        }
    }

    /// The next `n` bytes of the buffer, counted as written (the caller
    /// fills them all); `None`, and overflow, when they do not fit.
    fn room(&mut self, n: usize) -> Option<&mut [u8]> {
        let start = self.len;
        let end = start.saturating_add(n);
        if self.overflow || end > self.buf.len() {
            self.overflow = true;
            return None;
        }
        self.len = end;
        self.buf.get_mut(start..end)
    }

    pub(super) fn bytes(&mut self, b: &[u8]) {
        if let Some(dst) = self.room(b.len()) {
            dst.copy_from_slice(b);
        }
    }

    pub(super) fn byte(&mut self, b: u8) {
        if let Some([dst]) = self.room(1) {
            *dst = b;
        }
    }

    /// A JSON string made of `parts`, escaped per RFC 8259.
    pub(super) fn string(&mut self, parts: &[&str]) {
        self.byte(b'"');
        for part in parts {
            self.escaped(part);
        }
        self.byte(b'"');
    }

    /// `lead`, `s` as a JSON string, then `trail` (string values, and the
    /// keys of nested objects and arrays; scalar members have their own
    /// path, [`Sink::lead_and_room`]). On 32-bit targets, microcontrollers
    /// with little flash, always in pieces: 440 bytes less code, for more
    /// instructions per string.
    pub(super) fn quoted(&mut self, lead: Option<u8>, s: &str, trail: Option<u8>) {
        #[cfg(target_pointer_width = "64")]
        self.quoted_in_one(lead, s, trail);
        #[cfg(not(target_pointer_width = "64"))]
        self.quoted_in_pieces(lead, s, trail);
    }

    /// [`Sink::quoted`] in one piece when `s` needs no escapes (most
    /// strings): one capacity check, the text copied and checked in words.
    #[cfg_attr(not(target_pointer_width = "64"), allow(dead_code))]
    fn quoted_in_one(&mut self, lead: Option<u8>, s: &str, trail: Option<u8>) {
        let text = s.as_bytes();
        let at = usize::from(lead.is_some());
        let end = at + 1 + text.len();
        let start = self.len;
        let Some(dst) = self.room(end + 1 + usize::from(trail.is_some())) else {
            return;
        };
        let plain = dst.get_mut(at + 1..end).is_some_and(|d| copy_plain(d, text));
        if plain {
            if let Some(b) = lead {
                put(dst, 0, b);
            }
            put(dst, at, b'"');
            put(dst, end, b'"');
            if let Some(b) = trail {
                put(dst, end + 1, b);
            }
        } else {
            self.len = start;
            self.quoted_in_pieces(lead, s, trail);
        }
    }

    fn quoted_in_pieces(&mut self, lead: Option<u8>, s: &str, trail: Option<u8>) {
        if let Some(b) = lead {
            self.byte(b);
        }
        self.string(&[s]);
        if let Some(b) = trail {
            self.byte(b);
        }
    }

    fn escaped(&mut self, s: &str) {
        let mut rest = s.as_bytes();
        // Escapes are rare: copy the runs between them in one go.
        while let Some(run) = first_escape(rest) {
            let Some((plain, escape)) = rest.split_at_checked(run) else {
                return;
            };
            self.bytes(plain);
            let Some((&b, tail)) = escape.split_first() else {
                return;
            };
            let short = match b {
                b'"' => b'"',
                b'\\' => b'\\',
                b'\n' => b'n',
                b'\r' => b'r',
                b'\t' => b't',
                _ => 0,
            };
            if short != 0 {
                self.bytes(&[b'\\', short]);
            } else {
                const HEX: &[u8; 16] = b"0123456789abcdef";
                let hex = |nibble: u8| HEX.get(usize::from(nibble & 0xf)).copied().unwrap_or(b'0');
                self.bytes(&[b'\\', b'u', b'0', b'0', hex(b >> 4), hex(b)]);
            }
            rest = tail;
        }
        self.bytes(rest);
    }

    /// A scalar member or element: `,` if `comma`, `"key":` if there is a
    /// key, then the at most `MAX` bytes `value` writes. One capacity check
    /// for all of it while there is room for the most it can take (nearly
    /// always).
    #[inline]
    pub(super) fn scalar<const MAX: usize>(
        &mut self,
        comma: bool,
        key: Option<&str>,
        value: impl FnOnce(&mut [u8; MAX]) -> usize,
    ) {
        const { assert!(MAX <= SCRATCH, "the slow path's scratch holds every value") };
        let room = self.lead_and_room(comma, key, MAX);
        match room.and_then(|at| Some((at, self.buf.get_mut(at..)?.first_chunk_mut::<MAX>()?))) {
            Some((at, dst)) => self.len = at + value(dst),
            None => {
                // One copy of the slow path for every kind of value.
                let mut value = Some(value);
                self.scalar_slowly(comma, key, &mut |text: &mut [u8; SCRATCH]| {
                    let dst = text.first_chunk_mut::<MAX>();
                    value.take().zip(dst).map_or(0, |(value, dst)| value(dst))
                });
            }
        }
    }

    /// Writes `,` if `comma` and `"key":` if there is a key, when there is
    /// room for them and `value_max` bytes after them; returns where the
    /// value goes. Inlined, so that a constant key is checked for escapes
    /// and copied at compile time. `None` when out of room or the key needs
    /// escapes: then nothing was written.
    #[cfg_attr(target_pointer_width = "64", inline)]
    #[cfg_attr(not(target_pointer_width = "64"), inline(never))]
    fn lead_and_room(&mut self, comma: bool, key: Option<&str>, value_max: usize) -> Option<usize> {
        if self.overflow {
            return None;
        }
        let rest = self.buf.get_mut(self.len..)?;
        if rest.len() < key.map_or(0, |k| k.len() + 3) + 1 + value_max {
            return None;
        }
        put(rest, 0, b',');
        let at = usize::from(comma);
        let at = match key {
            Some(key) => put_key(rest, at, key.as_bytes())?,
            None => at,
        };
        Some(self.len + at)
    }

    /// [`Sink::scalar`] near the end of the buffer, or with a key that
    /// needs escapes: the value into a scratch buffer, then piece by piece.
    #[cold]
    #[inline(never)]
    fn scalar_slowly(
        &mut self,
        comma: bool,
        key: Option<&str>,
        value: &mut dyn FnMut(&mut [u8; SCRATCH]) -> usize,
    ) {
        let mut text = [0; SCRATCH];
        let n = value(&mut text);
        self.scalar_in_pieces(comma, key, text.get(..n).unwrap_or_default());
    }

    #[inline(never)]
    fn scalar_in_pieces(&mut self, comma: bool, key: Option<&str>, value: &[u8]) {
        if comma {
            self.byte(b',');
        }
        if let Some(key) = key {
            self.string(&[key]);
            self.byte(b':');
        }
        self.bytes(value);
    }

    pub(super) fn int(&mut self, v: i64) {
        self.scalar(false, None, |d| number::write_i64(v, d));
    }

    pub(super) fn serialize<T: Serialize + ?Sized>(&mut self, value: &T) {
        if self.overflow {
            return;
        }
        let rest = self.buf.get_mut(self.len..).unwrap_or_default();
        match serde_json_core::to_slice(value, rest) {
            Ok(n) => self.len += n,
            Err(_) => self.overflow = true,
        }
    }

    /// A writer over the same buffer, for a nested object or array.
    pub(super) fn reborrow(&mut self) -> Sink<'_> {
        Sink {
            buf: &mut *self.buf,
            len: self.len,
            overflow: self.overflow,
            origin: self.origin,
            failed_at: self.failed_at,
        }
    }

    pub(super) fn state(&self) -> SinkState {
        (self.len, self.overflow, self.failed_at)
    }

    /// Takes over what a nested writer wrote.
    pub(super) fn resume(&mut self, (len, overflow, failed_at): SinkState) {
        self.len = len;
        self.overflow = overflow;
        self.failed_at = failed_at;
    }

    /// A JSON string holding what `text` formats to, escaped.
    pub(super) fn display(&mut self, text: fmt::Arguments<'_>) {
        self.byte(b'"');
        // `Escaping` never fails: it only sets the overflow flag.
        let _ = fmt::write(&mut Escaping(self), text);
        self.byte(b'"');
    }

    /// Replaces everything written since `origin` with `,"msg":"<text>"`,
    /// the text escaped and cut at a character boundary where it would not
    /// fit (leaving room for the closing `}`), then refuses further writes.
    pub(super) fn failure(&mut self, text: fmt::Arguments<'_>) {
        // `Bounded` stops quietly when full; an error can only mean that.
        self.failure_with(|w| {
            let _ = fmt::write(w, text);
        });
    }

    /// As [`Sink::failure`], the text in parts (no `core::fmt` machinery).
    pub(super) fn failure_parts(&mut self, parts: &[&str]) {
        self.failure_with(|w| {
            for part in parts {
                if fmt::Write::write_str(w, part).is_err() {
                    break;
                }
            }
        });
    }

    fn failure_with(&mut self, write: impl FnOnce(&mut Bounded<'_, 'b>)) {
        self.len = self.origin;
        self.overflow = false;
        self.bytes(br#","msg":""#);
        // Room for the closing quote and brace, and for the head to grow
        // when `ret` is written into it.
        let limit = self.buf.len().saturating_sub(2 + RET_GROWTH);
        let mut w = Bounded {
            sink: self,
            limit,
            full: false,
        };
        write(&mut w);
        self.byte(b'"');
        if !self.overflow {
            self.failed_at = Some(self.len);
        }
        self.overflow = true;
    }
}

/// Copies `bytes` to the start of `out`; returns how many.
pub(super) fn put_all(out: &mut [u8], bytes: &[u8]) -> usize {
    if let Some(dst) = out.get_mut(..bytes.len()) {
        dst.copy_from_slice(bytes);
    }
    bytes.len()
}

/// Escapes text into a [`Sink`] (which notes an overflow itself).
struct Escaping<'s, 'b>(&'s mut Sink<'b>);

impl fmt::Write for Escaping<'_, '_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        self.0.escaped(s);
        Ok(())
    }
}

/// Escapes text into a [`Sink`] up to `limit`, whole characters (and whole
/// escapes) only.
struct Bounded<'s, 'b> {
    sink: &'s mut Sink<'b>,
    limit: usize,
    full: bool,
}

impl fmt::Write for Bounded<'_, '_> {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        if self.full {
            return Err(fmt::Error);
        }
        let mut one = [0u8; 4];
        for c in s.chars() {
            let before = (self.sink.len, self.sink.overflow);
            self.sink.escaped(c.encode_utf8(&mut one));
            if self.sink.overflow || self.sink.len > self.limit {
                (self.sink.len, self.sink.overflow) = before;
                self.full = true;
                return Err(fmt::Error);
            }
        }
        Ok(())
    }
}

/// Bytes that JSON strings must escape.
fn needs_escape(b: u8) -> bool {
    b < 0x20 || b == b'"' || b == b'\\'
}

/// Copies `src` into `dst` (of the same length); whether no byte of it
/// [`needs_escape`]. Short strings (keys) in two overlapping loads, longer
/// ones eight bytes at a time; never byte by byte.
#[inline]
fn copy_plain(dst: &mut [u8], src: &[u8]) -> bool {
    let n = src.len();
    let Some(dst) = dst.get_mut(..n) else {
        return false;
    };
    if n >= 8 {
        return copy_plain_long(dst, src);
    }
    let word = if let (Some(first), Some(last)) = (src.first_chunk::<4>(), src.last_chunk::<4>()) {
        // 4 to 7 bytes.
        if let Some(d) = dst.first_chunk_mut::<4>() {
            *d = *first;
        }
        if let Some(d) = dst.last_chunk_mut::<4>() {
            *d = *last;
        }
        u64::from(u32::from_le_bytes(*first)) | u64::from(u32::from_le_bytes(*last)) << 32
    } else if let (Some(&a), Some(&b), Some(&c)) = (src.first(), src.get(n / 2), src.last()) {
        // 1 to 3 bytes: the first, middle and last are all of them.
        put(dst, 0, a);
        put(dst, n / 2, b);
        put(dst, n - 1, c);
        u64::from_le_bytes([a, b, c, b' ', b' ', b' ', b' ', b' '])
    } else {
        return true;
    };
    !word_escapes(word)
}

/// [`copy_plain`] for eight bytes and more (out of line: the short case is
/// the hot one, and small): a plain copy, then [`first_escape`].
#[inline(never)]
fn copy_plain_long(dst: &mut [u8], src: &[u8]) -> bool {
    dst.copy_from_slice(src);
    first_escape(src).is_none()
}

/// Writes `"key":` at `at` into `dst` (which has the room); where it ends,
/// or `None` if the key needs escapes.
#[inline]
fn put_key(dst: &mut [u8], at: usize, key: &[u8]) -> Option<usize> {
    let end = at + 1 + key.len();
    if !dst.get_mut(at + 1..end).is_some_and(|d| copy_plain(d, key)) {
        return None;
    }
    put(dst, at, b'"');
    put(dst, end, b'"');
    put(dst, end + 1, b':');
    Some(end + 2)
}

/// Writes `b` at `at` (the caller has made the room).
#[inline]
pub(super) fn put(dst: &mut [u8], at: usize, b: u8) {
    if let Some(slot) = dst.get_mut(at) {
        *slot = b;
    }
}

/// Whether any of the eight bytes of `x` [`needs_escape`].
#[inline]
fn word_escapes(x: u64) -> bool {
    escape_flags(x) != 0
}

/// A high bit set in the bytes of `x` that [`needs_escape`] (exactly in
/// the lowest such byte; a borrow can also mark some above it).
#[inline]
fn escape_flags(x: u64) -> u64 {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const HIGH: u64 = 0x8080_8080_8080_8080;
    let zero = |x: u64| x.wrapping_sub(ONES) & !x & HIGH;
    let control = x.wrapping_sub(ONES * 0x20) & !x & HIGH;
    control | zero(x ^ (ONES * u64::from(b'"'))) | zero(x ^ (ONES * u64::from(b'\\')))
}

/// The index of the first byte that [`needs_escape`], eight bytes per step
/// (strings are mostly long runs that need none).
fn first_escape(bytes: &[u8]) -> Option<usize> {
    let mut offset = 0;
    let mut rest = bytes;
    while let Some((word, tail)) = rest.split_first_chunk::<8>() {
        let flags = escape_flags(u64::from_le_bytes(*word));
        if flags != 0 {
            // The lowest flag is exact.
            return Some(offset + (flags.trailing_zeros() / 8) as usize);
        }
        offset += 8;
        rest = tail;
    }
    // The last eight bytes, overlapping those checked, spare the byte by
    // byte search when they are clean.
    let clean_tail = bytes
        .last_chunk::<8>()
        .is_some_and(|w| escape_flags(u64::from_le_bytes(*w)) == 0);
    if rest.is_empty() || clean_tail {
        return None;
    }
    rest.iter().position(|&b| needs_escape(b)).map(|i| offset + i)
}
