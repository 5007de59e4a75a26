//! Field-level grammar: numbers, flags, and separated field lists, written
//! with nom. Each function takes one argument string and either returns a
//! typed value or a typed [`ArgError`]; none of them panics.
//!
//! nom runs on the bytes (every byte the grammar looks for is ASCII, so a
//! field cut there is whole characters): no UTF-8 decoding per character.
//! Numbers are read, and their syntax checked, by [`crate::number`].

use heapless::Vec;
use nom::bytes::complete::take_till;
use nom::character::complete::{char, digit1};
use nom::combinator::{all_consuming, rest};
use nom::sequence::separated_pair;
use nom::{Offset, Parser};

use crate::error::{ArgError, Bound};
use crate::number::{Number, parse_f32};

type NomError<'a> = nom::error::Error<&'a [u8]>;

/// A finite decimal number that fits an `f32`, correctly rounded, with its
/// text: DESIGN.md's one number grammar, `-? (digits ('.' digits?)? | '.'
/// digits) ([eE] [+-]? digits)?` ([`crate::number::parse_f32`] checks it
/// as it reads), so a leading `+`, spaces, `nan`, `inf` and hex never get
/// through.
pub(crate) fn number(token: &str) -> Result<Number<'_>, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    // Not in the grammar (`nan` and `inf` are words, not numbers), or
    // beyond an f32.
    Number::parse(token).ok_or(match parse_f32(token) {
        Some(_) => ArgError::OutOfRange(Bound::Float),
        None => ArgError::NotANumber,
    })
}

/// [`number`]'s `f32`.
pub(crate) fn float(token: &str) -> Result<f32, ArgError> {
    number(token).map(|n| n.value())
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
        .ok_or(ArgError::OutOfRange(Bound::Integer))
}

/// An integer PWM value, 0–65535.
pub(crate) fn pwm(token: &str) -> Result<u16, ArgError> {
    let too_large = ArgError::OutOfRange(Bound::Pwm);
    match uint(token) {
        Ok(v) => u16::try_from(v).map_err(|_| too_large),
        Err(ArgError::OutOfRange(_)) => Err(too_large),
        Err(e) => Err(e),
    }
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
