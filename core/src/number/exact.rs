//! The exact path of the parser: decimal → f32 by big-integer division,
//! for what the fast paths leave (more than 19 significant digits,
//! exponents beyond the table, subnormals, the rare products the table
//! cannot round). Small rather than fast: it runs rarely.
//!
//! Only the first [`MAX_DIGITS`] significant digits take part, the rest
//! only as "something nonzero follows". That is exact: every f32 midpoint
//! (the decimals where rounding changes) has at most 113 significant
//! digits, so a midpoint near the value is a multiple of the last kept
//! digit's unit and cannot fall strictly between the kept digits and the
//! whole number; it can only equal the kept digits, and then what follows
//! decides.

use core::cmp::Ordering;

use super::parse::{Decimal, finish};

/// Significant digits read exactly.
const MAX_DIGITS: i64 = 120;

/// 448 bits: the largest number below is 2^25 times 5^166 (the power of
/// five for 120 digits at the smallest exponent), under 2^412.
const LIMBS: usize = 14;

/// The magnitude of `d`, correctly rounded.
pub(super) fn magnitude(d: &Decimal<'_>) -> f32 {
    // 10^lead <= value < 10^(lead + 1).
    let lead = d.significant + d.exp10 - 1;
    if lead >= 39 {
        return f32::INFINITY;
    }
    if lead < -46 {
        // Below 10^-46, under half the smallest subnormal (2^-150).
        return 0.0;
    }
    let mut num = Big::small(0);
    let mut kept = 0;
    let mut sticky = false;
    let (mut chunk, mut chunk_len) = (0u32, 0u32);
    for &b in d.mantissa {
        let digit = b.wrapping_sub(b'0');
        if digit > 9 || (kept == 0 && digit == 0) {
            // The decimal point, or a leading zero.
            continue;
        }
        if kept == MAX_DIGITS {
            sticky |= digit != 0;
            continue;
        }
        chunk = chunk * 10 + u32::from(digit);
        chunk_len += 1;
        kept += 1;
        if chunk_len == 9 {
            num.mul_add(1_000_000_000, chunk);
            (chunk, chunk_len) = (0, 0);
        }
    }
    num.mul_add(10u32.pow(chunk_len), chunk);

    // value ≈ num · 10^e = num · 5^e · 2^e, |e| <= 166 after the checks above.
    let e = i32::try_from(d.exp10 + (d.significant - kept)).unwrap_or_default();
    let mut den = Big::small(1);
    if e >= 0 {
        num.mul_pow5(e.unsigned_abs());
    } else {
        den.mul_pow5(e.unsigned_abs());
    }
    // value = num / den · 2^e: scale the quotient to 25 or 26 bits.
    let shift = 25 - (num.bits() as i32 - den.bits() as i32);
    if shift >= 0 {
        num.shl(shift.unsigned_abs());
    } else {
        den.shl(shift.unsigned_abs());
    }
    let mut q = 0u32;
    den.shl(25);
    for bit in (0..26).rev() {
        q <<= 1;
        if num.cmp(&den) != Ordering::Less {
            num.sub(&den);
            q |= 1;
        }
        if bit > 0 {
            den.shr1();
        }
    }
    round(q, e - shift, !num.is_zero() || sticky)
}

/// The f32 nearest to (q + r) · 2^exp for 2^24 <= q < 2^26 and 0 <= r < 1,
/// r > 0 exactly when `inexact`; ties to even.
fn round(q: u32, exp: i32, inexact: bool) -> f32 {
    let width = 32 - q.leading_zeros() as i32;
    // Drop the bits beyond a mantissa's 24, or more where the value is
    // subnormal (their last bit is worth 2^-149): at least one.
    let drop = (width - 24).max(-149 - exp).max(1).unsigned_abs();
    let kept = q.checked_shr(drop).unwrap_or(0);
    let round_bit = q.checked_shr(drop - 1).unwrap_or(0) & 1;
    let below = q & 1u32.checked_shl(drop - 1).map_or(u32::MAX, |b| b - 1) != 0;
    let up = round_bit == 1 && (below || inexact || kept & 1 == 1);
    finish(u64::from(kept + u32::from(up)), exp + drop as i32)
}

/// A fixed-width unsigned integer, least significant 32 bits first. Every
/// value above stays far below its width, so carries out are never lost.
#[derive(Clone, Copy)]
struct Big([u32; LIMBS]);

impl Big {
    fn small(v: u32) -> Big {
        let mut b = Big([0; LIMBS]);
        if let Some(low) = b.0.first_mut() {
            *low = v;
        }
        b
    }

    /// self = self · m + add.
    fn mul_add(&mut self, m: u32, add: u32) {
        let mut carry = u64::from(add);
        for limb in &mut self.0 {
            let t = u64::from(*limb) * u64::from(m) + carry;
            *limb = t as u32;
            carry = t >> 32;
        }
    }

    fn mul_pow5(&mut self, mut n: u32) {
        while n > 0 {
            // 5^13 is the largest power of five below 2^32.
            let step = n.min(13);
            self.mul_add(5u32.pow(step), 0);
            n -= step;
        }
    }

    /// The number of significant bits.
    fn bits(&self) -> u32 {
        let mut bits = 32 * LIMBS as u32;
        for limb in self.0.iter().rev() {
            if *limb != 0 {
                return bits - limb.leading_zeros();
            }
            bits -= 32;
        }
        0
    }

    fn shl(&mut self, n: u32) {
        let limbs = (n / 32) as usize;
        let bits = n % 32;
        // From the top down, so that every limb is read before it is
        // overwritten.
        for i in (0..LIMBS).rev() {
            let limb = |j: Option<usize>| j.and_then(|j| self.0.get(j)).copied().unwrap_or(0);
            let high = limb(i.checked_sub(limbs));
            let low = limb(i.checked_sub(limbs + 1));
            let v = if bits == 0 {
                high
            } else {
                high << bits | low >> (32 - bits)
            };
            if let Some(slot) = self.0.get_mut(i) {
                *slot = v;
            }
        }
    }

    fn shr1(&mut self) {
        let mut carry = 0;
        for limb in self.0.iter_mut().rev() {
            let v = *limb;
            *limb = v >> 1 | carry << 31;
            carry = v & 1;
        }
    }

    /// self = self − other, for self >= other.
    fn sub(&mut self, other: &Big) {
        let mut borrow = false;
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            let (d, b1) = a.overflowing_sub(*b);
            let (d, b2) = d.overflowing_sub(u32::from(borrow));
            *a = d;
            borrow = b1 || b2;
        }
    }

    fn cmp(&self, other: &Big) -> Ordering {
        self.0.iter().rev().cmp(other.0.iter().rev())
    }

    fn is_zero(&self) -> bool {
        self.0.iter().all(|&limb| limb == 0)
    }
}
