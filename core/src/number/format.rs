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

use super::{POW10_U32, pow10};

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
    if magnitude > 0x7F80_0000 {
        return put(out, 0, b"NaN");
    }
    let sign = usize::from(bits >> 31 != 0);
    put(out, 0, b"-");
    let Some(body) = out.get_mut(sign..) else {
        return 0;
    };
    sign + match magnitude {
        0 => put(body, 0, b"0.0"),
        0x7F80_0000 => put(body, 0, b"inf"),
        _ => {
            let (digits, exp) = short_exact(magnitude).unwrap_or_else(|| shortest(magnitude));
            layout(body, digits, exp)
        }
    }
}

/// The float itself as `digits · 10^exp` when that is short enough to be
/// the answer: `1.5`, `-2.25`, `87.5`, `100.0` (most of what a vehicle
/// reports as round values), without the search [`shortest`] does.
///
/// A float c · 2^q is an exact decimal with f = max(0, −q') fraction
/// digits, q' = q + (trailing zero bits of c). Every decimal with fewer
/// significant digits is a multiple of 10^(1−f) (at the same magnitude),
/// so it is at least 10^−f away; when half the spacing of floats, 2^(q−1),
/// is less than that, none is inside the rounding interval, and the exact
/// value (distance 0) is the nearest of the shortest.
fn short_exact(bits: u32) -> Option<(u32, i32)> {
    let biased = (bits >> 23) as i32;
    if biased == 0 {
        return None;
    }
    let c = bits & 0x7F_FFFF | 1 << 23;
    let q = biased - 150;
    let zeros = c.trailing_zeros();
    let odd = c >> zeros;
    let exact_exp = q + zeros as i32;
    if exact_exp >= 0 {
        // An integer; below 2^24 (q <= 0) the spacing is at most 1, and any
        // other integer is at least 1 away.
        return (q <= 0).then(|| strip_zeros(odd << exact_exp, 0));
    }
    let f = exact_exp.unsigned_abs() as usize;
    let five = *POW5.get(f)?;
    let digits = odd.checked_mul(five).filter(|&d| d < 1_000_000_000)?;
    // 10^-f > 2^(q-1), i.e. 10^f < 2^(1-q); 1 - q > 0 here, f <= 13.
    let spacing_bits = (1 - q).unsigned_abs();
    let ten_f = u64::from(five) << f;
    let fits = spacing_bits >= 64 || ten_f < 1 << spacing_bits;
    fits.then_some((digits, exact_exp))
}

/// 5^0 to 5^13, the powers of five below 2^32.
const POW5: [u32; 14] = [
    1,
    5,
    25,
    125,
    625,
    3_125,
    15_625,
    78_125,
    390_625,
    1_953_125,
    9_765_625,
    48_828_125,
    244_140_625,
    1_220_703_125,
];

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
    // Scale by 10^-k, in quarter units: for v and the interval's ends,
    // c' · 2^(q-2) with c' = 4c, 4c + 2 and 4c - 2 (4c - 1 below a power of
    // two), that is c' · 2^q · 10^-k ≈ c' · g · 2^-shift, shift in 60..=63.
    let g = pow10::g(-k).unwrap_or_default();
    let shift = 63 - q - pow10::floor_log2_pow10(-k);
    let cb = c << 2;
    let cbl = cb - 2 + u32::from(irregular);
    let cbr = cb + 2;
    // Round to odd: the floor, with the lowest bit set when the scaled value
    // is not an integer. Comparisons with multiples of four (the candidates)
    // and with the midpoint between two of them are then exact.
    let [exact_l, exact_b, exact_r] = integral([cbl, cb, cbr], q, k);
    let vb = mul_shift(g, cb, shift) | u32::from(!exact_b);
    let vbl = mul_shift(g, cbl, shift) | u32::from(!exact_l);
    let vbr = mul_shift(g, cbr, shift) | u32::from(!exact_r);
    // The interval's ends belong to it when the float's mantissa is even
    // (a decimal exactly halfway rounds to the even neighbour).
    let out = c & 1;

    let s = vb >> 2;
    // One digit shorter: the multiples of ten on either side. The interval
    // is under ten units wide, so at most one of them is inside. (With a
    // single digit in s, a multiple of ten is no shorter.)
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

/// Whether each cp · 2^q · 10^-k = cp · 2^(q-k) · 5^-k is an integer.
fn integral(cps: [u32; 3], q: i32, k: i32) -> [bool; 3] {
    if q < k {
        // Then q < 0, so k < 0 too: only the power of two divides.
        let twos = (k - q).unsigned_abs();
        cps.map(|cp| cp.trailing_zeros() >= twos)
    } else if k <= 0 {
        [true; 3]
    } else if k < 12 {
        let five = 5u32.pow(k.unsigned_abs());
        cps.map(|cp| cp.is_multiple_of(five))
    } else {
        // cp < 2^26 < 5^12.
        [false; 3]
    }
}

/// `digits · 10^exp` with the trailing zeros of `digits` moved to `exp`.
fn strip_zeros(mut digits: u32, mut exp: i32) -> (u32, i32) {
    // n is a multiple of 10^k exactly when n · 5^-k (mod 2^32), rotated
    // right by k, is at most u32::MAX / 10^k, and then that is n / 10^k:
    // multiplying by the inverse of 5^k maps the multiples of 5^k onto
    // 0..=u32::MAX / 5^k and everything else above, and the rotation moves
    // any of the k low bits (not a multiple of 2^k) to the top.
    const INV5: u32 = 0xCCCC_CCCD;
    const INV25: u32 = INV5.wrapping_mul(INV5);
    const INV625: u32 = INV25.wrapping_mul(INV25);
    const INV5_8: u32 = INV625.wrapping_mul(INV625);
    for (inverse, k, max) in [
        (INV5_8, 8, u32::MAX / 100_000_000),
        (INV625, 4, u32::MAX / 10_000),
        (INV25, 2, u32::MAX / 100),
        (INV5, 1, u32::MAX / 10),
    ] {
        let q = digits.wrapping_mul(inverse).rotate_right(k);
        if q <= max {
            digits = q;
            exp += k as i32;
        }
    }
    (digits, exp)
}

fn pow10(n: usize) -> u32 {
    POW10_U32.get(n).copied().unwrap_or(1)
}

/// Ryu's layout of `digits · 10^exp` (digits < 10^9) at the start of
/// `out`: plain decimal notation while the decimal point is within 13
/// digits of the first digit and at most 5 zeros follow it, scientific
/// notation otherwise. Returns the length.
fn layout(out: &mut [u8], digits: u32, exp: i32) -> usize {
    // The number of digits: ⌊log10 2^bits⌋ or one more.
    let bits = 32 - digits.leading_zeros();
    let t = ((bits * 1_233) >> 12) as usize;
    let n = t + usize::from(digits >= pow10(t));
    // The decimal point's place: 10^(point-1) <= value < 10^point.
    let point = n as i32 + exp;
    if exp >= 0 && point <= 13 {
        // 1234e2 → 123400.0
        let point = point.unsigned_abs() as usize;
        put_digits(out, 0, n, digits);
        if let Some(zeros) = out.get_mut(n..point) {
            zeros.fill(b'0');
        }
        point + put(out, point, b".0")
    } else if 0 < point && point <= 13 {
        // 1234e-2 → 12.34
        let point = point.unsigned_abs() as usize;
        let scale = pow10(n - point);
        put_digits(out, 0, point, digits / scale);
        put(out, point, b".");
        put_digits(out, point + 1, n - point, digits % scale);
        n + 1
    } else if -6 < point && point <= 0 {
        // 1234e-6 → 0.001234
        let zeros = point.unsigned_abs() as usize;
        put(out, 0, b"0.");
        if let Some(z) = out.get_mut(2..2 + zeros) {
            z.fill(b'0');
        }
        put_digits(out, 2 + zeros, n, digits);
        2 + zeros + n
    } else {
        // 1234e30 → 1.234e33, 1e30
        let scale = pow10(n - 1);
        put_digits(out, 0, 1, digits / scale);
        let mut len = 1;
        if n > 1 {
            put(out, 1, b".");
            put_digits(out, 2, n - 1, digits % scale);
            len = n + 1;
        }
        let e = point - 1;
        len += put(out, len, if e < 0 { b"e-" } else { b"e" });
        let e = e.unsigned_abs();
        let width = if e >= 10 { 2 } else { 1 };
        put_digits(out, len, width, e);
        len + width
    }
}

/// Copies `bytes` into `out` at `at`; returns how many.
fn put(out: &mut [u8], at: usize, bytes: &[u8]) -> usize {
    if let Some(dst) = out.get_mut(at..at + bytes.len()) {
        dst.copy_from_slice(bytes);
    }
    bytes.len()
}

/// Writes the `width` lowest decimal digits of `v` (zero-padded) into
/// `out` at `at`, two per step.
fn put_digits(out: &mut [u8], at: usize, width: usize, mut v: u32) {
    let Some(dst) = out.get_mut(at..at + width) else {
        return;
    };
    let (odd, pairs) = dst.split_at_mut(width % 2);
    for pair in pairs.rchunks_exact_mut(2) {
        pair.copy_from_slice(&super::pair(v % 100));
        v /= 100;
    }
    if let Some(d) = odd.first_mut() {
        *d = b'0' + (v % 10) as u8;
    }
}
