//! Drivers shared by the fuzz targets: both WebSocket adapters' connection
//! code over in-memory streams, in-process, configured alike (the same
//! Origin/Host policy, the same message limit), and what the core's
//! WebSocket rules say each should answer; and lluavd's MAVLink link
//! ([`mavlink`]).

pub mod mavlink;

use std::cell::RefCell;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::Arc;

use lluav_core::CloseCode;
use lluav_core::websocket::handshake::{self, Request};
use lluav_core::websocket::policy::Policy;
use lluav_core::websocket::{Fragments, Interrupt, Opcode, Verdict, close_reply, parse_header, unmask};
use lluav_embedded::testing::{Pipe, PipeError};
use lluav_embedded::{Connection, Echo, Error, Limits};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// A valid upgrade request, for targets whose input is the frame stream.
pub const UPGRADE: &[u8] = b"GET / HTTP/1.1\r\nHost: drone\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";

/// The longest message both adapters take (the MCU's message buffer).
pub const LIMIT: usize = 1024;

/// The longest request head both adapters read (the MCU's; lluavd reads
/// 8 KiB).
pub const HEAD_LIMIT: usize = 1024;

/// The Origin/Host policy of both adapters: the connection arrived on
/// loopback, and `drone` (the Host of [`UPGRADE`]) is an allowed name.
pub const POLICY: Policy<'static> = Policy {
    local: IpAddr::V4(Ipv4Addr::LOCALHOST),
    tls: false,
    allowed_origins: &[],
    allowed_hosts: &["drone"],
};

/// The status each adapter answers `request` with, by the core's upgrade
/// check and [`POLICY`] alone: `(MCU, lluavd)`, or `None` when the head
/// does not end within [`HEAD_LIMIT`] bytes. The MCU serves nothing but
/// the protocol (a plain request gets 400); lluavd without a console
/// answers a plain request 404.
pub fn expected_status(request: &[u8]) -> Option<(u16, u16)> {
    let end = handshake::head_end(request).filter(|&end| end <= HEAD_LIMIT)?;
    Some(match handshake::judge(&request[..end], &POLICY) {
        Ok(Request::Upgrade(_)) => (101, 101),
        Ok(Request::Plain { .. }) => (400, 404),
        Err(why) => (why.status().0, why.status().0),
    })
}

/// The status code an answer starts with, if it is an HTTP answer.
pub fn status(answer: &[u8]) -> Option<u16> {
    let digits = answer.strip_prefix(b"HTTP/1.1 ")?.get(..3)?;
    std::str::from_utf8(digits).ok()?.parse().ok()
}

/// The code of the first close frame a server sent in `wire` (the bytes
/// after its `101`), if it sent one.
pub fn first_close_sent(mut wire: &[u8]) -> Option<u16> {
    while let [b0, b1, rest @ ..] = wire {
        let (len, rest) = match b1 & 0x7f {
            126 => (
                usize::from(u16::from_be_bytes([*rest.first()?, *rest.get(1)?])),
                rest.get(2..)?,
            ),
            127 => (
                usize::try_from(u64::from_be_bytes(*rest.first_chunk::<8>()?)).ok()?,
                rest.get(8..)?,
            ),
            n => (usize::from(n), rest),
        };
        let payload = rest.get(..len)?;
        if b0 & 0x0f == 0x8 {
            return Some(
                payload
                    .first_chunk::<2>()
                    .map_or(1005, |c| u16::from_be_bytes(*c)),
            );
        }
        wire = rest.get(len..)?;
    }
    None
}

/// The code the first close frame sent after the frames `wire` must carry,
/// by the core's rules alone (frames, fragmentation, UTF-8, the close
/// policy of the echo services, the answer to a peer's close), for
/// messages of at most [`LIMIT`] bytes; `None` when the frames end first.
pub fn expected_close(mut wire: &[u8]) -> Option<u16> {
    let mut fragments = Fragments::new();
    let mut message = Vec::new();
    loop {
        let header = match parse_header(wire) {
            Ok(Some(header)) => header,
            Ok(None) => return None,
            Err(code) => return Some(code.code()),
        };
        match fragments.begin(&header, LIMIT) {
            Ok(()) => {}
            Err(Interrupt::Fail(code)) => return Some(code.code()),
            Err(Interrupt::Oversized) => return Some(CloseCode::TooBig.code()),
        }
        let rest = wire.get(header.header_len..).unwrap_or_default();
        let arrived = rest.len().min(usize::try_from(header.len).ok()?);
        let mut payload = rest[..arrived].to_vec();
        unmask(&mut payload, header.mask, 0);
        let complete = arrived as u64 == header.len;
        wire = &rest[arrived..];
        if header.opcode.is_control() {
            match (complete, header.opcode) {
                (false, _) => return None,
                (true, Opcode::Close) => return Some(close_reply(&payload)),
                _ => continue,
            }
        }
        message.extend_from_slice(&payload);
        let whole = complete && header.fin;
        if fragments.extend(&message, whole) == Verdict::Invalid {
            return Some(CloseCode::InvalidPayload.code());
        }
        match (whole, complete) {
            (true, _) => {
                if let Err(code) = fragments.message(&message).text() {
                    return Some(code.code());
                }
                fragments.reset();
                message.clear();
            }
            (false, true) => {}
            (false, false) => return None,
        }
    }
}

/// Runs the embedded adapter (handshake, then the echo service) over
/// `input` delivered in `piece`-byte pieces into a 512-byte receive ring,
/// with small MCU-sized buffers ([`LIMIT`]-byte messages and replies).
/// Returns what it wrote.
pub fn embedded(input: &[u8], piece: usize) -> Vec<u8> {
    // The adapter's output is bounded by what it reads; this bound only
    // keeps a runaway from going unnoticed.
    let mut io = Pipe::new(input, piece, 512, 1028, 1 << 24);
    let mut message = [0u8; LIMIT];
    let limits = Limits {
        reply: LIMIT,
        idle: None,
        close: embassy_time::Duration::from_secs(1),
    };
    let mut conn = Connection::new(&mut message, limits);
    let ended = embassy_futures::block_on(async {
        conn.accept(&mut io, &POLICY, |_| true).await?;
        conn.run(&mut io, &Echo, &mut (), |_| {}).await
    });
    assert_ne!(
        ended,
        Err(Error::Io(PipeError::OutputBound)),
        "the adapter writes without bound"
    );
    io.output().to_vec()
}

thread_local! {
    /// One runtime per fuzzing thread, its clock paused so that timeouts
    /// fire at once instead of in real seconds.
    static RUNTIME: RefCell<tokio::runtime::Runtime> = RefCell::new(
        tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .start_paused(true)
            .build()
            .expect("a runtime"),
    );
}

/// Runs the daemon's connection code with the echo handler: writes
/// `request`, and once the server has answered it (RFC 6455 has a client
/// wait for the 101 before it sends frames) writes `frames`, then ends the
/// stream. Returns everything the server wrote.
pub fn host(request: &[u8], frames: &[u8]) -> Vec<u8> {
    RUNTIME.with(|rt| {
        rt.borrow().block_on(async {
            let (client, server) = tokio::io::duplex(1 << 16);
            let (_stop_tx, stop) = tokio::sync::watch::channel(false);
            let config = lluav_host::net::Config {
                limits: lluav_host::net::Limits {
                    max_message: LIMIT,
                    ..Default::default()
                },
                // POLICY's allow-list: UPGRADE names the server `drone`.
                policy: lluav_host::net::Policy::new(&[], &["drone".to_owned()]).expect("a valid host name"),
                ..Default::default()
            };
            let handler = Arc::new(lluav_host::net::Echo);
            let peer: SocketAddr = ([127, 0, 0, 1], 1).into();
            let serve = lluav_host::net::serve_stream(server, peer, peer.ip(), handler, config, stop);
            let talk = async {
                let (mut rd, mut wr) = tokio::io::split(client);
                let mut out = Vec::new();
                let _ = wr.write_all(request).await;
                if !frames.is_empty() {
                    let mut byte = [0u8; 1];
                    while !out.ends_with(b"\r\n\r\n") && matches!(rd.read(&mut byte).await, Ok(1)) {
                        out.push(byte[0]);
                    }
                    let _ = wr.write_all(frames).await;
                }
                let _ = wr.shutdown().await;
                let _ = rd.read_to_end(&mut out).await;
                out
            };
            let ((), out) = tokio::join!(serve, talk);
            out
        })
    })
}
