//! Decimal text → the nearest f32, ties to even (correctly rounded).
//!
//! One pass over the text checks the grammar and keeps the first 19
//! significant digits. Then the first of three paths that can decide
//! exactly does:
//!
//! 1. up to 2^24 in the digits and a power of ten up to 10^10: both are
//!    exact f32s, so one IEEE multiplication or division rounds correctly
//!    (Clinger's fast path). This is what clients send: `1.5`, `-3.0`,
//!    `0.25`, `12.345`.
//! 2. up to 19 digits and a power of ten in [`super::pow10`]'s table: the
//!    digits times the table's 64-bit approximation, whose error cannot
//!    change the rounding unless the bits below the mantissa are exactly
//!    zero or exactly one half (then path 3 decides).
//! 3. everything else, exactly, with big integers ([`super::exact`]).

use super::{exact, mul_high, pow10};

/// The f32 nearest to the decimal number `text` (ties to even), as
/// `str::parse::<f32>` rounds it; `None` if `text` is not the request
/// grammar's decimal notation:
/// `-? (digits ('.' digits?)? | '.' digits) ([eE] [+-]? digits)?`.
/// So a leading `+`, spaces, `nan`, `inf` and hexadecimal are refused
/// (where `str::parse` would read `+1`), and a number beyond
/// `f32::MAX` (after rounding) is an infinity, which the request grammar
/// then refuses. Any number of digits and any exponent are read exactly.
pub fn parse_f32(text: &str) -> Option<f32> {
    if let Some(v) = short(text.as_bytes()) {
        return Some(v);
    }
    let decimal = Decimal::scan(text.as_bytes())?;
    let magnitude = decimal.magnitude();
    Some(if decimal.negative { -magnitude } else { magnitude })
}

/// What clients send most, `-? digits ('.' digits?)?` or `'.' digits`
/// with at most seven digits and no exponent, in one tight pass: the
/// digits and 10^(fraction digits) are exact f32s, so one division rounds
/// correctly (path 1 without the general scan). `None` for anything else,
/// which the general path then reads (or refuses).
#[inline]
fn short(text: &[u8]) -> Option<f32> {
    let (negative, body) = sign(text);
    let mut w: u32 = 0;
    let mut digits = 0usize;
    let mut point = None;
    for &b in body {
        let digit = b.wrapping_sub(b'0');
        if digit <= 9 {
            w = w.wrapping_mul(10).wrapping_add(u32::from(digit));
            digits += 1;
        } else if b == b'.' && point.is_none() {
            point = Some(digits);
        } else {
            return None;
        }
    }
    if digits == 0 || digits > 7 {
        return None;
    }
    let scale = *POW10.get(digits - point.unwrap_or(digits))?;
    let v = w as f32 / scale;
    Some(if negative { -v } else { v })
}

/// The mantissa's sign: an optional `-` (a leading `+` is not the
/// grammar's, and is left in the body to be refused there).
fn sign(text: &[u8]) -> (bool, &[u8]) {
    match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        _ => (false, text),
    }
}

/// A decimal number as read from the text.
pub(super) struct Decimal<'a> {
    pub(super) negative: bool,
    /// The digits before the exponent, with the decimal point if any.
    pub(super) mantissa: &'a [u8],
    /// The first 19 significant digits (0 exactly when the number is 0).
    pub(super) w: u64,
    /// How many significant digits there are (from the first nonzero on).
    pub(super) significant: i64,
    /// The value is N · 10^exp10, N the integer of all the mantissa digits.
    pub(super) exp10: i64,
    /// Whether a nonzero digit follows the 19th significant one.
    truncated: bool,
}

/// Significant digits a u64 always holds.
const W_DIGITS: i64 = 19;

impl<'a> Decimal<'a> {
    pub(super) fn scan(text: &'a [u8]) -> Option<Self> {
        let (negative, body) = sign(text);
        let mut d = Decimal {
            negative,
            mantissa: body,
            w: 0,
            significant: 0,
            exp10: 0,
            truncated: false,
        };
        let mut rest = body;
        let int_digits = d.digits(&mut rest);
        let mut frac_digits = 0;
        if let Some((b'.', after)) = rest.split_first() {
            rest = after;
            frac_digits = d.digits(&mut rest);
        }
        if int_digits + frac_digits == 0 {
            return None;
        }
        d.mantissa = body.get(..body.len() - rest.len())?;
        let exp = match rest.split_first() {
            None => 0,
            Some((b'e' | b'E', after)) => exponent(after)?,
            Some(_) => return None,
        };
        d.exp10 = exp - frac_digits;
        Some(d)
    }

    /// Takes the digits at the front of `rest`; returns how many.
    fn digits(&mut self, rest: &mut &[u8]) -> i64 {
        let mut n = 0;
        while let Some((&b, after)) = rest.split_first() {
            let digit = b.wrapping_sub(b'0');
            if digit > 9 {
                break;
            }
            if self.w == 0 && digit == 0 {
                // A leading zero: not significant.
            } else if self.significant < W_DIGITS {
                self.w = self.w * 10 + u64::from(digit);
                self.significant += 1;
            } else {
                self.truncated |= digit != 0;
                self.significant += 1;
            }
            n += 1;
            *rest = after;
        }
        n
    }

    fn magnitude(&self) -> f32 {
        if self.w == 0 {
            return 0.0;
        }
        // The value is w · 10^e, plus whatever `truncated` says was dropped.
        let e = self.exp10 + (self.significant - W_DIGITS).max(0);
        if !self.truncated {
            if let Some(v) = exact_operands(self.w, e) {
                return v;
            }
            if let Some(v) = by_table(self.w, e) {
                return v;
            }
        }
        exact::magnitude(self)
    }
}

/// The exponent after `e`: an optional sign and at least one digit. Its
/// magnitude saturates near 10^12, far beyond where every value is zero or
/// infinite whatever the digits before it (a text would need ~10^12 digits
/// to move it back).
fn exponent(text: &[u8]) -> Option<i64> {
    let (negative, digits) = match text.split_first() {
        Some((b'-', rest)) => (true, rest),
        Some((b'+', rest)) => (false, rest),
        _ => (false, text),
    };
    if digits.is_empty() {
        return None;
    }
    let mut e: i64 = 0;
    for &b in digits {
        let digit = b.wrapping_sub(b'0');
        if digit > 9 {
            return None;
        }
        if e < 1 << 40 {
            e = e * 10 + i64::from(digit);
        }
    }
    Some(if negative { -e } else { e })
}

/// Powers of ten that are exact f32s.
const POW10: [f32; 11] = [1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10];

/// Path 1: `w · 10^e` when both operands are exact f32s, so that one
/// correctly rounded operation gives the correctly rounded result.
fn exact_operands(w: u64, e: i64) -> Option<f32> {
    let w = u32::try_from(w).ok().filter(|&w| w <= 1 << 24)?;
    let p = *POW10.get(usize::try_from(e.unsigned_abs()).ok()?)?;
    // From u32: a 32-bit core converts that in one instruction, a u64 in a
    // library call.
    let w = w as f32;
    Some(if e < 0 { w / p } else { w * p })
}

/// Path 2: `w · 10^e` from the table's approximation of 10^e, when that
/// decides the rounding; `None` when only exact arithmetic can.
fn by_table(w: u64, e: i64) -> Option<f32> {
    let e = i32::try_from(e).ok()?;
    let g = pow10::g(e)?;
    // 10^e = (g − ε) · 2^β with 0 < ε <= 1, β = ⌊log2 10^e⌋ − 63. With w
    // normalised to 64 bits, the exact product lies in (P − 2^64, P) for
    // P = wn · g, so its top 64 bits are those of P or one less.
    let lz = w.leading_zeros();
    let wn = w << lz;
    let top = mul_high(wn, g);
    // top >= 2^62: the mantissa is its highest 24 bits.
    let shift: u32 = if top >> 63 == 1 { 40 } else { 39 };
    let mantissa = top >> shift;
    let rest = top & ((1 << shift) - 1);
    let half = 1u64 << (shift - 1);
    // Only at exactly zero (a borrow could reach the mantissa) or exactly
    // one half (a tie, or either side of one) is the rounding unknown.
    if rest == 0 || rest == half {
        return None;
    }
    let mantissa = mantissa + u64::from(rest > half);
    // value ≈ mantissa · 2^exp with mantissa in [2^23, 2^24].
    let exp = shift as i32 + 1 + pow10::floor_log2_pow10(e) - lz as i32;
    if exp < -149 {
        // Subnormal: the exact path rounds at their fixed exponent.
        return None;
    }
    Some(finish(mantissa, exp))
}

/// The f32 `mantissa · 2^exp`, for a mantissa of 24 bits (or 2^24 after
/// rounding up) or a subnormal one with `exp` = −149; infinity above
/// `f32::MAX`.
pub(super) fn finish(mantissa: u64, exp: i32) -> f32 {
    // The biased exponent field is exp + 150 for a 24-bit mantissa whose
    // top bit is implicit: adding the mantissa to (exp + 149) << 23 sets
    // that field and carries a rounded-up 2^24 into it.
    let bits = (i64::from(exp) + 149) * (1 << 23) + mantissa as i64;
    match u32::try_from(bits) {
        Ok(b) if b < 0x7F80_0000 => f32::from_bits(b),
        _ => f32::INFINITY,
    }
}
