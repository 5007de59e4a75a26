//! The number module against the references, over millions of values.
//!
//! What "correct" means here:
//! - `parse_f32(text)` is `Some(x)` exactly when `str::parse::<f32>`
//!   accepts `text` and `text` is not one of its words (`nan`, `inf`,
//!   `infinity`, any case, signed), and then `x` has the same bits
//!   (correct rounding, ties to even, ±0, ±infinity beyond `f32::MAX`).
//! - `format_f32(v)` is byte for byte Ryu's text of `v` (the shortest
//!   decimal that reads back as `v`, the nearest to `v` among those, ties
//!   to even; Ryu's layout), at most `MAX_LEN` bytes, and reads back as
//!   exactly `v`.
//!
//! The floats: every sign and exponent (subnormals, infinities and NaNs
//! included), the lowest and highest mantissas of each exponent and a
//! stride through the rest. The texts: random decimals of 1 to 200 digits
//! with exponents up to ±250, the exact decimal of f32 midpoints (where
//! rounding changes) and texts just beside them, and random strings over
//! the grammar's alphabet. `numbers` in `fuzz/` runs the same comparisons
//! on arbitrary input; the whole 2^32 bit patterns were compared once
//! (BENCHMARKS.md).
//! - `Number::cmp_f32(bound)` orders the exact decimal a client sent
//!   against the decimal `bound` is written as, as written out plainly
//!   here with both as fixed-point digit strings.

use std::cmp::Ordering;

use lluav_core::number::{MAX_LEN, Number, format_f32, parse_f32};

/// Per exponent: the lowest and highest `EDGE` mantissas and every
/// `STRIDE`th one.
const EDGE: u32 = 1024;
const STRIDE: u32 = 1021;

fn swept_bits() -> impl Iterator<Item = u32> {
    (0..512u32).flat_map(|sign_exp| {
        let base = sign_exp << 23;
        let edges = (0..EDGE).chain((1 << 23) - EDGE..1 << 23);
        let middle = (EDGE..(1 << 23) - EDGE).step_by(STRIDE as usize);
        edges.chain(middle).map(move |m| base | m)
    })
}

#[test]
fn every_swept_float_is_written_as_ryu_writes_it() {
    let mut ryu = ryu::Buffer::new();
    let mut n = 0;
    for bits in swept_bits() {
        let v = f32::from_bits(bits);
        let ours = format_f32(v);
        let theirs = if v.is_finite() {
            ryu.format_finite(v)
        } else {
            ryu.format(v)
        };
        assert_eq!(ours.as_str(), theirs, "bits {bits:#010x}");
        assert!(ours.as_bytes().len() <= MAX_LEN);
        n += 1;
    }
    assert!(n > 5_000_000, "{n}");
}

#[test]
fn every_swept_float_reads_back_from_its_text() {
    for bits in swept_bits().filter(|b| b & 0x7F80_0000 != 0x7F80_0000) {
        let text = format_f32(f32::from_bits(bits));
        assert_eq!(
            parse_f32(text.as_str()).map(f32::to_bits),
            Some(bits),
            "{}",
            text.as_str()
        );
    }
}

/// SplitMix64: fast, and the same texts on every run.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    fn chance(&mut self, one_in: u64) -> bool {
        self.below(one_in) == 0
    }
}

/// A random decimal: 1–8, –20, –40 or –200 digits (zeros and nines more
/// often than others, to make long carries and exact values), a point
/// anywhere or none, leading zeros sometimes, an exponent sometimes.
fn random_decimal(rng: &mut Rng, s: &mut String) {
    s.clear();
    if rng.chance(3) {
        s.push('-');
    }
    let limit = [8, 20, 40, 200][rng.below(4) as usize];
    let digits = 1 + rng.below(limit) as usize;
    let point = rng.below(digits as u64 + 2) as usize;
    if rng.chance(4) {
        (0..rng.below(50)).for_each(|_| s.push('0'));
    }
    for i in 0..digits {
        if i == point {
            s.push('.');
        }
        let d = if rng.chance(5) {
            0
        } else if rng.chance(9) {
            9
        } else {
            rng.below(10) as u8
        };
        s.push(char::from(b'0' + d));
    }
    if point == digits && rng.chance(2) {
        s.push('.');
    }
    if rng.chance(2) {
        s.push(if rng.chance(2) { 'e' } else { 'E' });
        let span = [20, 120, 500][rng.below(3) as usize];
        let e = rng.below(span) as i64 - span as i64 / 2;
        if e >= 0 && rng.chance(3) {
            s.push('+');
        }
        s.push_str(&e.to_string());
    }
}

fn reads_as_core(text: &str) {
    let core: f32 = text.parse().unwrap_or_else(|e| panic!("{text:?}: {e}"));
    assert_eq!(
        parse_f32(text).map(f32::to_bits),
        Some(core.to_bits()),
        "{text:?}: core reads {core:?}"
    );
}

#[test]
fn random_decimal_texts_read_as_core_reads_them() {
    let mut rng = Rng(0x11_1a_0a_f1);
    let mut text = String::new();
    for _ in 0..2_000_000 {
        random_decimal(&mut rng, &mut text);
        reads_as_core(&text);
    }
}

/// The exact decimal text of c · 2^a · 5^b (a, b >= 0).
fn exact_digits(c: u64, a: u32, b: u32) -> String {
    const BASE: u64 = 1_000_000_000;
    let mut limbs = vec![c % BASE, c / BASE];
    let mut times = |m: u64| {
        let mut carry = 0;
        for l in limbs.iter_mut() {
            let t = *l * m + carry;
            *l = t % BASE;
            carry = t / BASE;
        }
        if carry > 0 {
            limbs.push(carry);
        }
    };
    (0..a).for_each(|_| times(2));
    (0..b).for_each(|_| times(5));
    while limbs.len() > 1 && limbs.last() == Some(&0) {
        limbs.pop();
    }
    let mut s = limbs.last().unwrap().to_string();
    for l in limbs.iter().rev().skip(1) {
        s.push_str(&format!("{l:09}"));
    }
    s
}

/// The exact text of the midpoint above the positive finite float `bits`
/// (where rounding changes), as (digits, exponent suffix).
fn midpoint_above(bits: u32) -> (String, String) {
    let (c, q) = if bits >> 23 == 0 {
        (u64::from(bits), -149)
    } else {
        (u64::from(bits & 0x7F_FFFF | 1 << 23), (bits >> 23) as i32 - 150)
    };
    // (2c + 1) · 2^(q - 1)
    let e = q - 1;
    if e >= 0 {
        (exact_digits(2 * c + 1, e as u32, 0), String::new())
    } else {
        (exact_digits(2 * c + 1, 0, (-e) as u32), format!("e{e}"))
    }
}

/// The midpoint itself (a tie), a hair above it and a hair below it.
fn at_and_beside_midpoint(bits: u32) -> [String; 3] {
    let (digits, exp) = midpoint_above(bits);
    let above = format!("{digits}.000000000000000000000000000001{exp}");
    let mut lower = digits.clone().into_bytes();
    for d in lower.iter_mut().rev() {
        if *d == b'0' {
            *d = b'9';
        } else {
            *d -= 1;
            break;
        }
    }
    let below = format!(
        "{}.99999999999999999999999{exp}",
        String::from_utf8(lower).unwrap()
    );
    [format!("{digits}{exp}"), above, below]
}

#[test]
fn texts_at_and_beside_midpoints_read_as_core_reads_them() {
    let special = [
        0,           // 2^-150: ties to zero
        1,           // between the two smallest subnormals
        0x007F_FFFF, // between the largest subnormal and the smallest normal
        0x0080_0000,
        0x3F7F_FFFF, // just below 1
        0x4B7F_FFFF, // 2^24 - 1 and 2^24
        0x4B80_0000,
        0x7F7F_FFFE,
        0x7F7F_FFFF, // f32::MAX and the overflow threshold: ties to infinity
    ];
    let sampled = (0..0x7F80_0000u32).step_by(8191);
    let mut n = 0;
    for bits in special.into_iter().chain(sampled) {
        for text in at_and_beside_midpoint(bits) {
            reads_as_core(&text);
            reads_as_core(&format!("-{text}"));
            n += 2;
        }
    }
    assert!(n > 1_500_000, "{n}");
}

/// A random string over the grammar's alphabet (and a few letters).
fn random_garble(rng: &mut Rng, s: &mut String) {
    const ALPHABET: &[u8] = b"0123456789..eE+-+-infatyINFATYx ";
    s.clear();
    for _ in 0..rng.below(8) {
        s.push(char::from(ALPHABET[rng.below(ALPHABET.len() as u64) as usize]));
    }
}

fn is_core_word(text: &str) -> bool {
    let word = text.strip_prefix(['+', '-']).unwrap_or(text);
    ["nan", "inf", "infinity"]
        .iter()
        .any(|w| word.eq_ignore_ascii_case(w))
}

/// The request grammar reads what `core` reads, less its words and a
/// leading `+` (DESIGN.md: one number grammar, `-?` only).
#[test]
fn the_parser_accepts_exactly_the_decimals_core_accepts_without_a_leading_plus() {
    let mut rng = Rng(7);
    let mut text = String::new();
    let mut accepted = 0;
    for _ in 0..1_000_000 {
        random_garble(&mut rng, &mut text);
        let core = text
            .parse::<f32>()
            .ok()
            .filter(|_| !is_core_word(&text) && !text.starts_with('+'));
        assert_eq!(
            parse_f32(&text).map(f32::to_bits),
            core.map(f32::to_bits),
            "{text:?}"
        );
        accepted += usize::from(core.is_some());
    }
    assert!(accepted > 10_000, "{accepted}");
}

#[test]
fn words_hex_and_malformed_numbers_are_refused() {
    for text in [
        "",
        ".",
        "-",
        "+",
        "e5",
        ".e5",
        "1e",
        "1e+",
        "1e-",
        "--1",
        "+-1",
        "1..0",
        "1.0.",
        " 1",
        "1 ",
        "1,5",
        "0x10",
        "0x1p3",
        "nan",
        "NaN",
        "-nan",
        "inf",
        "-inf",
        "+Infinity",
        "+1",
        "+0",
        "+.5",
        "1 5",
        "- 1",
        "1_000",
        "١",
    ] {
        assert_eq!(parse_f32(text), None, "{text:?}");
    }
}

#[test]
fn edge_values_read_exactly() {
    let cases: [(&str, f32); 14] = [
        ("0", 0.0),
        ("-0", -0.0),
        ("-0.0e-999999999999999999999", -0.0),
        ("1.", 1.0),
        (".5", 0.5),
        ("1e39", f32::INFINITY),
        ("-1e39", f32::NEG_INFINITY),
        ("340282356779733661637539395458142568448", f32::INFINITY),
        ("340282356779733661637539395458142568447", f32::MAX),
        ("1e-46", 0.0),
        ("7.006492321624085e-46", 0.0),
        ("7.006492321624086e-46", f32::from_bits(1)),
        ("1e99999999999999999999999", f32::INFINITY),
        (
            "0.000000000000000000000000000000000000011754943508222875",
            f32::MIN_POSITIVE,
        ),
    ];
    for (text, want) in cases {
        assert_eq!(
            parse_f32(text).map(f32::to_bits),
            Some(want.to_bits()),
            "{text:?}"
        );
    }
}

#[test]
fn values_read_back_as_clients_sent_them() {
    for (v, text) in [
        (0.1f32, "0.1"),
        (1.5, "1.5"),
        (-2.25, "-2.25"),
        (-10.0, "-10.0"),
        (87.5, "87.5"),
        (0.0, "0.0"),
        (-0.0, "-0.0"),
        (1e30, "1e30"),
        (1.2e-7, "1.2e-7"),
        (123456.79, "123456.79"),
        (f32::MAX, "3.4028235e38"),
        (f32::from_bits(1), "1e-45"),
        (f32::NAN, "NaN"),
        (f32::NEG_INFINITY, "-inf"),
    ] {
        assert_eq!(format_f32(v).as_str(), text);
    }
}

/// `text` (a decimal of at most 60 integer and 60 fraction digits) as its
/// sign and 120 digits of fixed point, for comparing exactly by strings.
fn fixed_point(text: &str) -> (bool, String) {
    let (negative, body) = match text.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, text),
    };
    let (mantissa, exp) = match body.split_once(['e', 'E']) {
        Some((m, e)) => (m, e.parse::<i64>().unwrap()),
        None => (body, 0),
    };
    let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let digits = format!("{int}{frac}");
    // The digit at index i has the value 10^(point - 1 - i).
    let point = int.len() as i64 + exp;
    let mut fixed = vec![b'0'; 120];
    for (i, d) in digits.bytes().enumerate() {
        let at = 60 - point + i as i64;
        assert!((0..120).contains(&at), "{text} does not fit");
        fixed[at as usize] = d;
    }
    let fixed = String::from_utf8(fixed).unwrap();
    let zero = fixed.bytes().all(|d| d == b'0');
    (negative && !zero, fixed)
}

fn exact_order(a: &str, b: &str) -> Ordering {
    let ((na, a), (nb, b)) = (fixed_point(a), fixed_point(b));
    match (na, nb) {
        (false, false) => a.cmp(&b),
        (true, true) => b.cmp(&a),
        (true, false) => Ordering::Less,
        (false, true) => Ordering::Greater,
    }
}

/// A decimal of up to 25 digits with an exponent in -20..20, and bounds
/// around it: its own `f32` (so that only the digits beyond an `f32`'s
/// precision decide), the floats beside it, and a few round ones.
#[test]
fn numbers_as_sent_compare_with_bounds_exactly() {
    let mut rng = Rng(11);
    let mut compared = [0usize; 3];
    for _ in 0..200_000 {
        let mut text = String::new();
        if rng.chance(3) {
            text.push('-');
        }
        let digits = 1 + rng.below(25) as usize;
        let point = rng.below(digits as u64 + 1) as usize;
        for i in 0..digits {
            if i == point {
                text.push('.');
            }
            let d = if rng.chance(4) { 0 } else { rng.below(10) as u8 };
            text.push(char::from(b'0' + d));
        }
        if rng.chance(2) {
            text.push_str(&format!("e{}", rng.below(40) as i64 - 20));
        }
        let Some(n) = Number::parse(&text) else {
            assert!(
                parse_f32(&text).is_some_and(f32::is_infinite),
                "{text} is in the grammar"
            );
            continue;
        };
        let v = n.value();
        let beside = |up: bool| {
            f32::from_bits(if (v > 0.0) == up {
                v.to_bits() + 1
            } else {
                v.to_bits().saturating_sub(1)
            })
        };
        for bound in [v, beside(true), beside(false), 0.0, -0.0, 90.0, -90.0, 0.1, 60.0] {
            if !(bound == 0.0 || (1e-15..=1e15).contains(&bound.abs())) {
                continue;
            }
            // As core writes it (Ryu's digits: at a tie between two
            // shortest texts, the even one).
            let written = format_f32(bound).as_str().to_owned();
            let want = exact_order(&text, &written);
            assert_eq!(n.cmp_f32(bound), Some(want), "{text} against {written}");
            compared[(want as i8 + 1) as usize] += 1;
        }
    }
    assert!(compared.iter().all(|&c| c > 1000), "{compared:?}");
}

#[test]
fn a_bound_is_the_decimal_it_is_written_as() {
    let n = |t: &'static str| Number::parse(t).unwrap();
    // 0.1f32 is 0.100000001490116…, but the bound is the 0.1 it stands for.
    assert_eq!(n("0.1").cmp_f32(0.1), Some(Ordering::Equal));
    assert!(n("0.1000000001").above(0.1));
    assert!(n("90.000001").above(90.0) && n("90.000001").value() == 90.0);
    assert!(!n("90.0000000000").above(90.0));
    assert!(n("-1e-50").below(0.0) && n("-1e-50").value() == 0.0);
    assert!(!n("-0").below(0.0));
    assert_eq!(n("1").cmp_f32(f32::NAN), None);
    assert!(Number::from(0.5).below(0.75) && !Number::from(0.5).above(0.5));
}

#[test]
fn numbers_are_equal_when_their_values_as_sent_are() {
    let n = |t: &'static str| Number::parse(t).unwrap();
    assert_eq!(n("1.50"), n("1.5"));
    assert_eq!(n("15e-1"), Number::from(1.5));
    assert_eq!(Number::from(0.1), n("0.1"));
    assert_ne!(n("90.000001"), n("90"));
    assert_eq!(n("-0"), n("0"));
}

#[test]
fn numbers_in_reasons_are_short() {
    let show = |n: Number<'_>| n.to_string();
    assert_eq!(show(Number::parse("1e38").unwrap()), "1e38");
    assert_eq!(show(Number::from(1e38)), "1e38");
    assert_eq!(show(Number::from(20_000.0)), "20000");
    assert_eq!(show(Number::from(0.1)), "0.1");
    assert_eq!(show(Number::from(-0.0)), "0");
    assert_eq!(show(Number::parse("-0.00").unwrap()), "0");
    assert_eq!(show(Number::parse("60.000001").unwrap()), "60.000001");
    let long = format!("1{}", "0".repeat(38));
    assert_eq!(show(Number::parse(&long).unwrap()), "1e38");
    assert!(Number::parse("+1").is_none() && Number::parse("1e39").is_none());
}
