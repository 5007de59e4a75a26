//! A number as a client sent it, compared with a range exactly.
//!
//! A client's `90.000001` rounds to the `f32` 90, so a range check on the
//! `f32` would let it through; DESIGN.md checks ranges on the decimal value
//! as sent. [`Number`] keeps the text beside the `f32` and compares the
//! text's exact value with a bound, taking the bound as the decimal it is
//! written as (its shortest form: `0.1f32` is the bound 0.1, not
//! 0.100000001490116…), digit by digit, without arithmetic.

use core::cmp::Ordering;
use core::fmt;

use super::format::format_f32;
use super::parse::{Decimal, parse_f32};

/// The longest text [`Number`]'s `Display` echoes as sent; a longer one is
/// written as its `f32`.
const ECHO_MAX: usize = 24;

/// A finite number: the `f32` the vehicle acts on and, when it came from a
/// client, the decimal text it was sent as.
#[derive(Clone, Copy, Debug)]
pub struct Number<'a> {
    text: Option<&'a str>,
    value: f32,
}

impl<'a> Number<'a> {
    /// Reads `text` in the request grammar (`-`, digits, an optional
    /// fraction and exponent: no `+`, no spaces, no `inf`/`NaN`); `None`
    /// for anything else, or a number too large for an `f32`.
    pub fn parse(text: &'a str) -> Option<Self> {
        let value = parse_f32(text).filter(|v| v.is_finite())?;
        Some(Number {
            text: Some(text),
            value,
        })
    }

    /// The nearest `f32`, which the vehicle acts on.
    pub fn value(&self) -> f32 {
        self.value
    }

    /// The text as sent (`None` for a number made from an `f32`).
    pub fn text(&self) -> Option<&'a str> {
        self.text
    }

    /// The exact value as sent, compared with `bound` as it is written
    /// (its shortest decimal form); `None` if `bound` is NaN.
    pub fn cmp_f32(&self, bound: f32) -> Option<Ordering> {
        match self.text {
            None => self.value.partial_cmp(&bound),
            Some(_) => self.cmp_decimal(format_f32(bound).as_str()),
        }
    }

    /// The exact value as sent, compared with the decimal `bound` (in the
    /// request grammar: `90`, `-0.5`, `2e4`); `None` if `bound` is not
    /// one. A number made from an `f32` compares as that `f32` with the
    /// `f32` nearest to `bound`.
    pub fn cmp_decimal(&self, bound: &str) -> Option<Ordering> {
        let exact = Exact::of(&Decimal::scan(bound.as_bytes())?);
        self.cmp_exact(&exact, parse_f32(bound)?)
    }

    /// [`Number::cmp_decimal`] with a bound read already: its exact value
    /// and its `f32`.
    pub(crate) fn cmp_exact(&self, bound: &Exact<'_>, bound_f32: f32) -> Option<Ordering> {
        match self.text {
            None => self.value.partial_cmp(&bound_f32),
            Some(text) => Some(compare(&Exact::of(&Decimal::scan(text.as_bytes())?), bound)),
        }
    }

    /// Whether the value as sent is above `max`.
    pub fn above(&self, max: f32) -> bool {
        self.cmp_f32(max) == Some(Ordering::Greater)
    }

    /// Whether the value as sent is below `min`.
    pub fn below(&self, min: f32) -> bool {
        self.cmp_f32(min) == Some(Ordering::Less)
    }
}

impl From<f32> for Number<'_> {
    /// A number that is exactly `value` (a finite one: a hand-built
    /// command with an infinity or NaN is refused when it is built).
    fn from(value: f32) -> Self {
        Number { text: None, value }
    }
}

impl PartialEq for Number<'_> {
    /// The same value as sent: `1.50` equals `1.5` and `Number::from(1.5)`;
    /// `90.000001` does not equal `90`, though both are the `f32` 90.
    fn eq(&self, other: &Self) -> bool {
        match (self.text, other.text) {
            (_, None) => self.cmp_f32(other.value) == Some(Ordering::Equal),
            (None, Some(_)) => other.cmp_f32(self.value) == Some(Ordering::Equal),
            (Some(_), Some(b)) => self.cmp_decimal(b) == Some(Ordering::Equal),
        }
    }
}

impl fmt::Display for Number<'_> {
    /// For reasons: the text as sent when it is short (`60.000001`,
    /// `1e38`), else the shortest form of its `f32` without a `.0`, `-0`
    /// written `0` (`1e38`, `20000`, `0.1`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let zero = self.cmp_exact(&Exact::ZERO, 0.0) == Some(Ordering::Equal);
        if let Some(text) = self.text.filter(|t| t.len() <= ECHO_MAX && !zero) {
            return f.write_str(text);
        }
        let shortest = format_f32(self.value + 0.0);
        let text = shortest.as_str();
        f.write_str(text.strip_suffix(".0").unwrap_or(text))
    }
}

/// A decimal's exact value, as far as ordering needs it.
pub(crate) struct Exact<'a> {
    /// -1, 0 or 1.
    sign: i8,
    /// Where the first significant digit stands: the value is 0.d… × 10^lead.
    lead: i64,
    /// The digits, with the point if any (leading zeros are skipped).
    mantissa: &'a [u8],
}

impl<'a> Exact<'a> {
    /// Zero.
    pub(crate) const ZERO: Exact<'static> = Exact::integer(0, 0, b"");
    /// 90.
    pub(crate) const NINETY: Exact<'static> = Exact::integer(1, 2, b"90");
    /// -90.
    pub(crate) const MINUS_NINETY: Exact<'static> = Exact::integer(-1, 2, b"90");

    const fn integer(sign: i8, lead: i64, digits: &'static [u8]) -> Exact<'static> {
        Exact {
            sign,
            lead,
            mantissa: digits,
        }
    }

    fn of(d: &Decimal<'a>) -> Self {
        Exact {
            sign: match (d.w == 0, d.negative) {
                (true, _) => 0,
                (false, true) => -1,
                (false, false) => 1,
            },
            lead: d.significant + d.exp10,
            mantissa: d.mantissa,
        }
    }
}

/// The exact order of two decimals: by sign, then by where their first
/// significant digit stands, then digit by digit (a missing digit is 0).
fn compare(a: &Exact<'_>, b: &Exact<'_>) -> Ordering {
    if a.sign != b.sign || a.sign == 0 {
        return a.sign.cmp(&b.sign);
    }
    let (mut x, mut y) = (Digits::of(a.mantissa), Digits::of(b.mantissa));
    let mut order = a.lead.cmp(&b.lead);
    while order == Ordering::Equal && !(x.0.is_empty() && y.0.is_empty()) {
        order = x.next().cmp(&y.next());
    }
    if a.sign < 0 { order.reverse() } else { order }
}

/// The significant digits of a decimal's mantissa, then zeros.
struct Digits<'a>(&'a [u8]);

impl<'a> Digits<'a> {
    fn of(mantissa: &'a [u8]) -> Self {
        let mut digits = Digits(mantissa);
        while let Some((b'0' | b'.', rest)) = digits.0.split_first() {
            digits.0 = rest;
        }
        digits
    }

    fn next(&mut self) -> u8 {
        if let Some((b'.', rest)) = self.0.split_first() {
            self.0 = rest;
        }
        match self.0.split_first() {
            Some((&d, rest)) => {
                self.0 = rest;
                d
            }
            None => b'0',
        }
    }
}
