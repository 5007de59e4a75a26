//! The streamed echo (feature `streamed-echo`, `Service::ECHOES_TEXT`):
//! a text message passes through the message buffer one piece at a time
//! and goes back as a fragmented message, so messages far longer than
//! every buffer are echoed; over the in-memory transport, which cuts the
//! peer's bytes anywhere and wraps the receive ring.

mod support;

use std::net::{IpAddr, Ipv4Addr};

use embassy_time::Duration;
use lluav_embedded::lluav_core::websocket::policy::Policy;
use lluav_embedded::testing::{Pipe, PipeError};
use lluav_embedded::{Connection, Echo, Error, Limits, MIN_MESSAGE};
use support::{Frame, KEY, block_on, masked, op, parse_server_frame, upgrade_request};

const POLICY: Policy<'static> = Policy {
    local: IpAddr::V4(Ipv4Addr::new(10, 53, 0, 1)),
    tls: false,
    allowed_origins: &[],
    allowed_hosts: &[],
};

/// The smallest message buffer, so that pieces are short and a message
/// of a few KiB already takes many; the firmware's rings.
const PIECE: usize = MIN_MESSAGE;
const RX: usize = 1024;
const TX: usize = 2052;
const REPLY: usize = 2048;

/// What the echo did with one input.
struct Run {
    ended: Result<u16, Error<PipeError>>,
    /// The frames it sent after the `101`, in order.
    frames: Vec<Frame>,
    /// Whether it read every byte the peer sent.
    consumed: bool,
}

fn session(frames: &[Vec<u8>]) -> Vec<u8> {
    let mut input = upgrade_request(&format!("Sec-WebSocket-Key: {KEY}\r\n")).into_bytes();
    for f in frames {
        input.extend_from_slice(f);
    }
    input
}

/// Runs the echo over `input` cut into `piece`-byte reads, with a
/// `message`-byte message buffer; `slow`: the peer reads what was sent
/// only when the transmit ring is full or the connection flushes.
fn run(input: &[u8], piece: usize, message: usize, slow: bool) -> Run {
    let mut io = Pipe::new(input, piece, RX, TX, 1 << 26);
    if slow {
        io = io.slow_peer();
    }
    let mut buffer = vec![0; message];
    let limits = Limits {
        reply: REPLY,
        idle: None,
        close: Duration::from_secs(1),
    };
    let mut conn = Connection::new(&mut buffer, limits);
    let ended = block_on(async {
        conn.accept(&mut io, &POLICY, |_| true).await?;
        conn.run(&mut io, &Echo, &mut (), |_| {}).await
    });
    let consumed = io.consumed();
    let output = io.output();
    let head_end = output.windows(4).position(|w| w == b"\r\n\r\n").expect("the 101") + 4;
    let mut rest = &output[head_end..];
    let mut frames = Vec::new();
    while let Some((frame, used)) = parse_server_frame(rest) {
        frames.push(frame);
        rest = &rest[used..];
    }
    assert!(rest.is_empty(), "a frame cut short: {rest:?}");
    Run {
        ended,
        frames,
        consumed,
    }
}

/// What the peer made of the frames: each echoed message (checked to be a
/// text frame, continuations, the last one final, none longer than
/// `piece`), the control frames in order, and the bytes of a message the
/// echo began but never finished.
#[derive(Debug, Default, PartialEq)]
struct Received {
    messages: Vec<Vec<u8>>,
    controls: Vec<(u8, Vec<u8>)>,
    unfinished: Option<Vec<u8>>,
}

fn receive(frames: &[Frame], piece: usize) -> Received {
    let mut got = Received::default();
    for f in frames {
        match f.opcode {
            op::TEXT | op::CONTINUATION => {
                assert!(f.payload.len() <= piece, "a frame of {} bytes", f.payload.len());
                let started = got.unfinished.is_some();
                assert_eq!(f.opcode == op::CONTINUATION, started, "{f:?} after {got:?}");
                let mut message = got.unfinished.take().unwrap_or_default();
                message.extend_from_slice(&f.payload);
                if f.fin {
                    got.messages.push(message);
                } else {
                    got.unfinished = Some(message);
                }
            }
            opcode => got.controls.push((opcode, f.payload.clone())),
        }
    }
    got
}

/// `len` bytes of text of one- to four-byte characters, so that piece
/// boundaries fall inside characters of every length.
fn text(len: usize) -> Vec<u8> {
    let chars = ["a", "\u{e9}", "\u{263A}", "\u{1F6F8}", " ", "\u{3ba}\u{1f79}"];
    let mut out = Vec::new();
    let mut i = 0;
    while out.len() < len {
        out.extend_from_slice(chars[i % chars.len()].as_bytes());
        i += 7;
    }
    // Cut at the last character boundary, padded to `len`.
    let end = (0..=len)
        .rev()
        .find(|&end| std::str::from_utf8(&out[..end]).is_ok())
        .unwrap();
    out.truncate(end);
    out.resize(len, b'z');
    out
}

/// `message` cut into frames of the given lengths (the last takes the
/// rest), a ping after each but the last.
fn fragments(message: &[u8], lengths: &[usize]) -> Vec<Vec<u8>> {
    let mut frames = Vec::new();
    let mut rest = message;
    for (i, &len) in lengths.iter().enumerate() {
        let (now, later) = rest.split_at(len.min(rest.len()));
        let opcode = if i == 0 { op::TEXT } else { op::CONTINUATION };
        frames.push(masked(false, opcode, now));
        frames.push(masked(true, op::PING, format!("{i}").as_bytes()));
        rest = later;
    }
    frames.push(masked(true, op::CONTINUATION, rest));
    frames
}

const CLOSE_1000: [u8; 2] = 1000u16.to_be_bytes();

/// A message of 100,000 bytes, 390 times the message buffer, single and
/// in fragments of odd lengths with pings between them, comes back whole
/// in frames of at most the buffer's length, whatever the piece size,
/// with every pong in order, to a peer that reads at once or late.
#[test]
fn a_message_far_longer_than_the_buffer_is_echoed_whole_in_pieces() {
    let long = text(100_000);
    let single = session(&[
        masked(true, op::TEXT, &long),
        masked(true, op::CLOSE, &CLOSE_1000),
    ]);
    let mut frames = fragments(&long, &[1, 300, 7, 40_000, 0, 255]);
    frames.push(masked(true, op::CLOSE, &CLOSE_1000));
    let fragmented = session(&frames);
    for (input, pongs) in [(&single, 0), (&fragmented, 6)] {
        for piece in [1, 3, 100, 1500, 4096] {
            for slow in [false, true] {
                let r = run(input, piece, PIECE, slow);
                assert_eq!(r.ended, Ok(1000), "piece {piece}");
                let got = receive(&r.frames, PIECE);
                assert_eq!(got.messages.len(), 1, "piece {piece}");
                assert!(got.messages[0] == long, "piece {piece}: the echo differs");
                let mut expected: Vec<(u8, Vec<u8>)> = (0..pongs)
                    .map(|i| (op::PONG, format!("{i}").into_bytes()))
                    .collect();
                expected.push((op::CLOSE, CLOSE_1000.to_vec()));
                assert_eq!(got.controls, expected, "piece {piece}");
                assert!(
                    r.frames.len() > long.len() / PIECE,
                    "piece {piece}: not in pieces"
                );
            }
        }
    }
}

/// A four-byte character across the first piece's end, and characters
/// of every length across a fragment's end and the reads' ends: the piece
/// is sent with the character's start, the next one finishes it.
#[test]
fn a_character_split_across_pieces_and_fragments_is_echoed() {
    let mut message = vec![b'a'; PIECE - 2];
    message.extend_from_slice("\u{1F6F8}".as_bytes());
    message.extend_from_slice(&text(3000));
    let first = message[..PIECE].to_vec();
    assert!(
        std::str::from_utf8(&first).is_err(),
        "the first piece ends inside a character"
    );
    let frames = [
        fragments(&message, &[PIECE - 1, 2, 1, 100]),
        vec![masked(true, op::CLOSE, &CLOSE_1000)],
    ]
    .concat();
    for piece in 1..=9 {
        let r = run(&session(&frames), piece, PIECE, false);
        assert_eq!(r.ended, Ok(1000), "piece {piece}");
        let data: Vec<&Frame> = r.frames.iter().filter(|f| f.opcode < op::CLOSE).collect();
        assert_eq!(data[0].payload, first, "piece {piece}");
        assert_eq!(receive(&r.frames, PIECE).messages, vec![message.clone()]);
    }
}

/// Control frames between fragments are answered at once, between the
/// echo's own fragments: a piece sent before a ping, its pong, the rest
/// after. A close between fragments is answered and ends the echo
/// unfinished.
#[test]
fn control_frames_between_fragments_go_out_between_the_echo_s_frames() {
    let message = text(PIECE + 44);
    let input = session(&[
        masked(false, op::TEXT, &message[..PIECE + 20]),
        masked(true, op::PING, b"between"),
        masked(true, op::CONTINUATION, &message[PIECE + 20..]),
        masked(true, op::CLOSE, &CLOSE_1000),
    ]);
    for piece in [1, 5, 64, 4096] {
        let r = run(&input, piece, PIECE, false);
        assert_eq!(r.ended, Ok(1000), "piece {piece}");
        let shape: Vec<(bool, u8, usize)> = r
            .frames
            .iter()
            .map(|f| (f.fin, f.opcode, f.payload.len()))
            .collect();
        assert_eq!(
            shape,
            [
                (false, op::TEXT, PIECE),
                (true, op::PONG, 7),
                (true, op::CONTINUATION, 44),
                (true, op::CLOSE, 2),
            ],
            "piece {piece}"
        );
        assert_eq!(receive(&r.frames, PIECE).messages, vec![message.clone()]);
    }
    let closing = session(&[
        masked(false, op::TEXT, &message[..PIECE + 20]),
        masked(true, op::CLOSE, &4000u16.to_be_bytes()),
        masked(true, op::CONTINUATION, b"never echoed"),
    ]);
    let r = run(&closing, 64, PIECE, false);
    assert_eq!(r.ended, Ok(4000));
    let got = receive(&r.frames, PIECE);
    assert_eq!(got.messages, Vec::<Vec<u8>>::new());
    assert_eq!(got.unfinished.as_deref(), Some(&message[..PIECE]));
    assert_eq!(got.controls, vec![(op::CLOSE, 4000u16.to_be_bytes().to_vec())]);
}

/// An invalid byte in the middle of a 10,000-byte text frame closes with
/// 1007 as soon as it is read: the pieces before it were echoed, none
/// with it, no final frame, and the rest of the frame was never read. So
/// with a fragmented message whose second fragment is invalid: its third
/// is never read.
#[test]
fn an_invalid_byte_mid_message_closes_1007_without_reading_the_rest() {
    let mut message = text(10_000);
    let bad = 5_000;
    // A character boundary, so that the byte before it is valid text.
    let bad = (bad..)
        .find(|&i| std::str::from_utf8(&message[..i]).is_ok())
        .unwrap();
    message[bad] = 0xff;
    let single = session(&[masked(true, op::TEXT, &message)]);
    let fragmented = session(&[
        masked(false, op::TEXT, &message[..bad - 10]),
        masked(false, op::CONTINUATION, &message[bad - 10..bad + 10]),
        masked(true, op::CONTINUATION, &message[bad + 10..]),
    ]);
    for input in [single, fragmented] {
        for piece in [1, 7, 100, 1024] {
            let r = run(&input, piece, PIECE, false);
            assert_eq!(r.ended, Ok(1007), "piece {piece}");
            assert!(!r.consumed, "piece {piece}: the rest of the message was read");
            let got = receive(&r.frames, PIECE);
            assert_eq!(got.controls, vec![(op::CLOSE, 1007u16.to_be_bytes().to_vec())]);
            assert!(got.messages.is_empty(), "piece {piece}: the echo was finished");
            let echoed = got.unfinished.unwrap_or_default();
            assert_eq!(
                echoed.len(),
                bad / PIECE * PIECE,
                "piece {piece}: whole pieces before the bad byte"
            );
            assert_eq!(echoed[..], message[..echoed.len()]);
        }
    }
}

/// A message whose last frame ends inside a character closes with 1007;
/// its last frame is never sent, so the peer never gets invalid text.
#[test]
fn a_message_ending_inside_a_character_closes_1007_without_its_last_frame() {
    let mut message = text(PIECE + 10);
    message.extend_from_slice(&"\u{263A}".as_bytes()[..2]);
    for piece in [1, 3, 4096] {
        let r = run(&session(&[masked(true, op::TEXT, &message)]), piece, PIECE, false);
        assert_eq!(r.ended, Ok(1007), "piece {piece}");
        let got = receive(&r.frames, PIECE);
        assert!(got.messages.is_empty());
        assert_eq!(got.unfinished.as_deref(), Some(&message[..PIECE]));
    }
}

/// Several messages in a row, each starting with a text frame again;
/// empty messages and empty fragments; a message that fills the buffer
/// exactly goes out as one final frame.
#[test]
fn messages_in_a_row_each_start_over() {
    let exact = text(PIECE);
    let input = session(&[
        masked(true, op::TEXT, b""),
        masked(false, op::TEXT, b""),
        masked(false, op::CONTINUATION, b"ab"),
        masked(true, op::CONTINUATION, b""),
        masked(true, op::TEXT, &exact),
        masked(true, op::TEXT, &text(3 * PIECE + 1)),
        masked(true, op::TEXT, b"last"),
        masked(true, op::CLOSE, &CLOSE_1000),
    ]);
    for piece in [1, 2, 300, 4096] {
        let r = run(&input, piece, PIECE, false);
        assert_eq!(r.ended, Ok(1000), "piece {piece}");
        let got = receive(&r.frames, PIECE);
        let expected = vec![
            Vec::new(),
            b"ab".to_vec(),
            exact.clone(),
            text(3 * PIECE + 1),
            b"last".to_vec(),
        ];
        assert_eq!(got.messages, expected, "piece {piece}");
        let data: Vec<(bool, u8, usize)> = r
            .frames
            .iter()
            .filter(|f| f.opcode < op::CLOSE)
            .map(|f| (f.fin, f.opcode, f.payload.len()))
            .collect();
        let expected = [
            (true, op::TEXT, 0),
            (true, op::TEXT, 2),
            (true, op::TEXT, PIECE),
            (false, op::TEXT, PIECE),
            (false, op::CONTINUATION, PIECE),
            (false, op::CONTINUATION, PIECE),
            (true, op::CONTINUATION, 1),
            (true, op::TEXT, 4),
        ];
        assert_eq!(data, expected, "piece {piece}");
    }
}

/// Every other rule still holds in the middle of a streamed message: a
/// new text frame before the last fragment, a frame with a reserved bit,
/// a length not in its minimal form fail the connection with 1002 after
/// the pieces already echoed; binary messages are gathered and refused
/// (1003), and one longer than the message buffer is oversized (1009).
#[test]
fn frame_rules_hold_mid_stream_and_binary_is_still_refused() {
    let first = masked(false, op::TEXT, &text(PIECE + 1));
    let mut reserved = masked(true, op::CONTINUATION, b"x");
    reserved[0] |= 0x20;
    let mut not_minimal = vec![op::CONTINUATION | 0x80, 0x80 | 126, 0, 5, 1, 2, 3, 4];
    not_minimal.extend_from_slice(b"hello");
    for breaking in [masked(true, op::TEXT, b"again"), reserved, not_minimal] {
        let r = run(&session(&[first.clone(), breaking]), 64, PIECE, false);
        assert_eq!(r.ended, Ok(1002));
        let got = receive(&r.frames, PIECE);
        assert_eq!(got.unfinished.map(|m| m.len()), Some(PIECE));
        assert_eq!(got.controls, vec![(op::CLOSE, 1002u16.to_be_bytes().to_vec())]);
    }
    let binary = session(&[masked(true, op::BINARY, &[1; 100])]);
    assert_eq!(run(&binary, 64, PIECE, false).ended, Ok(1003));
    let long_binary = session(&[masked(true, op::BINARY, &[1; PIECE + 1])]);
    let r = run(&long_binary, 64, PIECE, false);
    assert_eq!(r.ended, Ok(1009));
    assert!(!r.consumed, "an oversized frame is refused at its header");
}
