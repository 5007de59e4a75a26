//! Every one of the 2^32 f32 bit patterns through the number module:
//! `format_f32` must write byte for byte Ryu's text, and `parse_f32` must
//! read that text (and `core`'s `{:?}` text) back as the same bits. With
//! `--midpoints N`, also the exact decimal of every Nth midpoint between
//! two adjacent floats, and texts a hair above and below it, against
//! `core`'s parser (ties to even, rounding at the ends of the range).
//!
//! ```text
//! cargo run --release -p lluav-core --example numbers_exhaustive [-- --midpoints 101]
//! ```
//!
//! A one-off proof, too long for `cargo test` (minutes on two cores);
//! `core/tests/numbers.rs` runs a sweep of every exponent on every test
//! run, and `fuzz/fuzz_targets/numbers.rs` the same comparisons on
//! arbitrary input.

use std::sync::atomic::{AtomicU64, Ordering};
use std::thread;

use lluav_core::number::{format_f32, parse_f32};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let midpoints = args.iter().position(|a| a == "--midpoints").map(|i| {
        args.get(i + 1)
            .and_then(|n| n.parse::<u64>().ok())
            .expect("--midpoints N")
    });
    let threads = thread::available_parallelism().map_or(1, |n| n.get()) as u64;
    let failures = AtomicU64::new(0);
    let span = (1u64 << 32) / threads;
    thread::scope(|s| {
        for t in 0..threads {
            let failures = &failures;
            s.spawn(move || {
                let mut ryu = ryu::Buffer::new();
                for b in t * span..(t + 1) * span {
                    let bits = b as u32;
                    let v = f32::from_bits(bits);
                    let ours = format_f32(v);
                    let theirs = if v.is_finite() {
                        ryu.format_finite(v)
                    } else {
                        ryu.format(v)
                    };
                    let mut ok = ours.as_str() == theirs;
                    if v.is_finite() {
                        ok &= parse_f32(theirs).map(f32::to_bits) == Some(bits);
                        ok &= parse_f32(&format!("{v:?}")).map(f32::to_bits) == Some(bits);
                    }
                    if !ok && failures.fetch_add(1, Ordering::Relaxed) < 20 {
                        eprintln!("{bits:#010x}: ours {:?}, Ryu {theirs:?}", ours.as_str());
                    }
                    if let Some(step) = midpoints
                        && b % step == 0
                        && bits < 0x7F80_0000
                    {
                        for text in around_midpoint(bits) {
                            let core: f32 = text.parse().expect("decimal");
                            if parse_f32(&text).map(f32::to_bits) != Some(core.to_bits())
                                && failures.fetch_add(1, Ordering::Relaxed) < 20
                            {
                                eprintln!("{text}: ours {:?}, core {core:?}", parse_f32(&text));
                            }
                        }
                    }
                }
            });
        }
    });
    let failures = failures.into_inner();
    println!("2^32 bit patterns, {threads} threads: {failures} failures");
    std::process::exit(i32::from(failures > 0));
}

/// The exact decimal of the midpoint above the positive finite float
/// `bits`, and texts a hair above and below it.
fn around_midpoint(bits: u32) -> [String; 3] {
    let (c, q) = if bits >> 23 == 0 {
        (u64::from(bits), -149)
    } else {
        (u64::from(bits & 0x7F_FFFF | 1 << 23), (bits >> 23) as i32 - 150)
    };
    // (2c + 1) · 2^(q - 1)
    let e = q - 1;
    let (digits, exp) = if e >= 0 {
        (times(2 * c + 1, 2, e as u32), String::new())
    } else {
        (times(2 * c + 1, 5, (-e) as u32), format!("e{e}"))
    };
    let mut lower = digits.clone().into_bytes();
    for d in lower.iter_mut().rev() {
        if *d == b'0' {
            *d = b'9';
        } else {
            *d -= 1;
            break;
        }
    }
    let lower = String::from_utf8(lower).expect("ASCII");
    [
        format!("{digits}{exp}"),
        format!("{digits}.000000000000000000000000001{exp}"),
        format!("{lower}.999999999999999999999999999{exp}"),
    ]
}

/// The decimal digits of c · m^k.
fn times(c: u64, m: u64, k: u32) -> String {
    const BASE: u64 = 1_000_000_000;
    let mut limbs = vec![c % BASE, c / BASE];
    for _ in 0..k {
        let mut carry = 0;
        for l in limbs.iter_mut() {
            let t = *l * m + carry;
            *l = t % BASE;
            carry = t / BASE;
        }
        if carry > 0 {
            limbs.push(carry);
        }
    }
    while limbs.len() > 1 && limbs.last() == Some(&0) {
        limbs.pop();
    }
    let mut s = limbs.last().expect("a limb").to_string();
    for l in limbs.iter().rev().skip(1) {
        s.push_str(&format!("{l:09}"));
    }
    s
}
