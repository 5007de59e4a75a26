//! The connection code over an in-memory transport that delivers the
//! peer's bytes in pieces of a chosen size into a receive ring of a chosen
//! size, so frame boundaries and the ring's wrap-around fall anywhere.

mod support;

use std::net::{IpAddr, Ipv4Addr};

use embassy_time::Duration;
use lluav_embedded::lluav_core::websocket::policy::Policy;
use lluav_embedded::testing::{Pipe, PipeError};
use lluav_embedded::{Connection, Echo, Error, Limits};
use support::{KEY, block_on, masked, op, parse_server_frame, upgrade_request};

/// The address the in-memory connection "arrived at" (the test requests' Host).
const POLICY: Policy<'static> = Policy {
    local: IpAddr::V4(Ipv4Addr::new(10, 53, 0, 1)),
    tls: false,
    allowed_origins: &[],
    allowed_hosts: &[],
};

/// What the adapter did with one input.
struct Run {
    ended: Result<u16, Error<PipeError>>,
    /// The frames it sent after the `101`: opcode and payload.
    frames: Vec<(u8, Vec<u8>)>,
    /// The bytes it sent after the `101`.
    wire: Vec<u8>,
}

/// Buffer sizes of one run.
#[derive(Clone, Copy)]
struct Sizes {
    rx: usize,
    tx: usize,
    message: usize,
    reply: usize,
}

/// The firmware's sizes: a 1 KiB receive ring, a transmit ring just
/// large enough for a whole 2 KiB reply, a 4 KiB message buffer.
const MCU: Sizes = Sizes {
    rx: 1024,
    tx: 2052,
    message: 4096,
    reply: 2048,
};

/// The echo configuration's sizes, large enough for 64 KiB messages.
const LARGE: Sizes = Sizes {
    rx: 4096,
    tx: 70_016,
    message: 70_000,
    reply: 70_000,
};

/// Runs the echo service over `input` cut into `piece`-byte reads.
fn run(input: &[u8], piece: usize) -> Run {
    run_with(input, piece, LARGE)
}

fn run_with(input: &[u8], piece: usize, sizes: Sizes) -> Run {
    let mut io = Pipe::new(input, piece, sizes.rx, sizes.tx, 1 << 24);
    let mut message = vec![0; sizes.message];
    let limits = Limits {
        reply: sizes.reply,
        idle: None,
        close: Duration::from_secs(1),
    };
    let mut conn = Connection::new(&mut message, limits);
    let ended = block_on(async {
        conn.accept(&mut io, &POLICY, |_| true).await?;
        conn.run(&mut io, &Echo, &mut (), |_| {}).await
    });
    let output = io.output();
    let head_end = output
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map_or(0, |i| i + 4);
    let wire = output[head_end..].to_vec();
    let mut rest = &wire[..];
    let mut frames = Vec::new();
    while let Some((frame, used)) = parse_server_frame(rest) {
        frames.push((frame.opcode, frame.payload));
        rest = &rest[used..];
    }
    Run { ended, frames, wire }
}

fn session(frames: &[Vec<u8>]) -> Vec<u8> {
    let mut input = upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n")).into_bytes();
    for f in frames {
        input.extend_from_slice(f);
    }
    input
}

#[test]
fn fragmented_message_is_reassembled_however_the_bytes_are_cut() {
    let input = session(&[
        masked(false, op::TEXT, b"frag"),
        masked(true, op::PING, b"!"),
        masked(false, op::CONTINUATION, b"mented "),
        masked(
            true,
            op::CONTINUATION,
            "message of some length \u{263A}".as_bytes(),
        ),
        masked(true, op::CLOSE, &1000u16.to_be_bytes()),
    ]);
    for piece in [1, 2, 3, 7, 64, 4096] {
        let Run { ended, frames, .. } = run(&input, piece);
        assert_eq!(ended, Ok(1000), "piece {piece}");
        let expected = vec![
            (op::PONG, b"!".to_vec()),
            (
                op::TEXT,
                "fragmented message of some length \u{263A}".as_bytes().to_vec(),
            ),
            (op::CLOSE, 1000u16.to_be_bytes().to_vec()),
        ];
        assert_eq!(frames, expected, "piece {piece}");
    }
}

#[test]
fn peer_vanishing_mid_frame_ends_the_connection_without_a_reply() {
    let mut input = session(&[masked(true, op::TEXT, b"state")]);
    input.truncate(input.len() - 2);
    let Run { ended, frames, .. } = run(&input, 5);
    assert_eq!((ended, frames.len()), (Err(Error::PeerClosed), 0));
}

#[test]
fn reserved_bits_fail_the_connection_with_1002() {
    let mut frame = masked(true, op::TEXT, b"x");
    frame[0] |= 0x40;
    let Run { ended, frames, .. } = run(&session(&[frame]), 64);
    assert_eq!(ended, Ok(1002));
    assert_eq!(frames, vec![(op::CLOSE, 1002u16.to_be_bytes().to_vec())]);
}

/// RFC 6455, section 5.2: a length must use the minimal form; a 3-byte
/// payload announced in 16 bits, or a 200-byte one in 64 bits, fails the
/// connection with 1002 before any payload is read.
#[test]
fn a_length_not_in_its_minimal_form_fails_with_1002() {
    let mask = [1, 2, 3, 4];
    let short_in_16 = [&[0x81, 0x80 | 126, 0, 3][..], &mask, b"abc"].concat();
    let mut medium_in_64 = vec![0x81, 0x80 | 127, 0, 0, 0, 0, 0, 0, 0, 200];
    medium_in_64.extend_from_slice(&mask);
    medium_in_64.extend(std::iter::repeat_n(b'a', 200));
    for frame in [short_in_16, medium_in_64] {
        for piece in [1, 3, 64] {
            let Run { ended, frames, .. } = run(&session(std::slice::from_ref(&frame)), piece);
            assert_eq!(ended, Ok(1002), "piece {piece}");
            assert_eq!(frames, vec![(op::CLOSE, 1002u16.to_be_bytes().to_vec())]);
        }
    }
}

#[test]
fn text_frame_inside_a_fragmented_message_fails_with_1002() {
    let input = session(&[masked(false, op::TEXT, b"a"), masked(true, op::TEXT, b"b")]);
    assert_eq!(run(&input, 64).ended, Ok(1002));
}

#[test]
fn close_reason_that_is_not_utf8_is_answered_with_1007() {
    let input = session(&[masked(true, op::CLOSE, b"\x03\xe8\xff")]);
    assert_eq!(run(&input, 64).ended, Ok(1007));
}

#[test]
fn too_small_buffers_are_an_error_not_a_panic() {
    let sizes = [
        // A message buffer below MIN_MESSAGE.
        Sizes { message: 16, ..MCU },
        // A reply capacity below the core's minimum.
        Sizes { reply: 16, ..MCU },
        // A transmit buffer that cannot hold a whole reply and its header.
        Sizes {
            tx: MCU.reply + 3,
            ..MCU
        },
    ];
    for sizes in sizes {
        let r = run_with(&session(&[]), 64, sizes);
        assert_eq!(r.ended, Err(Error::Buffers));
        assert!(r.wire.is_empty());
    }
}

#[test]
fn a_65535_byte_echo_uses_the_minimal_16_bit_length() {
    let text = "a".repeat(0xffff);
    let r = run(&session(&[masked(true, op::TEXT, text.as_bytes())]), 4096);
    assert_eq!(r.ended, Err(Error::PeerClosed));
    assert_eq!(r.wire[..4], [0x81, 126, 0xff, 0xff]);
    assert_eq!(r.frames, vec![(op::TEXT, text.into_bytes())]);
}

/// Whatever the length of the key and of an offered protocol, the
/// connection answers (101 for a valid key, 400 otherwise; offered
/// protocols are ignored) and never panics: embedded-websocket, which
/// builds the 101, is only ever handed a key of 24 base64 characters.
#[test]
fn key_and_protocol_of_any_length_are_answered_never_a_panic() {
    for len in 0..=64 {
        let key: String = "dGhlIHNhbXBsZSBub25jZQ==".chars().cycle().take(len).collect();
        let protocol = "p".repeat(len.max(1));
        let request = upgrade_request(&format!(
            "Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Protocol: {protocol}\r\n"
        ));
        let mut io = Pipe::new(request.as_bytes(), 7, 512, 600, 1 << 20);
        let mut message = [0; 512];
        let limits = Limits {
            reply: 512,
            idle: None,
            close: Duration::from_secs(1),
        };
        let accepted =
            block_on(Connection::new(&mut message, limits).accept(&mut io, &POLICY, |_| true)).is_ok();
        let status = if accepted {
            "HTTP/1.1 101 "
        } else {
            "HTTP/1.1 400 "
        };
        assert!(io.output().starts_with(status.as_bytes()), "key {len} bytes");
        assert_eq!(accepted, len == 24, "key and protocol of {len} bytes");
    }
}

/// Random bytes after a valid upgrade, and random mutations of valid
/// frames: every connection ends with a close code we may send or a stream
/// error, never a panic (a deterministic generator; the fuzzer goes further).
#[test]
fn arbitrary_frame_streams_end_in_a_close_or_an_error() {
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let valid = [
        masked(false, op::TEXT, b"st"),
        masked(true, op::PING, b"x"),
        masked(true, op::CONTINUATION, b"ate"),
        masked(true, op::TEXT, &[b'a'; 300]),
        masked(true, op::CLOSE, &1000u16.to_be_bytes()),
    ];
    for round in 0..2000 {
        let mut frames: Vec<u8> = valid.concat();
        if round % 2 == 0 {
            let len = (next() % 600) as usize;
            frames = (0..len).map(|_| next() as u8).collect();
        } else {
            for _ in 0..1 + next() % 4 {
                let at = (next() as usize) % frames.len();
                frames[at] = next() as u8;
            }
        }
        let piece = 1 + (next() % 64) as usize;
        let ended = run(&session(&[frames]), piece).ended;
        match ended {
            Ok(code) => assert!(
                matches!(code, 1000..=1003 | 1007..=1011 | 3000..=4999),
                "round {round}: {code}"
            ),
            Err(e) => assert_eq!(e, Error::PeerClosed, "round {round}"),
        }
    }
}

/// RFC 6455 8.1 "fail fast": a text message whose second fragment makes it
/// invalid UTF-8 is closed with 1007 before its third fragment is read
/// (Autobahn cases 6.4.1 and 6.4.2), and a single frame whose middle is
/// invalid is closed before its end arrives (6.4.3, 6.4.4).
#[test]
fn invalid_utf8_fails_at_the_first_bad_byte_not_at_the_end() {
    let fragments = session(&[
        masked(false, op::TEXT, "\u{3ba}\u{1f79}".as_bytes()),
        masked(false, op::CONTINUATION, b"\xf4\x90\x80\x80"),
        masked(true, op::CONTINUATION, b"edited"),
    ]);
    let mut single = session(&[]);
    let frame = masked(
        true,
        op::TEXT,
        b"\xce\xba\xf4\x90\x80\x80\x65\x64\x69\x74\x65\x64",
    );
    single.extend_from_slice(&frame);
    for input in [fragments, single] {
        for piece in [1, 3, 64] {
            let mut io = Pipe::new(&input, piece, 1024, 2052, 1 << 20);
            let mut message = [0; 4096];
            let limits = Limits {
                reply: 2048,
                idle: None,
                close: Duration::from_secs(1),
            };
            let mut conn = Connection::new(&mut message, limits);
            let ended = block_on(async {
                conn.accept(&mut io, &POLICY, |_| true).await?;
                conn.run(&mut io, &Echo, &mut (), |_| {}).await
            });
            assert_eq!(ended, Ok(1007), "piece {piece}");
            if piece <= 3 {
                assert!(!io.consumed(), "piece {piece}: the rest of the message was read");
            }
        }
    }
}

#[test]
fn a_message_ending_inside_a_character_closes_with_1007() {
    let input = session(&[masked(true, op::TEXT, &"\u{263A}".as_bytes()[..2])]);
    assert_eq!(run(&input, 1).ended, Ok(1007));
}

/// With the firmware's sizes, a 4 KiB message goes through a 1 KiB receive
/// ring (the frame wrapping around it many times) and its 2 KiB reply
/// through a transmit ring that holds one reply: every frame of the mix is
/// answered, in order, whatever the piece size.
#[test]
fn mcu_sized_rings_carry_full_size_messages_and_replies() {
    let big = "m".repeat(2048);
    let input = session(&[
        masked(true, op::TEXT, b"a"),
        masked(true, op::TEXT, big.as_bytes()),
        masked(true, op::PING, b"p"),
        masked(true, op::TEXT, b"b"),
        masked(true, op::TEXT, big.as_bytes()),
        masked(true, op::CLOSE, &1000u16.to_be_bytes()),
    ]);
    for piece in [1, 5, 100, 1500] {
        let r = run_with(&input, piece, MCU);
        assert_eq!(r.ended, Ok(1000), "piece {piece}");
        let expected = vec![
            (op::TEXT, b"a".to_vec()),
            (op::TEXT, big.clone().into_bytes()),
            (op::PONG, b"p".to_vec()),
            (op::TEXT, b"b".to_vec()),
            (op::TEXT, big.clone().into_bytes()),
            (op::CLOSE, 1000u16.to_be_bytes().to_vec()),
        ];
        assert_eq!(r.frames, expected, "piece {piece}");
    }
}

/// The echo is sent straight from the message buffer, in as many pieces
/// as the transmit ring takes: with the firmware's sizes, a 4 KiB message
/// (twice the reply capacity, twice the transmit ring) comes back whole,
/// to a peer that reads only when the connection waits for it too.
#[test]
fn an_echo_longer_than_the_transmit_ring_goes_out_whole_in_pieces() {
    let long: Vec<u8> = (0..4096).map(|i| b'a' + (i % 26) as u8).collect();
    let input = session(&[
        masked(true, op::TEXT, &long),
        masked(true, op::TEXT, b"next"),
        masked(true, op::CLOSE, &1000u16.to_be_bytes()),
    ]);
    for piece in [1, 100, 4096] {
        let r = run_with(&input, piece, MCU);
        assert_eq!(r.ended, Ok(1000), "piece {piece}");
        let expected = vec![
            (op::TEXT, long.clone()),
            (op::TEXT, b"next".to_vec()),
            (op::CLOSE, 1000u16.to_be_bytes().to_vec()),
        ];
        assert_eq!(r.frames, expected, "piece {piece}");
    }
    let mut io = Pipe::new(&input, 100, MCU.rx, MCU.tx, 1 << 20).slow_peer();
    let mut message = vec![0; MCU.message];
    let limits = Limits {
        reply: MCU.reply,
        idle: None,
        close: Duration::from_secs(1),
    };
    let mut conn = Connection::new(&mut message, limits);
    let ended = block_on(async {
        conn.accept(&mut io, &POLICY, |_| true).await?;
        conn.run(&mut io, &Echo, &mut (), |_| {}).await
    });
    assert_eq!(ended, Ok(1000));
    let output = io.output();
    let wire = &output[output.windows(4).position(|w| w == b"\r\n\r\n").unwrap() + 4..];
    let (frame, _) = parse_server_frame(wire).expect("the echo");
    assert_eq!((frame.opcode, frame.payload), (op::TEXT, long));
}

/// embedded-websocket frames pongs and close frames into a contiguous run
/// of the transmit ring. With a peer that reads only when the connection
/// flushes, 125-byte pongs pile up until the ring's free run is too short
/// for the next one: the connection waits for the peer to read, and every
/// pong, the echo and the close frame go out whole and in order.
#[test]
fn largest_pongs_go_out_whole_when_the_transmit_ring_runs_short() {
    let reply = lluav_embedded::lluav_core::MIN_RESPONSE_CAPACITY;
    let payloads: Vec<Vec<u8>> = (0..7u8).map(|i| vec![b'a' + i; 125]).collect();
    let mut frames: Vec<Vec<u8>> = payloads.iter().map(|p| masked(true, op::PING, p)).collect();
    frames.push(masked(true, op::TEXT, b"after the pongs"));
    frames.push(masked(true, op::CLOSE, &4000u16.to_be_bytes()));
    let input = session(&frames);
    for piece in [1, 9, 130, 4096] {
        let mut io = Pipe::new(&input, piece, 256, reply + 4, 1 << 20).slow_peer();
        let mut message = [0; 512];
        let limits = Limits {
            reply,
            idle: None,
            close: Duration::from_secs(1),
        };
        let mut conn = Connection::new(&mut message, limits);
        let ended = block_on(async {
            conn.accept(&mut io, &POLICY, |_| true).await?;
            conn.run(&mut io, &Echo, &mut (), |_| {}).await
        });
        assert_eq!(ended, Ok(4000), "piece {piece}");
        let output = io.output();
        let mut rest = &output[output.windows(4).position(|w| w == b"\r\n\r\n").unwrap() + 4..];
        let mut got = Vec::new();
        while let Some((frame, used)) = parse_server_frame(rest) {
            got.push((frame.opcode, frame.payload));
            rest = &rest[used..];
        }
        let mut expected: Vec<(u8, Vec<u8>)> = payloads.iter().map(|p| (op::PONG, p.clone())).collect();
        expected.push((op::TEXT, b"after the pongs".to_vec()));
        expected.push((op::CLOSE, 4000u16.to_be_bytes().to_vec()));
        assert_eq!(got, expected, "piece {piece}");
    }
}
