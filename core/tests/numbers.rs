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

use lluav_core::number::{MAX_LEN, format_f32, parse_f32};

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
    match rng.below(4) {
        0 => s.push('-'),
        1 => s.push('+'),
        _ => {}
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

#[test]
fn the_parser_accepts_exactly_the_decimals_core_accepts() {
    let mut rng = Rng(7);
    let mut text = String::new();
    let mut accepted = 0;
    for _ in 0..1_000_000 {
        random_garble(&mut rng, &mut text);
        let core = text.parse::<f32>().ok().filter(|_| !is_core_word(&text));
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
