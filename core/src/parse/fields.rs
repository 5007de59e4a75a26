//! Field-level grammar: numbers, flags, and separated field lists, built
//! with nom. Each function takes one argument string and either returns a
//! typed value or a typed [`ArgError`]; none of them panics.

use heapless::Vec;
use nom::branch::alt;
use nom::bytes::complete::take_till;
use nom::character::complete::{char, digit0, digit1, one_of};
use nom::combinator::{all_consuming, opt, recognize, rest};
use nom::multi::fold_many0;
use nom::sequence::{preceded, separated_pair};
use nom::{IResult, Parser};

use crate::error::ArgError;

type NomError<'a> = nom::error::Error<&'a str>;

/// `[+-]? (digits ('.' digits?)? | '.' digits) ([eE] [+-]? digits)?`:
/// decimal notation only, so `nan`, `inf` and hex never get through.
fn decimal(i: &str) -> IResult<&str, &str> {
    recognize((
        opt(one_of("+-")),
        alt((
            recognize((digit1, opt((char('.'), digit0)))),
            recognize((char('.'), digit1)),
        )),
        opt((one_of("eE"), opt(one_of("+-")), digit1)),
    ))
    .parse(i)
}

/// A finite decimal number that fits an `f32`.
pub(crate) fn float(token: &str) -> Result<f32, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    if all_consuming(decimal).parse(token).is_err() {
        let word = token.trim_start_matches(['+', '-']);
        let non_finite = ["nan", "inf", "infinity"]
            .iter()
            .any(|w| word.eq_ignore_ascii_case(w));
        return Err(if non_finite {
            ArgError::NotFinite
        } else {
            ArgError::NotANumber
        });
    }
    // The syntax is checked above, so only overflow to infinity remains.
    token
        .parse::<f32>()
        .map_err(|_| ArgError::NotANumber)
        .and_then(super::rules::finite)
}

/// An unsigned decimal integer that fits a `u32`.
pub(crate) fn uint(token: &str) -> Result<u32, ArgError> {
    if token.is_empty() {
        return Err(ArgError::Missing);
    }
    all_consuming(digit1::<_, NomError>)
        .parse(token)
        .map_err(|_| ArgError::NotANumber)?;
    token.parse::<u32>().map_err(|_| ArgError::OutOfRange)
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
    sep: char,
    item: impl Fn(&str) -> Result<T, ArgError>,
) -> Result<Vec<T, N>, ArgError> {
    // The list is filled in place: folding it through nom by value would
    // copy the whole fixed-capacity vector once per field.
    let mut items = Vec::new();
    let mut failure = None;
    let mut push = |token: &str| {
        if failure.is_none()
            && let Err(e) = item(token).and_then(|v| items.push(v).map_err(|_| ArgError::TooMany))
        {
            failure = Some(e);
        }
    };
    let field = || take_till::<_, _, NomError>(move |c| c == sep);
    let (rest_input, first_token) = field().parse(input).map_err(|_| ArgError::Malformed)?;
    push(first_token);
    all_consuming(fold_many0(
        preceded(char(sep), field()),
        || (),
        |(), token| push(token),
    ))
    .parse(rest_input)
    .map_err(|_| ArgError::Malformed)?;
    match failure {
        Some(e) => Err(e),
        None => Ok(items),
    }
}

/// Exactly `N` numbers separated by `sep`.
pub(crate) fn numbers<const N: usize>(input: &str, sep: char) -> Result<[f32; N], ArgError> {
    let v = list::<f32, N>(input, sep, float).map_err(|e| match e {
        ArgError::TooMany => ArgError::Malformed,
        other => other,
    })?;
    v.into_array().map_err(|_| ArgError::Malformed)
}

/// Splits at the first `sep`: `(head, tail)`; no `sep` is malformed.
pub(crate) fn split_first(input: &str, sep: char) -> Result<(&str, &str), ArgError> {
    separated_pair(take_till::<_, _, NomError>(|c| c == sep), char(sep), rest)
        .parse(input)
        .map(|(_, pair)| pair)
        .map_err(|_| ArgError::Malformed)
}
