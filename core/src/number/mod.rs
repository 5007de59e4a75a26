//! Numbers between text and `f32`, exactly, without tables large enough to
//! matter on a microcontroller (one 616-byte table of powers of ten serves
//! both directions).
//!
//! - [`parse_f32`]: decimal text → the nearest `f32` (ties to even), the
//!   same value as `str::parse::<f32>` for every decimal text, with the
//!   request grammar's syntax check built in (no leading `+`, no `nan`,
//!   `inf`, hex).
//! - [`format_f32`]: `f32` → the shortest text that reads back as the same
//!   `f32` (`0.1`, never `0.10000000149011612`), the same text as Ryu.
//! - [`Number`]: a number as a client sent it, compared with a range on its
//!   exact decimal value (`90.000001` is above 90, though its `f32` is 90).
//!
//! Both are proven against `core`'s parser and Ryu: every f32 bit pattern
//! in a sweep over all exponents, long runs of consecutive ones, and
//! millions of random decimal texts (`core/tests/numbers.rs`), and a fuzz
//! target (`fuzz/fuzz_targets/numbers.rs`).

mod exact;
mod format;
mod parse;
mod pow10;
mod sent;

pub(crate) use format::write as write_f32;
pub use format::{MAX_LEN, Shortest, format_f32};
pub use parse::parse_f32;
pub(crate) use sent::Exact;
pub use sent::Number;

/// "00" to "99".
const PAIRS: &[u8; 200] = b"\
0001020304050607080910111213141516171819\
2021222324252627282930313233343536373839\
4041424344454647484950515253545556575859\
6061626364656667686970717273747576777879\
8081828384858687888990919293949596979899";

/// The two ASCII digits of `v` (below 100).
pub(crate) fn pair(v: u32) -> [u8; 2] {
    let at = (v as usize % 100) * 2;
    match PAIRS.get(at..at + 2) {
        Some(&[a, b]) => [a, b],
        _ => [b'0'; 2],
    }
}

/// The eight decimal digits of `v` (below 10^8), zero-padded, in ASCII:
/// all at once in one 64-bit word (two 4-digit lanes, split into four
/// 2-digit lanes, split into eight digits), no table, no loop.
pub(crate) fn eight_digits(v: u32) -> [u8; 8] {
    // The first digits go to the lowest bytes (little-endian order).
    let x = u64::from(v / 10_000) | u64::from(v % 10_000) << 32;
    // ⌊n · 10486 / 2^20⌋ = ⌊n / 100⌋ for n < 43699.
    let hundreds = ((x * 10_486) >> 20) & 0x0000_007F_0000_007F;
    let x = hundreds | (x - hundreds * 100) << 16;
    // ⌊n · 103 / 2^10⌋ = ⌊n / 10⌋ for n < 179.
    let tens = ((x * 103) >> 10) & 0x000F_000F_000F_000F;
    let x = tens | (x - tens * 10) << 8;
    (x + 0x3030_3030_3030_3030).to_le_bytes()
}

/// Room for [`write_u64`] and [`write_i64`]: 20 characters, and the spare
/// bytes their eight-byte stores may write beyond.
pub(crate) const INT_ROOM: usize = 24;

/// Writes `v` in decimal at the start of `out`; returns the length.
pub(crate) fn write_u64(v: u64, out: &mut [u8; INT_ROOM]) -> usize {
    digits_at(v, out, 0)
}

/// Writes `v` in decimal at the start of `out`; returns the length.
pub(crate) fn write_i64(v: i64, out: &mut [u8; INT_ROOM]) -> usize {
    let sign = usize::from(v < 0);
    if let Some(first) = out.first_mut() {
        *first = b'-';
    }
    digits_at(v.unsigned_abs(), out, sign)
}

/// An integer's decimal text, for a message made of parts (no
/// `core::fmt`, which a firmware would link for it).
pub(crate) struct Digits {
    buf: [u8; INT_ROOM],
    len: usize,
}

impl Digits {
    /// The digits of `v`.
    pub(crate) fn of(v: i64) -> Digits {
        let mut buf = [0; INT_ROOM];
        let len = write_i64(v, &mut buf);
        Digits { buf, len }
    }

    /// The text.
    pub(crate) fn as_str(&self) -> &str {
        self.buf
            .get(..self.len)
            .and_then(|b| core::str::from_utf8(b).ok())
            .unwrap_or("")
    }
}

/// Writes `v` (below 100) at `at`: one or two digits (the second written
/// over the first when there is only one); returns where they end.
#[inline]
fn small_at(v: u32, out: &mut [u8], at: usize) -> usize {
    let [tens, units] = pair(v);
    let two = usize::from(v >= 10);
    put(out, at, tens);
    put(out, at + two, units);
    at + 1 + two
}

/// Writes the digits of `v` at `at`; returns where they end.
fn digits_at(v: u64, out: &mut [u8; INT_ROOM], at: usize) -> usize {
    if v < 100 {
        return small_at(v as u32, out, at);
    }
    // 32-bit cores have no 64-bit division: split by multiplication into
    // a top below 10^8 and up to two eight-digit groups (a millisecond
    // timestamp has one).
    const GROUP: u64 = 100_000_000;
    let (top, first, second, groups) = if v < GROUP {
        (v, 0, 0, 0)
    } else {
        let high = div_1e8(v);
        let low = (v - high * GROUP) as u32;
        if high < GROUP {
            (high, low, 0, 1)
        } else {
            let top = div_1e8(high);
            (top, (high - top * GROUP) as u32, low, 2)
        }
    };
    // The n digits of the top are the last n of its eight.
    let top = top as u32;
    let n = digit_count(top);
    let mut end = at;
    for (i, group) in [top, first, second].into_iter().take(1 + groups).enumerate() {
        let text = u64::from_le_bytes(eight_digits(group));
        let (text, width) = if i == 0 {
            (text >> (8 * (8 - n)), n)
        } else {
            (text, 8)
        };
        put8(out, end, text.to_le_bytes());
        end += width;
    }
    end
}

fn put(out: &mut [u8], at: usize, b: u8) {
    if let Some(slot) = out.get_mut(at) {
        *slot = b;
    }
}

fn put8(out: &mut [u8], at: usize, bytes: [u8; 8]) {
    if let Some(dst) = out.get_mut(at..).and_then(|rest| rest.first_chunk_mut::<8>()) {
        *dst = bytes;
    }
}

/// 10^0 to 10^9: every power of ten a `u32` holds.
pub(crate) const POW10_U32: [u32; 10] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
];

/// How many decimal digits `v` has (one for zero).
pub(crate) fn digit_count(v: u32) -> usize {
    // ⌊log10 2^bits⌋, or one more.
    // Zero has one digit; setting the lowest bit never reaches a power of ten.
    let v = v | 1;
    let bits = 32 - v.leading_zeros();
    let t = ((bits * 1_233) >> 12) as usize;
    t + usize::from(POW10_U32.get(t).is_some_and(|&p| v >= p))
}

/// `v / 10^8` by multiplication (a 32-bit core has no 64-bit division):
/// ⌊v · m / 2^90⌋ with m = ⌈2^90 / 10^8⌉, exact for every u64 since
/// m · 10^8 − 2^90 <= 2^26 (Granlund and Montgomery).
pub(crate) fn div_1e8(v: u64) -> u64 {
    mul_high(v, 0xABCC_7711_8461_CEFD) >> 26
}

/// The high 64 bits of the 128-bit product `a · b`.
pub(crate) fn mul_high(a: u64, b: u64) -> u64 {
    #[cfg(target_pointer_width = "64")]
    {
        ((u128::from(a) * u128::from(b)) >> 64) as u64
    }
    #[cfg(not(target_pointer_width = "64"))]
    {
        mul_high_by_halves(a, b)
    }
}

/// [`mul_high`] from 32-bit halves, for 32-bit cores (which have no 64×64
/// multiplication; a 128-bit one would be a library call).
#[cfg_attr(target_pointer_width = "64", allow(dead_code))]
fn mul_high_by_halves(a: u64, b: u64) -> u64 {
    const LOW: u64 = 0xFFFF_FFFF;
    let (a1, a0) = (a >> 32, a & LOW);
    let (b1, b0) = (b >> 32, b & LOW);
    let low = a0 * b0;
    let cross1 = a0 * b1;
    let cross2 = a1 * b0;
    let middle = (low >> 32) + (cross1 & LOW) + (cross2 & LOW);
    a1 * b1 + (cross1 >> 32) + (cross2 >> 32) + (middle >> 32)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn eight_digits_are_the_zero_padded_decimal() {
        for v in (0..100_000_000).step_by(7).chain(99_999_990..100_000_000) {
            let mut want = [b'0'; 8];
            let mut rest = v;
            for d in want.iter_mut().rev() {
                *d = b'0' + (rest % 10) as u8;
                rest /= 10;
            }
            assert_eq!(eight_digits(v), want, "{v}");
        }
    }

    #[test]
    fn digit_counts_are_exact() {
        let mut p: u64 = 1;
        for n in 1..=10usize {
            // 10^(n-1) and the values around it.
            for v in [p.saturating_sub(1), p, p + 1, p * 10 - 1] {
                if let Ok(v) = u32::try_from(v) {
                    let want = (1..=10).find(|&d| u64::from(v) < 10u64.pow(d)).unwrap_or(0) as usize;
                    assert_eq!(digit_count(v), want, "{v}");
                }
            }
            p *= 10;
            let _ = n;
        }
        assert_eq!(digit_count(0), 1);
        assert_eq!(digit_count(u32::MAX), 10);
    }

    #[test]
    fn division_by_ten_to_the_eight_is_exact() {
        let mut x: u64 = 0x2545_F491_4F6C_DD1D;
        for i in 0..1_000_000u64 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            for v in [
                x,
                x >> (i % 64),
                i,
                u64::MAX - i,
                i * 100_000_000,
                (i * 100_000_000).wrapping_sub(1),
            ] {
                assert_eq!(div_1e8(v), v / 100_000_000, "{v}");
            }
        }
    }

    #[test]
    fn high_products_are_exact() {
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..1_000_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let y = x.rotate_left(29) ^ 0x5555;
            let want = ((u128::from(x) * u128::from(y)) >> 64) as u64;
            assert_eq!(mul_high(x, y), want);
            assert_eq!(mul_high_by_halves(x, y), want);
        }
        assert_eq!(mul_high_by_halves(u64::MAX, u64::MAX), u64::MAX - 1);
    }
}
