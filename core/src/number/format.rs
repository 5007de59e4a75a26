//! f32 → the shortest decimal text that reads back as the same f32.
//!
//! The digits are those of the shortest decimal inside the float's rounding
//! interval (the reals that round to it), the one nearest the float when
//! several are that short, ties to even: the same digits as Ryu. They are
//! found the Schubfach way (R. Giulietti, "The Schubfach way to render
//! doubles", 2020): scale the float and both ends of its interval by the
//! power of ten that makes the interval between 1 and 10 units wide; then
//! the answer is one of four candidates, the multiples of ten on either
//! side of the scaled float or the integers on either side of it.
//!
//! The scaled values are floors of 64-bit products (see [`super::pow10`]);
//! whether a scaled value is an integer (which decides whether an interval
//! end or the midpoint between two candidates is hit exactly) is decided by
//! divisibility, exactly, so a value at an end of its interval is inside
//! it exactly when the parser would round it to this float.

use super::pow10;

/// The longest text [`format_f32`] writes: a sign, `0.`, five zeros and
/// nine digits (`-0.0000123456789`).
pub const MAX_LEN: usize = 17;

/// The text of an `f32`, as [`format_f32`] writes it.
#[derive(Clone, Copy, Debug)]
pub struct Shortest {
    bytes: [u8; MAX_LEN],
    len: usize,
}

impl Shortest {
    /// The text, ASCII.
    pub fn as_str(&self) -> &str {
        core::str::from_utf8(self.as_bytes()).unwrap_or_default()
    }

    /// The text's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or_default()
    }
}

/// The shortest text that [`super::parse_f32`] (or `str::parse::<f32>`)
/// reads back as exactly `v`, laid out as Ryu does: `1.5`, `-10.0`, `0.1`,
/// `1e30`, `1.2e-7`, `0.0`, `-0.0`; `NaN`, `inf` and `-inf` for the values
/// that are not finite (which JSON has no numbers for: the response writer
/// writes `null` instead).
pub fn format_f32(v: f32) -> Shortest {
    let mut bytes = [0; MAX_LEN];
    let len = write(v, &mut bytes);
    Shortest { bytes, len }
}

/// Writes [`format_f32`]'s text of `v` into `out`; returns its length.
pub(crate) fn write(v: f32, out: &mut [u8; MAX_LEN]) -> usize {
    let bits = v.to_bits();
    let magnitude = bits & 0x7FFF_FFFF;
    let mut w = Cursor { buf: out, len: 0 };
    if magnitude > 0x7F80_0000 {
        w.extend(b"NaN");
        return w.len;
    }
    if bits >> 31 != 0 {
        w.push(b'-');
    }
    match magnitude {
        0 => w.extend(b"0.0"),
        0x7F80_0000 => w.extend(b"inf"),
        _ => {
            let (digits, exp) = shortest(magnitude);
            layout(&mut w, digits, exp);
        }
    }
    w.len
}

/// The shortest decimal `digits · 10^exp` in the rounding interval of the
/// positive finite float whose bits are `bits`, nearest to it among those
/// (ties to even), with no trailing zeros in `digits`.
fn shortest(bits: u32) -> (u32, i32) {
    let fraction = bits & 0x7F_FFFF;
    let biased = (bits >> 23) as i32;
    // v = c · 2^q.
    let (c, q) = if biased == 0 {
        (fraction, -149)
    } else {
        (fraction | 1 << 23, biased - 150)
    };
    // At a power of two the float below is only half as far away as the
    // one above (except below the smallest normal, where the spacing of
    // the subnormals continues).
    let irregular = fraction == 0 && biased > 1;
    let k = if irregular {
        pow10::floor_log10_three_quarters_pow2(q)
    } else {
        pow10::floor_log10_pow2(q)
    };
    // Scale by 10^-k, in quarter units: for an interval end c' · 2^(q-2)
    // (c' = 4c ± 2, or 4c - 1 below a power of two) that is
    // c' · 2^q · 10^-k ≈ c' · g · 2^-shift, with shift in 60..=63.
    let g = pow10::g(-k).unwrap_or_default();
    let shift = 63 - q - pow10::floor_log2_pow10(-k);
    // Round to odd: the floor, with the lowest bit set when the scaled value
    // is not an integer. Comparisons with multiples of four (the candidates)
    // and with the midpoint between two of them are then exact.
    let scale = |cp: u32| mul_shift(g, cp, shift) | u32::from(!integral(cp, q, k));
    let cb = c << 2;
    let vb = scale(cb);
    let vbl = scale(cb - 2 + u32::from(irregular));
    let vbr = scale(cb + 2);
    // The interval's ends belong to it when the float's mantissa is even
    // (a decimal exactly halfway rounds to the even neighbour).
    let out = c & 1;

    let s = vb >> 2;
    // One digit shorter: the multiples of ten on either side. The interval
    // is under ten units wide, so at most one of them is inside.
    // (With a single digit in s, a multiple of ten is no shorter.)
    let tens = s / 10;
    let lower_ten_in = vbl + out <= 40 * tens;
    let upper_ten_in = 40 * tens + 40 + out <= vbr;
    if s >= 10 && lower_ten_in != upper_ten_in {
        return strip_zeros(tens + u32::from(upper_ten_in), k + 1);
    }
    // Otherwise s or s + 1 (the interval is at least one unit wide, so one
    // of them is inside), the nearer one if both are.
    let lower_in = vbl + out <= 4 * s;
    let upper_in = 4 * s + 4 + out <= vbr;
    let upper = if lower_in == upper_in {
        let midpoint = 4 * s + 2;
        vb > midpoint || (vb == midpoint && s & 1 == 1)
    } else {
        upper_in
    };
    strip_zeros(s + u32::from(upper), k)
}

/// ⌊cp · g / 2^shift⌋ for shift in 60..=63, from 32-bit halves.
fn mul_shift(g: u64, cp: u32, shift: i32) -> u32 {
    let high = (g >> 32) * u64::from(cp);
    let low = (g & 0xFFFF_FFFF) * u64::from(cp);
    let top = high + (low >> 32);
    let by = u32::try_from(shift - 32).unwrap_or(31);
    // cp < 2^26 and g < 2^64, so the result is below 2^30.
    (top >> by) as u32
}

/// Whether cp · 2^q · 10^-k = cp · 2^(q-k) · 5^-k is an integer.
fn integral(cp: u32, q: i32, k: i32) -> bool {
    let twos = q - k >= 0 || cp.trailing_zeros() as i32 >= k - q;
    // cp < 2^26 < 5^12: no larger power of five divides it.
    let fives = k <= 0 || (k < 12 && cp.is_multiple_of(5u32.pow(k as u32)));
    twos && fives
}

/// `digits · 10^exp` with the trailing zeros of `digits` moved to `exp`.
fn strip_zeros(mut digits: u32, mut exp: i32) -> (u32, i32) {
    while digits != 0 && digits.is_multiple_of(10) {
        digits /= 10;
        exp += 1;
    }
    (digits, exp)
}

/// Ryu's layout of `digits · 10^exp`: plain decimal notation while the
/// decimal point is within 13 digits of the first digit and at most 5 zeros
/// follow it, scientific notation otherwise.
fn layout(w: &mut Cursor<'_>, digits: u32, exp: i32) {
    let mut text = [0u8; 10];
    let start = super::decimal_u32(digits, &mut text);
    let digits = text.get(start..).unwrap_or_default();
    let n = digits.len() as i32;
    // The decimal point's place: 10^(point-1) <= value < 10^point.
    let point = n + exp;
    if exp >= 0 && point <= 13 {
        w.extend(digits);
        w.zeros(exp);
        w.extend(b".0");
    } else if 0 < point && point <= 13 {
        let (int, frac) = digits.split_at_checked(point as usize).unwrap_or_default();
        w.extend(int);
        w.push(b'.');
        w.extend(frac);
    } else if -6 < point && point <= 0 {
        w.extend(b"0.");
        w.zeros(-point);
        w.extend(digits);
    } else {
        if let Some((first, rest)) = digits.split_first() {
            w.push(*first);
            if !rest.is_empty() {
                w.push(b'.');
                w.extend(rest);
            }
        }
        w.push(b'e');
        let e = point - 1;
        if e < 0 {
            w.push(b'-');
        }
        let mut text = [0u8; 10];
        let start = super::decimal_u32(e.unsigned_abs(), &mut text);
        w.extend(text.get(start..).unwrap_or_default());
    }
}

/// Bytes appended to a fixed buffer; what does not fit is dropped (the
/// layouts above never exceed [`MAX_LEN`], which the tests check for every
/// float).
struct Cursor<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl Cursor<'_> {
    fn push(&mut self, b: u8) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = b;
            self.len += 1;
        }
    }

    fn extend(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.push(b);
        }
    }

    fn zeros(&mut self, n: i32) {
        for _ in 0..n {
            self.push(b'0');
        }
    }
}
