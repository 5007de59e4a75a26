//! How each core [`Grammar`] looks in Python: its parameters (names, types,
//! which are optional), how Python values become core [`Args`], and how
//! parsed [`Args`] become Python values again.
//!
//! This is the one place that maps grammars to Python: [`params`] here,
//! [`convert`] (Python -> owned values), [`args`] (owned values -> core
//! [`Args`] and back to Python). Every match on [`Grammar`] is exhaustive,
//! so a grammar added to the core does not build until it is given a
//! Python shape.
//!
//! [`Args`]: lluav_core::Args

pub mod args;
pub mod convert;

use std::sync::LazyLock;

use lluav_core::{Grammar, Spec, TABLE};

/// What kind of Python value a parameter takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// A finite number (int or float), sent as an `f32`.
    Float,
    /// A non-negative integer.
    Int,
    /// `True`/`False` (or the integers 0 and 1).
    Flag,
    /// Text.
    Str,
    /// A parameter value (str, int, float or bool), sent as text.
    Value,
    /// A non-empty sequence of numbers.
    Floats,
    /// A non-empty sequence of non-negative integers.
    Ints,
    /// A landing point `(x, y, yaw)`.
    LandPoint,
    /// A dict or list (sent as JSON) or a str (a path on the vehicle).
    Payload,
}

impl Kind {
    /// The type annotation, as written in the stub and in `__signature__`.
    pub fn annotation(self) -> &'static str {
        match self {
            Kind::Float => "float",
            Kind::Int => "int",
            Kind::Flag => "bool",
            Kind::Str => "str",
            Kind::Value => "str | int | float | bool",
            Kind::Floats => "Sequence[float]",
            Kind::Ints => "Sequence[int]",
            Kind::LandPoint => "tuple[float, float, float]",
            Kind::Payload => "dict[str, Any] | list[Any] | str",
        }
    }
}

/// One Python parameter of a grammar.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Param {
    /// Its name. A grammar with one parameter takes the name from the
    /// command's usage line when that is an identifier (see [`params`]).
    pub name: &'static str,
    /// Its type.
    pub kind: Kind,
    /// Whether it may be left out (it then defaults to `None`).
    pub optional: bool,
}

fn req(name: &'static str, kind: Kind) -> Param {
    Param {
        name,
        kind,
        optional: false,
    }
}

fn opt(name: &'static str, kind: Kind) -> Param {
    Param {
        name,
        kind,
        optional: true,
    }
}

/// Most parameters any grammar has.
pub const MAX_PARAMS: usize = 4;

/// The parameters of a grammar, with their default names.
fn grammar_params(grammar: Grammar) -> Vec<Param> {
    use Kind::*;
    match grammar {
        Grammar::None => vec![],
        Grammar::Flag => vec![req("on", Flag)],
        Grammar::OptCount => vec![opt("count", Int)],
        Grammar::Pwm => vec![req("pwm", Int)],
        Grammar::Amount => vec![req("value", Float)],
        Grammar::OptAmount => vec![opt("value", Float)],
        Grammar::Angle => vec![req("angle", Float)],
        Grammar::Name => vec![req("name", Str)],
        Grammar::OptName => vec![opt("name", Str)],
        Grammar::Path => vec![req("path", Str)],
        Grammar::Text => vec![req("text", Str)],
        Grammar::TaskName => vec![req("name", Str)],
        Grammar::Secret => vec![req("password", Str)],
        Grammar::NewPassword => vec![req("new_password", Str)],
        Grammar::ParamName => vec![req("name", Str)],
        Grammar::SetParam => vec![req("name", Str), req("value", Value)],
        Grammar::Setpoint | Grammar::Pose => vec![
            req("x", Float),
            req("y", Float),
            req("z", Float),
            req("yaw", Float),
        ],
        Grammar::Point => vec![req("x", Float), req("y", Float), req("z", Float)],
        Grammar::Zyhk => vec![req("heights", Floats), opt("land", LandPoint)],
        Grammar::Mission => vec![req("ext_id", Int), req("payload", Payload)],
        Grammar::MwExec => vec![req("ext_id", Int), req("wp_ids", Ints)],
        Grammar::Ai1Mission => vec![req("task_id", Str), req("mission_file", Str)],
        Grammar::Override => vec![opt("failsafe", Flag)],
    }
}

/// Python keywords, which cannot name a parameter.
const KEYWORDS: &[&str] = &[
    "False", "None", "True", "and", "as", "assert", "async", "await", "break", "class", "continue", "def",
    "del", "elif", "else", "except", "finally", "for", "from", "global", "if", "import", "in", "is",
    "lambda", "nonlocal", "not", "or", "pass", "raise", "return", "try", "while", "with", "yield",
];

/// The argument word of a one-argument usage line (`showmsg [count]` ->
/// `count`, `login <password>` -> `password`), if it is a Python identifier.
fn usage_word(usage: &'static str) -> Option<&'static str> {
    let (_, arg) = usage.split_once(' ')?;
    let word = arg.trim_matches(['[', ']', '<', '>']);
    let identifier = word
        .bytes()
        .next()
        .is_some_and(|b| b.is_ascii_lowercase() || b == b'_')
        && word
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
    (identifier && !KEYWORDS.contains(&word)).then_some(word)
}

/// The Python parameters of a command: its grammar's, with a single
/// parameter named after the usage line (`dump_missionresult [ext_id]`
/// takes `ext_id`, `apron_vol voltage` takes `voltage`).
pub fn params(spec: &Spec) -> &'static [Param] {
    static PARAMS: LazyLock<Vec<Vec<Param>>> = LazyLock::new(|| TABLE.iter().map(named_params).collect());
    PARAMS
        .get(usize::from(u8::from(spec.id)).saturating_sub(1))
        .map_or(&[], Vec::as_slice)
}

fn named_params(spec: &Spec) -> Vec<Param> {
    let mut params = grammar_params(spec.grammar);
    if let [only] = params.as_mut_slice()
        && let Some(word) = usage_word(spec.usage)
    {
        only.name = word;
    }
    params
}

/// Why a grammar's values may encode to a frame that parses differently.
pub fn misread_hint(grammar: Grammar) -> &'static str {
    match grammar {
        Grammar::Mission => " (a str payload is a path on the vehicle; pass a dict or list to send JSON)",
        _ => "",
    }
}
