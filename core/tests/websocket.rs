//! The WebSocket frame codec both adapters share: client headers checked
//! against RFC 6455, unmasking in pieces, server headers in the minimal
//! length form, UTF-8 checked as a text message arrives, the rules of a
//! message across its frames, and the answer to a peer's close.

use lluav_core::websocket::{
    Fragments, Header, Interrupt, Opcode, Utf8, Utf8Stream, Verdict, close_reply, parse_header, unmask,
    write_header,
};
use lluav_core::{CloseCode, Message};
use proptest::prelude::*;

#[test]
fn a_header_cut_short_waits_for_more_bytes() {
    assert_eq!(parse_header(&[]), Ok(None));
    assert_eq!(parse_header(&[0x81]), Ok(None));
    assert_eq!(parse_header(&[0x81, 0xfe, 0x01]), Ok(None));
    assert_eq!(parse_header(&[0x81, 0xff, 0, 0, 0, 0, 0, 0, 1]), Ok(None));
    assert_eq!(parse_header(&[0x81, 0x85, 1, 2, 3]), Ok(None));
}

#[test]
fn sixteen_and_sixty_four_bit_lengths_are_read() {
    let h = parse_header(&[0x81, 0xfe, 0x01, 0x00, 1, 2, 3, 4]);
    let h = h.ok().flatten().expect("a whole header");
    assert_eq!((h.len, h.header_len, h.mask), (256, 8, [1, 2, 3, 4]));
    let h = parse_header(&[0x02, 0xff, 0, 0, 0, 1, 0, 0, 0, 0, 9, 9, 9, 9]);
    let h = h.ok().flatten().expect("a whole header");
    assert_eq!(
        (h.len, h.header_len, h.fin, h.opcode),
        (1 << 32, 14, false, Opcode::Binary)
    );
}

#[test]
fn every_opcode_reads_back_from_its_bits() {
    for opcode in [
        Opcode::Continuation,
        Opcode::Text,
        Opcode::Binary,
        Opcode::Close,
        Opcode::Ping,
        Opcode::Pong,
    ] {
        let h = parse_header(&[0x80 | opcode.bits(), 0x80, 0, 0, 0, 0]);
        assert_eq!(h.ok().flatten().map(|h| h.opcode), Some(opcode));
    }
}

#[test]
fn frames_the_rfc_forbids_fail_with_1002() {
    let bad: [&[u8]; 7] = [
        &[0xc1, 0x80, 0, 0, 0, 0],                   // RSV1 without an extension
        &[0x83, 0x80, 0, 0, 0, 0],                   // reserved data opcode
        &[0x8b, 0x80, 0, 0, 0, 0],                   // reserved control opcode
        &[0x81, 0x00],                               // unmasked client frame
        &[0x09, 0x80, 0, 0, 0, 0],                   // fragmented ping
        &[0x89, 0xfe, 0, 126, 0, 0, 0, 0],           // ping over 125 bytes
        &[0x81, 0xff, 0x80, 0, 0, 0, 0, 0, 0, 0, 0], // 64-bit length, top bit set
    ];
    for frame in bad {
        assert_eq!(parse_header(frame), Err(CloseCode::ProtocolError), "{frame:?}");
    }
}

#[test]
fn lengths_not_in_their_minimal_form_fail_with_1002() {
    // RFC 6455, section 5.2: "the minimal number of bytes MUST be used".
    let bad: [&[u8]; 4] = [
        &[0x81, 0xfe, 0, 3, 1, 2, 3, 4],                         // 3 bytes in 16 bits
        &[0x81, 0xfe, 0, 125, 1, 2, 3, 4],                       // 125 in 16 bits
        &[0x81, 0xff, 0, 0, 0, 0, 0, 0, 0, 200, 1, 2, 3, 4],     // 200 in 64 bits
        &[0x81, 0xff, 0, 0, 0, 0, 0, 0, 0xff, 0xff, 1, 2, 3, 4], // 65,535 in 64 bits
    ];
    for frame in bad {
        assert_eq!(parse_header(frame), Err(CloseCode::ProtocolError), "{frame:?}");
        // Known as soon as the length is in, before the mask arrives.
        assert_eq!(
            parse_header(&frame[..frame.len() - 4]),
            Err(CloseCode::ProtocolError)
        );
    }
    let least: [(&[u8], u64); 2] = [
        (&[0x81, 0xfe, 0, 126, 1, 2, 3, 4], 126),
        (&[0x81, 0xff, 0, 0, 0, 0, 0, 1, 0, 0, 1, 2, 3, 4], 0x1_0000),
    ];
    for (frame, len) in least {
        assert_eq!(parse_header(frame).ok().flatten().map(|h| h.len), Some(len));
    }
}

#[test]
fn server_headers_use_the_minimal_length_form() {
    let header = |opcode, len| {
        let mut out = [0u8; 10];
        let n = write_header(&mut out, opcode, len).expect("room for any header");
        out[..n].to_vec()
    };
    assert_eq!(header(Opcode::Text, 125), [0x81, 125]);
    assert_eq!(header(Opcode::Text, 126), [0x81, 126, 0, 126]);
    // 65535 still fits the 16-bit form (Autobahn case 1.1.6).
    assert_eq!(header(Opcode::Text, 0xffff), [0x81, 126, 0xff, 0xff]);
    assert_eq!(header(Opcode::Text, 0x10000), [0x81, 127, 0, 0, 0, 0, 0, 1, 0, 0]);
    assert_eq!(header(Opcode::Pong, 2), [0x8a, 2]);
    assert_eq!(header(Opcode::Close, 0), [0x88, 0]);
    assert_eq!(write_header(&mut [0u8; 3], Opcode::Text, 126), None);
}

#[test]
fn unmasking_in_pieces_of_any_size_equals_unmasking_at_once() {
    let mask = [0x37, 0xfa, 0x21, 0x3d];
    let clear: Vec<u8> = (0..=255u8).cycle().take(300).collect();
    let masked: Vec<u8> = clear
        .iter()
        .zip(mask.iter().cycle())
        .map(|(b, k)| b ^ k)
        .collect();
    for piece in [1, 2, 3, 7, 8, 13, 64, 300] {
        let mut wire = masked.clone();
        let mut at = 0;
        for chunk in wire.chunks_mut(piece) {
            unmask(chunk, mask, at);
            at += chunk.len();
        }
        assert_eq!(wire, clear, "pieces of {piece}");
    }
}

#[test]
fn the_rfc_s_masked_hello_unmasks_across_pieces() {
    // RFC 6455, section 5.7: "Hello", masked with 37 fa 21 3d.
    let mask = [0x37, 0xfa, 0x21, 0x3d];
    let mut wire = *b"\x7f\x9f\x4d\x51\x58";
    let (a, b) = wire.split_at_mut(2);
    unmask(a, mask, 0);
    unmask(b, mask, 2);
    assert_eq!(&wire, b"Hello");
}

/// Feeds `pieces` one after the other; the verdict after the last one fed
/// and whether the message ends on a character boundary.
fn feed(pieces: &[&[u8]]) -> (Verdict, bool) {
    let mut message = Vec::new();
    let mut utf8 = Utf8::new();
    let mut verdict = Verdict::Open;
    for piece in pieces {
        message.extend_from_slice(piece);
        verdict = utf8.extend(&message);
        if verdict == Verdict::Invalid {
            break;
        }
    }
    (verdict, utf8.complete(message.len()))
}

#[test]
fn a_character_split_between_pieces_is_valid() {
    let smiley = "\u{263A}".as_bytes();
    assert_eq!(
        feed(&[b"a", &smiley[..1], &smiley[1..2], &smiley[2..]]),
        (Verdict::Open, true)
    );
}

#[test]
fn a_message_ending_inside_a_character_is_incomplete() {
    assert_eq!(
        feed(&[b"ab", &"\u{263A}".as_bytes()[..2]]),
        (Verdict::Open, false)
    );
}

#[test]
fn an_invalid_byte_fails_before_the_message_ends() {
    assert_eq!(feed(&[b"valid", b"\xff", b"never read"]).0, Verdict::Invalid);
}

#[test]
fn a_code_point_above_the_unicode_range_fails_at_its_second_byte() {
    // 0xF4 0x90 would start U+110000: invalid as soon as 0x90 arrives.
    assert_eq!(feed(&[b"\xf4", b"\x90"]).0, Verdict::Invalid);
}

#[test]
fn surrogates_and_overlong_forms_fail() {
    assert_eq!(feed(&[b"\xed\xa0\x80"]).0, Verdict::Invalid);
    assert_eq!(feed(&[b"\xc0\xaf"]).0, Verdict::Invalid);
}

/// Whether some continuation can still make `prefix` valid UTF-8: the
/// verdict a checker that saw `prefix` must give.
fn possible(prefix: &[u8]) -> bool {
    match std::str::from_utf8(prefix) {
        Ok(_) => true,
        Err(e) => e.error_len().is_none(),
    }
}

/// Pushes `message` cut at `cuts` (ascending offsets) into a
/// [`Utf8Stream`], checking after each piece that its verdict is the one
/// the bytes so far call for; stops at the first `Invalid`. Whether the
/// message ended on a character boundary, if it was pushed whole.
fn stream(message: &[u8], cuts: &[usize]) -> Option<bool> {
    let mut utf8 = Utf8Stream::new();
    let mut at = 0;
    for &end in cuts.iter().chain([&message.len()]) {
        let verdict = utf8.push(&message[at..end]);
        let expected = if possible(&message[..end]) {
            Verdict::Open
        } else {
            Verdict::Invalid
        };
        assert_eq!(
            verdict, expected,
            "{message:x?} cut at {cuts:?}, after {end} bytes"
        );
        if verdict == Verdict::Invalid {
            return None;
        }
        at = end;
    }
    Some(utf8.complete())
}

/// Characters of one to four bytes, and the invalid forms Autobahn's
/// section 6 sends (a code point above U+10FFFF, a surrogate, overlong
/// forms, a lone continuation byte, a character cut by the end): cut into
/// two and three pieces at every offset, each piece is judged as the whole
/// message so far would be, and only a valid message ends complete.
#[test]
fn a_stream_cut_anywhere_is_judged_as_the_whole_message() {
    let messages: [&[u8]; 9] = [
        "a\u{e9}\u{263A}\u{1F6F8}z".as_bytes(),
        "\u{3ba}\u{1f79}\u{3c3}\u{3bc}\u{3b5}".as_bytes(),
        b"\xce\xba\xf4\x90\x80\x80edited",
        b"ab\xed\xa0\x80cd",
        b"\xc0\xaf and \xe0\x80\xaf",
        b"text \x80 lone",
        b"ends inside \xe2\x98",
        b"\xf0\x9f\x9b",
        b"",
    ];
    for message in messages {
        let whole = std::str::from_utf8(message).is_ok();
        for a in 0..=message.len() {
            if let Some(complete) = stream(message, &[a]) {
                assert_eq!(complete, whole, "{message:x?} cut at {a}");
            }
            for b in a..=message.len() {
                if let Some(complete) = stream(message, &[a, b]) {
                    assert_eq!(complete, whole, "{message:x?} cut at {a} and {b}");
                }
            }
        }
    }
}

#[test]
fn a_stream_of_one_byte_pieces_carries_every_character_across() {
    let text = "\u{1F6F8} over \u{263A}, \u{e9}t\u{e9}".as_bytes();
    let cuts: Vec<usize> = (1..text.len()).collect();
    assert_eq!(stream(text, &cuts), Some(true));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2048, ..ProptestConfig::default() })]

    /// Valid text with stray bytes mixed in, cut anywhere: the stream's
    /// verdict after every piece is the whole prefix's.
    #[test]
    fn a_stream_agrees_with_the_whole_message(
        parts in proptest::collection::vec(
            prop_oneof![
                any::<char>().prop_map(|c| c.to_string().into_bytes()),
                any::<u8>().prop_map(|b| vec![b]),
            ],
            0..40,
        ),
        mut cuts in proptest::collection::vec(any::<proptest::sample::Index>(), 0..8),
    ) {
        let message = parts.concat();
        let mut cuts: Vec<usize> = cuts.drain(..).map(|i| i.index(message.len() + 1)).collect();
        cuts.sort_unstable();
        if let Some(complete) = stream(&message, &cuts) {
            prop_assert_eq!(complete, std::str::from_utf8(&message).is_ok());
        }
    }
}

/// The header of a masked client frame with a `len`-byte payload.
fn header(first: u8, len: u64) -> Header {
    let mut wire = vec![first];
    match len {
        0..=125 => wire.push(0x80 | len as u8),
        126..=0xffff => {
            wire.push(0x80 | 126);
            wire.extend_from_slice(&(len as u16).to_be_bytes());
        }
        _ => {
            wire.push(0x80 | 127);
            wire.extend_from_slice(&len.to_be_bytes());
        }
    }
    wire.extend_from_slice(&[0; 4]);
    parse_header(&wire).ok().flatten().expect("a valid header")
}

#[test]
fn a_fragmented_message_is_one_message_and_control_frames_may_interleave() {
    let mut fragments = Fragments::new();
    assert_eq!(fragments.begin(&header(0x01, 4), 100), Ok(()));
    fragments.extend(b"set_", false);
    assert_eq!(fragments.begin(&header(0x89, 5), 100), Ok(()));
    assert_eq!(fragments.begin(&header(0x80, 3), 100), Ok(()));
    fragments.extend(b"set_sp_", true);
    assert_eq!(fragments.received(), 7);
    assert_eq!(fragments.message(b"set_sp_"), Message::Text(b"set_sp_"));
    fragments.reset();
    assert!(!fragments.in_progress());
    assert_eq!(fragments.begin(&header(0x82, 2), 100), Ok(()));
    assert_eq!(fragments.message(&[1, 2]), Message::Binary(&[1, 2]));
}

#[test]
fn continuations_out_of_place_fail_with_1002() {
    let fail = Err(Interrupt::Fail(CloseCode::ProtocolError));
    assert_eq!(Fragments::new().begin(&header(0x80, 1), 100), fail);
    let mut fragments = Fragments::new();
    assert_eq!(fragments.begin(&header(0x01, 1), 100), Ok(()));
    assert_eq!(fragments.begin(&header(0x81, 1), 100), fail);
    assert_eq!(fragments.begin(&header(0x02, 1), 100), fail);
}

#[test]
fn a_message_over_the_limit_is_refused_at_the_header_of_its_frame() {
    assert_eq!(
        Fragments::new().begin(&header(0x81, 11), 10),
        Err(Interrupt::Oversized)
    );
    let mut fragments = Fragments::new();
    assert_eq!(fragments.begin(&header(0x01, 6), 10), Ok(()));
    fragments.extend(b"aaaaaa", false);
    assert_eq!(fragments.begin(&header(0x80, 4), 10), Ok(()));
    assert_eq!(fragments.begin(&header(0x80, 5), 10), Err(Interrupt::Oversized));
    assert_eq!(
        Fragments::new().begin(&header(0x81, u64::MAX >> 1), usize::MAX),
        Ok(())
    );
}

#[test]
fn text_fails_at_its_first_bad_byte_and_a_complete_message_is_left_whole() {
    let mut fragments = Fragments::new();
    assert_eq!(fragments.begin(&header(0x01, 3), 100), Ok(()));
    assert_eq!(fragments.extend(b"ok", false), Verdict::Open);
    assert_eq!(fragments.extend(b"ok\xff", false), Verdict::Invalid);
    // A complete message is Message::text's to check, once.
    let mut whole = Fragments::new();
    assert_eq!(whole.begin(&header(0x81, 1), 100), Ok(()));
    assert_eq!(whole.extend(b"\xff", true), Verdict::Open);
    assert_eq!(whole.message(b"\xff").text(), Err(CloseCode::InvalidPayload));
    // Binary is not text.
    let mut binary = Fragments::new();
    assert_eq!(binary.begin(&header(0x02, 1), 100), Ok(()));
    assert_eq!(binary.extend(b"\xff", false), Verdict::Open);
}

#[test]
fn a_peers_close_is_answered_with_its_code_or_the_reason_it_cannot_be() {
    assert_eq!(close_reply(&[]), 1000);
    assert_eq!(close_reply(&[0x03]), 1002);
    for code in [1000u16, 1001, 1003, 1007, 1011, 1014, 3000, 4999] {
        assert_eq!(close_reply(&code.to_be_bytes()), code);
    }
    for code in [0u16, 999, 1004, 1005, 1006, 1015, 1016, 2999, 5000] {
        assert_eq!(close_reply(&code.to_be_bytes()), 1002, "{code}");
    }
    assert_eq!(close_reply(b"\x03\xe8bye"), 1000);
    assert_eq!(close_reply(b"\x03\xe8\xff"), 1007);
}
