//! Field-level grammar: numbers, flags, and separated field lists. Each
//! function takes one argument string and either returns a typed value or
//! a typed [`ArgError`]; none of them panics.

use heapless::Vec;

use crate::error::ArgError;
use crate::number::parse_f32;

use super::scan::{cut, split};

/// A finite decimal number that fits an `f32`, correctly rounded:
/// `[+-]? (digits ('.' digits?)? | '.' digits) ([eE] [+-]? digits)?`, so
/// `nan`, `inf` and hex never get through.
pub(crate) fn float(token: &str) -> Result<f32, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    match parse_f32(token) {
        // Overflow to infinity is the only way to a non-finite value.
        Some(v) => super::rules::finite(v),
        None => {
            let bytes = token.as_bytes();
            let signs = bytes.iter().take_while(|&&b| b == b'+' || b == b'-').count();
            let word = bytes.get(signs..).unwrap_or_default();
            let non_finite = [&b"nan"[..], b"inf", b"infinity"]
                .iter()
                .any(|w| word.eq_ignore_ascii_case(w));
            Err(if non_finite {
                ArgError::NotFinite
            } else {
                ArgError::NotANumber
            })
        }
    }
}

/// An unsigned decimal integer that fits a `u32`.
pub(crate) fn uint(token: &str) -> Result<u32, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    let mut value: u32 = 0;
    let mut overflow = false;
    for b in token.bytes() {
        let digit = b.wrapping_sub(b'0');
        if digit > 9 {
            return Err(ArgError::NotANumber);
        }
        match value
            .checked_mul(10)
            .and_then(|v| v.checked_add(u32::from(digit)))
        {
            Some(v) => value = v,
            None => overflow = true,
        }
    }
    if overflow {
        Err(ArgError::OutOfRange)
    } else {
        Ok(value)
    }
}

/// An integer PWM value, 0–65535.
pub(crate) fn pwm(token: &str) -> Result<u16, ArgError> {
    u16::try_from(uint(token)?).map_err(|_| ArgError::OutOfRange)
}

/// Exactly `0` or `1`.
pub(crate) fn flag(token: &str) -> Result<bool, ArgError> {
    match token {
        "0" => Ok(false),
        "1" => Ok(true),
        "" => Err(ArgError::Missing),
        _ => Err(ArgError::NotAFlag),
    }
}

/// Splits `input` at every `sep` and converts each field with `item`,
/// keeping at most `N`. More than `N` fields is [`ArgError::TooMany`]; the
/// first field that fails to convert decides the error.
pub(crate) fn list<T, const N: usize>(
    input: &str,
    sep: u8,
    item: impl Fn(&str) -> Result<T, ArgError>,
) -> Result<Vec<T, N>, ArgError> {
    // Filled in place: a fixed-capacity vector moved per field would be
    // copied whole each time.
    let mut items = Vec::new();
    for token in split(input, sep) {
        items.push(item(token)?).map_err(|_| ArgError::TooMany)?;
    }
    Ok(items)
}

/// `list(input, sep, uint)` in one pass over the bytes, without cutting
/// the fields out first: the same values and the same first error.
pub(crate) fn uints<const N: usize>(input: &str, sep: u8) -> Result<Vec<u32, N>, ArgError> {
    let mut items = Vec::new();
    let mut rest = input.as_bytes();
    loop {
        // One field: its digits up to the separator or the end.
        let mut value: u32 = 0;
        let mut digits = 0;
        let mut overflow = false;
        let mut more = false;
        while let Some((&b, tail)) = rest.split_first() {
            rest = tail;
            if b == sep {
                more = true;
                break;
            }
            let digit = b.wrapping_sub(b'0');
            if digit > 9 {
                return Err(ArgError::NotANumber);
            }
            let (times_ten, o1) = value.overflowing_mul(10);
            let (next, o2) = times_ten.overflowing_add(u32::from(digit));
            overflow |= o1 | o2;
            value = next;
            digits += 1;
        }
        if digits == 0 {
            return Err(ArgError::Missing);
        }
        if overflow {
            return Err(ArgError::OutOfRange);
        }
        items.push(value).map_err(|_| ArgError::TooMany)?;
        if !more {
            return Ok(items);
        }
    }
}

/// Exactly `N` numbers separated by `sep`.
pub(crate) fn numbers<const N: usize>(input: &str, sep: u8) -> Result<[f32; N], ArgError> {
    let mut values = [0.0; N];
    fill(input, sep, &mut values)?;
    Ok(values)
}

/// Exactly `values.len()` numbers separated by `sep`, into `values` (one
/// copy of the code for every count).
fn fill(input: &str, sep: u8, values: &mut [f32]) -> Result<(), ArgError> {
    let mut slots = values.iter_mut();
    for token in split(input, sep) {
        let v = float(token)?;
        *slots.next().ok_or(ArgError::Malformed)? = v;
    }
    match slots.next() {
        None => Ok(()),
        Some(_) => Err(ArgError::Malformed),
    }
}

/// Splits at the first `sep`: `(head, tail)`; no `sep` is malformed.
pub(crate) fn split_first(input: &str, sep: u8) -> Result<(&str, &str), ArgError> {
    match cut(input, sep) {
        (head, Some(tail)) => Ok((head, tail)),
        (_, None) => Err(ArgError::Malformed),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every string of up to five bytes over digits, the separator and one
    /// other byte, and long runs of digits around u32::MAX.
    #[test]
    fn one_pass_integer_lists_read_as_field_by_field_ones() {
        let alphabet = [b'0', b'1', b'9', b',', b'x'];
        let mut inputs = [0u8; 5];
        for len in 0..=5 {
            for n in 0..alphabet.len().pow(len) {
                let mut k = n;
                for slot in inputs.iter_mut().take(len as usize) {
                    *slot = alphabet.get(k % alphabet.len()).copied().unwrap_or_default();
                    k /= alphabet.len();
                }
                let text =
                    core::str::from_utf8(inputs.get(..len as usize).unwrap_or_default()).unwrap_or_default();
                assert_eq!(
                    uints::<3>(text, b','),
                    list::<u32, 3>(text, b',', uint),
                    "{text:?}"
                );
            }
        }
        for text in [
            "4294967295",
            "4294967296",
            "4294967296x",
            "1,99999999999,x",
            "0,0,0,0",
            "007,08",
        ] {
            assert_eq!(
                uints::<3>(text, b','),
                list::<u32, 3>(text, b',', uint),
                "{text:?}"
            );
        }
    }
}
