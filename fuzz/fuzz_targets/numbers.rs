//! The number module against the references: arbitrary bytes as decimal
//! text into `parse_f32` (the same f32 as `core`'s parser, accepted exactly
//! when `core` accepts it, it is not `nan`/`inf`/`infinity` and it has no
//! leading `+`: the request grammar's one number grammar), and their
//! first four bytes as an f32 into `format_f32` (byte for byte Ryu's text,
//! which reads back as the same bits). Never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lluav_core::number::{MAX_LEN, format_f32, parse_f32};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let word = text.strip_prefix(['+', '-']).unwrap_or(&text);
    let is_word = ["nan", "inf", "infinity"]
        .iter()
        .any(|w| word.eq_ignore_ascii_case(w));
    let core = text
        .parse::<f32>()
        .ok()
        .filter(|_| !is_word && !text.starts_with('+'));
    assert_eq!(
        parse_f32(&text).map(f32::to_bits),
        core.map(f32::to_bits),
        "{text:?}"
    );

    if let Some(&bits) = data.first_chunk::<4>() {
        let v = f32::from_bits(u32::from_le_bytes(bits));
        let ours = format_f32(v);
        let mut ryu = ryu::Buffer::new();
        let theirs = if v.is_finite() {
            ryu.format_finite(v)
        } else {
            ryu.format(v)
        };
        assert_eq!(ours.as_str(), theirs, "{:#010x}", v.to_bits());
        assert!(ours.as_bytes().len() <= MAX_LEN);
        if v.is_finite() {
            assert_eq!(
                parse_f32(ours.as_str()).map(f32::to_bits),
                Some(v.to_bits()),
                "{theirs}"
            );
        }
    }
});
