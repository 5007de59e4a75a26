//! Numbers between text and `f32`, exactly, without tables large enough to
//! matter on a microcontroller (one 616-byte table of powers of ten serves
//! both directions).
//!
//! - [`parse_f32`]: decimal text → the nearest `f32` (ties to even), the
//!   same value as `str::parse::<f32>` for every decimal text, with the
//!   request grammar's syntax check built in (no `nan`, `inf`, hex).
//! - [`format_f32`]: `f32` → the shortest text that reads back as the same
//!   `f32` (`0.1`, never `0.10000000149011612`), the same text as Ryu.
//!
//! Both are proven against `core`'s parser and Ryu: every f32 bit pattern
//! in a sweep over all exponents, long runs of consecutive ones, and
//! millions of random decimal texts (`core/tests/numbers.rs`), and a fuzz
//! target (`fuzz/fuzz_targets/numbers.rs`).

mod exact;
mod format;
mod parse;
mod pow10;

pub(crate) use format::write as write_f32;
pub use format::{MAX_LEN, Shortest, format_f32};
pub use parse::parse_f32;

/// "00" to "99".
const PAIRS: &[u8; 200] = b"\
0001020304050607080910111213141516171819\
2021222324252627282930313233343536373839\
4041424344454647484950515253545556575859\
6061626364656667686970717273747576777879\
8081828384858687888990919293949596979899";

/// Writes `v` in decimal at the end of `buf`, two digits per step; returns
/// where the digits start.
pub(crate) fn decimal_u32(mut v: u32, buf: &mut [u8; 10]) -> usize {
    let mut at = buf.len();
    while v >= 100 {
        let pair = (v % 100) as usize * 2;
        v /= 100;
        at = at.saturating_sub(2);
        copy_pair(buf, at, pair);
    }
    if v >= 10 {
        at = at.saturating_sub(2);
        copy_pair(buf, at, v as usize * 2);
    } else {
        at = at.saturating_sub(1);
        if let Some(d) = buf.get_mut(at) {
            *d = b'0' + v as u8;
        }
    }
    at
}

fn copy_pair(buf: &mut [u8], at: usize, pair: usize) {
    if let (Some(dst), Some(src)) = (buf.get_mut(at..at + 2), PAIRS.get(pair..pair + 2)) {
        dst.copy_from_slice(src);
    }
}
