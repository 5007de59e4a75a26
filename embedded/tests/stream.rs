//! The connection code over an in-memory stream that delivers the peer's
//! bytes in pieces of a chosen size, so frame boundaries fall anywhere.

mod support;

use embedded_io_async::{ErrorKind, ErrorType, Read, Write};
use lluav_embedded::{Buffers, Connection, Echo, Error};
use support::{KEY, block_on, masked, op, parse_server_frame, upgrade_request};

/// Gives out `input` at most `piece` bytes per read; collects what is written.
struct Pieces {
    input: Vec<u8>,
    at: usize,
    piece: usize,
    output: Vec<u8>,
}

impl ErrorType for Pieces {
    type Error = ErrorKind;
}

impl Read for Pieces {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        let n = buf.len().min(self.piece).min(self.input.len() - self.at);
        buf[..n].copy_from_slice(&self.input[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

impl Write for Pieces {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        self.output.extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

/// What the adapter did with one input.
struct Run {
    ended: Result<u16, Error<ErrorKind>>,
    /// The frames it sent after the `101`: opcode and payload.
    frames: Vec<(u8, Vec<u8>)>,
    /// The bytes it sent after the `101`.
    wire: Vec<u8>,
}

/// Runs the echo service over `input` cut into `piece`-byte reads.
fn run(input: &[u8], piece: usize) -> Run {
    let mut io = Pieces {
        input: input.to_vec(),
        at: 0,
        piece,
        output: Vec::new(),
    };
    let (mut raw, mut message, mut response, mut transmit) =
        (vec![0; 512], vec![0; 70_000], vec![0; 70_000], vec![0; 70_000]);
    let buffers = Buffers {
        raw: &mut raw,
        message: &mut message,
        response: &mut response,
        transmit: &mut transmit,
    };
    let mut conn = Connection::new(buffers, None);
    let ended = block_on(async {
        conn.accept(&mut io).await?;
        conn.run(&mut io, &Echo).await
    });
    let head_end = io
        .output
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map_or(0, |i| i + 4);
    let wire = io.output[head_end..].to_vec();
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
    let mut io = Pieces {
        input: session(&[]),
        at: 0,
        piece: 64,
        output: Vec::new(),
    };
    let (mut raw, mut message, mut response, mut transmit) = ([0; 16], [0; 16], [0; 16], [0; 16]);
    let buffers = Buffers {
        raw: &mut raw,
        message: &mut message,
        response: &mut response,
        transmit: &mut transmit,
    };
    let mut conn = Connection::new(buffers, None);
    assert_eq!(block_on(conn.accept(&mut io)), Err(Error::Buffers));
}

#[test]
fn a_65535_byte_echo_uses_the_minimal_16_bit_length() {
    let text = "a".repeat(0xffff);
    let r = run(&session(&[masked(true, op::TEXT, text.as_bytes())]), 4096);
    assert_eq!(r.ended, Err(Error::PeerClosed));
    assert_eq!(r.wire[..4], [0x81, 126, 0xff, 0xff]);
    assert_eq!(r.frames, vec![(op::TEXT, text.into_bytes())]);
}

/// The two values embedded-websocket 0.9.5 stores in 24-byte strings with
/// an `unwrap`: whatever their length, the connection answers (101 for a
/// valid key and short protocols, 400 otherwise) and never panics.
#[test]
fn key_and_protocol_of_any_length_are_answered_never_a_panic() {
    for len in 0..=64 {
        let key: String = "dGhlIHNhbXBsZSBub25jZQ==".chars().cycle().take(len).collect();
        let protocol = "p".repeat(len.max(1));
        let request = upgrade_request(&format!(
            "Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Protocol: {protocol}\r\n"
        ));
        let mut io = Pieces {
            input: request.into_bytes(),
            at: 0,
            piece: 7,
            output: Vec::new(),
        };
        let (mut raw, mut message, mut response, mut transmit) = ([0; 512], [0; 512], [0; 512], [0; 512]);
        let buffers = Buffers {
            raw: &mut raw,
            message: &mut message,
            response: &mut response,
            transmit: &mut transmit,
        };
        let accepted = block_on(Connection::new(buffers, None).accept(&mut io)).is_ok();
        let status = if accepted {
            "HTTP/1.1 101 "
        } else {
            "HTTP/1.1 400 "
        };
        assert!(io.output.starts_with(status.as_bytes()), "key {len} bytes");
        assert_eq!(
            accepted,
            len == 24 && protocol.len() <= 24,
            "key and protocol of {len} bytes"
        );
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
