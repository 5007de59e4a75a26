//! Field-level grammar: numbers, flags, and separated field lists, written
//! with nom. Each function takes one argument string and either returns a
//! typed value or a typed [`ArgError`]; none of them panics.
//!
//! nom runs on the bytes (every byte the grammar looks for is ASCII, so a
//! field cut there is whole characters): no UTF-8 decoding per character.
//! The digits nom recognises are turned into values by [`crate::number`].

use heapless::Vec;
use nom::bytes::complete::take_till;
use nom::character::complete::{char, digit0, digit1, satisfy};
use nom::combinator::{all_consuming, opt, rest};
use nom::error::ErrorKind;
use nom::sequence::{preceded, separated_pair};
use nom::{IResult, Offset, Parser};

use crate::error::ArgError;
use crate::number::parse_f32;

type NomError<'a> = nom::error::Error<&'a [u8]>;

/// `[+-]? (digits ('.' digits?)? | '.' digits) ([eE] [+-]? digits)?`:
/// decimal notation only, so `nan`, `inf` and hex never get through. nom's
/// parsers in sequence rather than nested `alt`s, which would try the
/// digits twice and build an error for every branch not taken.
fn decimal(i: &[u8]) -> IResult<&[u8], &[u8]> {
    let sign = || opt(satisfy(|c| c == '+' || c == '-'));
    let start = i;
    let (i, _) = sign().parse(i)?;
    let (i, int) = digit0(i)?;
    let (i, frac) = opt(preceded(char('.'), digit0)).parse(i)?;
    if int.is_empty() && frac.is_none_or(<[u8]>::is_empty) {
        return Err(nom::Err::Error(NomError::new(i, ErrorKind::Digit)));
    }
    let (i, _) = opt((satisfy(|c| c == 'e' || c == 'E'), sign(), digit1)).parse(i)?;
    Ok((i, start.get(..start.offset(i)).unwrap_or_default()))
}

/// A finite decimal number that fits an `f32`, correctly rounded.
pub(crate) fn float(token: &str) -> Result<f32, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    if all_consuming(decimal).parse(token.as_bytes()).is_err() {
        let bytes = token.as_bytes();
        let signs = bytes.iter().take_while(|&&b| b == b'+' || b == b'-').count();
        let word = bytes.get(signs..).unwrap_or_default();
        let non_finite = [&b"nan"[..], b"inf", b"infinity"]
            .iter()
            .any(|w| word.eq_ignore_ascii_case(w));
        return Err(if non_finite {
            ArgError::NotFinite
        } else {
            ArgError::NotANumber
        });
    }
    // The syntax is checked above, so only overflow to infinity remains.
    parse_f32(token)
        .ok_or(ArgError::NotANumber)
        .and_then(super::rules::finite)
}

/// An unsigned decimal integer that fits a `u32`.
pub(crate) fn uint(token: &str) -> Result<u32, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    let (_, digits) = all_consuming(digit1::<&[u8], NomError>)
        .parse(token.as_bytes())
        .map_err(|_| ArgError::NotANumber)?;
    digits
        .iter()
        .try_fold(0u32, |v, &d| {
            v.checked_mul(10)?.checked_add(u32::from(d.wrapping_sub(b'0')))
        })
        .ok_or(ArgError::OutOfRange)
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

/// Calls `each` with every field of `input` between the `sep`s (ASCII), in
/// order, as `str::split` cuts them: one empty field for an empty input,
/// one after a trailing `sep`. nom's `take_till` and `char` in a loop (a
/// `fold_many0` costs several times more per field).
fn fields<'a>(input: &'a str, sep: char, each: &mut dyn FnMut(&'a str)) -> Result<(), ArgError> {
    let bytes = input.as_bytes();
    let sep_byte = u8::try_from(sep).map_err(|_| ArgError::Malformed)?;
    let mut rest = bytes;
    loop {
        let (after, field) = take_till::<_, &[u8], NomError>(|b| b == sep_byte)
            .parse(rest)
            .map_err(|_| ArgError::Malformed)?;
        // The field as text: a cut at an ASCII byte is at a character
        // boundary.
        let at = bytes.offset(field);
        each(input.get(at..at + field.len()).unwrap_or_default());
        match char::<_, NomError>(sep).parse(after) {
            Ok((next, _)) => rest = next,
            Err(_) => return Ok(()),
        }
    }
}

/// Splits `input` at every `sep` and converts each field with `item`,
/// keeping at most `N`. More than `N` fields is [`ArgError::TooMany`]; the
/// first field that fails to convert decides the error.
pub(crate) fn list<T, const N: usize>(
    input: &str,
    sep: char,
    item: impl Fn(&str) -> Result<T, ArgError>,
) -> Result<Vec<T, N>, ArgError> {
    // Filled in place: a fixed-capacity vector folded by value would be
    // copied whole once per field.
    let mut items = Vec::new();
    let mut outcome = Ok(());
    fields(input, sep, &mut |token| {
        if outcome.is_ok() {
            outcome = item(token).and_then(|v| items.push(v).map_err(|_| ArgError::TooMany));
        }
    })?;
    outcome?;
    Ok(items)
}

/// Exactly `N` numbers separated by `sep`.
pub(crate) fn numbers<const N: usize>(input: &str, sep: char) -> Result<[f32; N], ArgError> {
    let mut values = [0.0; N];
    fill(input, sep, &mut values)?;
    Ok(values)
}

/// Exactly `values.len()` numbers separated by `sep`, into `values` (one
/// copy of the code for every count); the first field that fails decides
/// the error, too many or too few is malformed.
fn fill(input: &str, sep: char, values: &mut [f32]) -> Result<(), ArgError> {
    let mut slots = values.iter_mut();
    let mut failure = None;
    fields(input, sep, &mut |token| {
        if failure.is_none() {
            let slot = slots.next();
            match (float(token), slot) {
                (Ok(v), Some(slot)) => *slot = v,
                (Ok(_), None) => failure = Some(ArgError::Malformed),
                (Err(e), _) => failure = Some(e),
            }
        }
    })?;
    match (failure, slots.next()) {
        (Some(e), _) => Err(e),
        (None, Some(_)) => Err(ArgError::Malformed),
        (None, None) => Ok(()),
    }
}

/// Splits at the first `sep` (ASCII): `(head, tail)`; no `sep` is
/// malformed.
pub(crate) fn split_first(input: &str, sep: char) -> Result<(&str, &str), ArgError> {
    let bytes = input.as_bytes();
    let sep_byte = u8::try_from(sep).map_err(|_| ArgError::Malformed)?;
    let (_, (head, tail)) = separated_pair(
        take_till::<_, &[u8], NomError>(|b| b == sep_byte),
        char(sep),
        rest,
    )
    .parse(bytes)
    .map_err(|_| ArgError::Malformed)?;
    // Cut at an ASCII byte: both sides are whole characters.
    let text = |part: &[u8]| {
        let at = bytes.offset(part);
        input.get(at..at + part.len())
    };
    text(head).zip(text(tail)).ok_or(ArgError::Malformed)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every string of up to six bytes over the characters a decimal is
    /// made of (and two that it is not): nom's grammar accepts exactly
    /// what the number module's own scanner accepts, with the same value.
    #[test]
    fn the_nom_grammar_and_the_number_scanner_accept_the_same_decimals() {
        let alphabet = *b"0159.eE+-x";
        let mut text = [0u8; 6];
        for len in 1..=6u32 {
            for n in 0..alphabet.len().pow(len) {
                let mut k = n;
                for slot in text.iter_mut().take(len as usize) {
                    *slot = alphabet.get(k % alphabet.len()).copied().unwrap_or_default();
                    k /= alphabet.len();
                }
                let bytes = text.get(..len as usize).unwrap_or_default();
                let token = core::str::from_utf8(bytes).unwrap_or_default();
                let nom = all_consuming(decimal).parse(bytes).is_ok();
                let ours = parse_f32(token);
                assert_eq!(nom, ours.is_some(), "{token:?}");
                if let (Ok(v), Some(w)) = (float(token), ours) {
                    assert_eq!(v.to_bits(), w.to_bits(), "{token:?}");
                }
            }
        }
    }
}
