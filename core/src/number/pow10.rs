//! Powers of ten as 64-bit binary approximations, shared by the parser and
//! the formatter: `10^e ≈ g · 2^(floor_log2_pow10(e) − 63)` with `g` in
//! `[2^63, 2^64)`, rounded up (the next integer above the exact value).
//!
//! The table is computed by the compiler from its definition (see
//! [`approx`]), so there are no magic constants to get wrong; tests check
//! it against exact arithmetic.

/// The smallest exponent in the table: the formatter scales by `10^-k` for
/// `k` up to 31 (f32 values up to 2^128 ≈ 3.4·10^38).
pub(super) const MIN_E: i32 = -31;
/// The largest exponent in the table: the formatter scales the smallest
/// subnormal, 1.4·10^-45, by 10^45.
pub(super) const MAX_E: i32 = 45;

const LEN: usize = (MAX_E - MIN_E + 1) as usize;

/// `G[e − MIN_E]` = ⌊10^e · 2^(63 − ⌊log2 10^e⌋)⌋ + 1.
static G: [u64; LEN] = table();

/// The approximation of `10^e`, for `e` in `MIN_E..=MAX_E`.
pub(super) fn g(e: i32) -> Option<u64> {
    let index = usize::try_from(e.checked_sub(MIN_E)?).ok()?;
    G.get(index).copied()
}

/// ⌊log2 10^e⌋ for |e| ≤ 70 (checked by a test).
pub(super) fn floor_log2_pow10(e: i32) -> i32 {
    (e * 13_606) >> 12
}

/// ⌊log10 2^q⌋ for |q| ≤ 160 (checked by a test).
pub(super) fn floor_log10_pow2(q: i32) -> i32 {
    (q * 1_233) >> 12
}

/// ⌊log10 (3/4 · 2^q)⌋ for |q| ≤ 160 (checked by a test).
pub(super) fn floor_log10_three_quarters_pow2(q: i32) -> i32 {
    (q * 1_233 - 515) >> 12
}

const fn table() -> [u64; LEN] {
    let mut t = [0u64; LEN];
    let mut rest: &mut [u64] = &mut t;
    let mut e = MIN_E;
    while let [slot, tail @ ..] = rest {
        *slot = approx(e);
        rest = tail;
        e += 1;
    }
    t
}

/// ⌊10^e · 2^(63 − ⌊log2 10^e⌋)⌋ + 1, exactly, for |e| ≤ 54 (5^54 fits
/// 128 bits). Evaluated by the compiler only: an overflow here is a build
/// error, never a run-time one.
const fn approx(e: i32) -> u64 {
    let m = e.unsigned_abs();
    let mut five: u128 = 1;
    let mut i = 0;
    while i < m {
        five *= 5;
        i += 1;
    }
    let bits = 128 - five.leading_zeros();
    if e >= 0 {
        // 10^e = 5^e · 2^e, and ⌊log2 10^e⌋ = e + bits − 1: the value is
        // 5^e · 2^(64 − bits), whose top 64 bits are those of 5^e.
        let top = if bits <= 64 {
            five << (64 - bits)
        } else {
            five >> (bits - 64)
        };
        top as u64 + 1
    } else {
        // 10^e = 1 / (5^m · 2^m), and ⌊log2 10^e⌋ = −m − bits (5^m is not
        // a power of two): the value is 2^(63 + bits) / 5^m.
        quotient_of_pow2(63 + bits, five) + 1
    }
}

/// ⌊2^n / d⌋ for d > 1 and a quotient below 2^64, by long division.
const fn quotient_of_pow2(n: u32, d: u128) -> u64 {
    // The dividend is a one followed by n zeros; the remainder stays below
    // d, so doubling it cannot overflow for d < 2^127.
    let mut remainder: u128 = 1;
    let mut quotient: u64 = 0;
    let mut i = 0;
    while i < n {
        remainder <<= 1;
        quotient <<= 1;
        if remainder >= d {
            remainder -= d;
            quotient |= 1;
        }
        i += 1;
    }
    quotient
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// Whether 10^e >= 2^n, exactly (|e| <= 54, |n| small enough).
    fn pow10_at_least_pow2(e: i32, n: i32) -> bool {
        let five = 5u128.pow(e.unsigned_abs());
        if e >= 0 {
            // 5^e · 2^e >= 2^n  <=>  5^e >= 2^(n − e)
            let s = n - e;
            s < 0 || (s < 128 && five >= 1u128 << s)
        } else {
            // 1 / (5^m · 2^m) >= 2^n  <=>  2^(−n − m) >= 5^m
            let s = -n + e;
            s >= 128 || (s >= 0 && 1u128 << s >= five)
        }
    }

    /// `a · b` as a 256-bit number (high, low).
    fn mul(a: u64, b: u128) -> (u128, u128) {
        let (b1, b0) = (b >> 64, b & u128::from(u64::MAX));
        let low = u128::from(a) * b0;
        let high = u128::from(a) * b1 + (low >> 64);
        (high >> 64, (high << 64) | (low & u128::from(u64::MAX)))
    }

    /// 2^n as a 256-bit number (high, low).
    fn pow2(n: u32) -> (u128, u128) {
        if n >= 128 {
            (1u128 << (n - 128), 0)
        } else {
            (0, 1u128 << n)
        }
    }

    #[test]
    fn floor_log2_pow10_is_exact_over_its_range() {
        for e in -54..=54 {
            let n = floor_log2_pow10(e);
            assert!(pow10_at_least_pow2(e, n), "e={e}");
            assert!(!pow10_at_least_pow2(e, n + 1), "e={e}");
        }
    }

    #[test]
    fn floor_log10_of_powers_of_two_is_exact_over_its_range() {
        for q in -160i32..=160 {
            // No q·log10(2) (or that minus log10(4/3)) is within 1e-9 of
            // an integer except q·log10(2) at q = 0, so f64 decides exactly.
            let exact = f64::from(q) * core::f64::consts::LOG10_2;
            let three_quarters = exact + 0.75f64.log10();
            assert!((exact - exact.round()).abs() > 1e-9 || q == 0);
            assert!((three_quarters - three_quarters.round()).abs() > 1e-9);
            assert_eq!(floor_log10_pow2(q), exact.floor() as i32, "q={q}");
            assert_eq!(
                floor_log10_three_quarters_pow2(q),
                three_quarters.floor() as i32,
                "q={q}"
            );
        }
    }

    #[test]
    fn every_power_of_ten_is_approximated_from_above_within_one_unit() {
        for e in MIN_E..=MAX_E {
            let g = g(e).unwrap();
            assert!(g >> 63 == 1, "e={e}: {g:#x} is not normalised");
            // 10^e · 2^(63 − ⌊log2 10^e⌋) in (g − 1, g]: multiplied out so
            // that both sides are integers.
            let fl = floor_log2_pow10(e);
            let five = 5u128.pow(e.unsigned_abs());
            if e >= 0 {
                // 5^e · 2^(63 − fl + e): compare 5^e · 2^s with g.
                let s = 63 - fl + e;
                let (lo, hi) = if s >= 0 {
                    (u128::from(g - 1), u128::from(g))
                } else {
                    (u128::from(g - 1) << -s, u128::from(g) << -s)
                };
                let v = if s >= 0 { five << s } else { five };
                assert!(lo <= v && v < hi, "e={e}");
            } else {
                // 2^(63 − fl − m) / 5^m: compare 2^t with (g − 1)·5^m and g·5^m.
                let t = u32::try_from(63 - fl + e).unwrap();
                assert!(mul(g - 1, five) <= pow2(t) && pow2(t) < mul(g, five), "e={e}");
            }
        }
    }
}
