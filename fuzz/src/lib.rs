//! Drivers shared by the WebSocket fuzz targets: both adapters' connection
//! code over in-memory streams, in-process.

use std::cell::RefCell;
use std::net::SocketAddr;
use std::sync::Arc;

use embedded_io_async::{ErrorKind, ErrorType, Read, Write};
use lluav_embedded::{Buffers, Connection, Echo};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// A valid upgrade request, for targets whose input is the frame stream.
pub const UPGRADE: &[u8] = b"GET / HTTP/1.1\r\nHost: drone\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";

/// Hands out the input at most `piece` bytes per read, then end of stream;
/// keeps what the adapter writes, up to a bound.
struct Pieces<'a> {
    input: &'a [u8],
    piece: usize,
    output: Vec<u8>,
}

impl ErrorType for Pieces<'_> {
    type Error = ErrorKind;
}

impl Read for Pieces<'_> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, ErrorKind> {
        let n = buf.len().min(self.piece).min(self.input.len());
        let (now, later) = self.input.split_at(n);
        buf[..n].copy_from_slice(now);
        self.input = later;
        Ok(n)
    }
}

impl Write for Pieces<'_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, ErrorKind> {
        // The adapter's output is bounded by what it reads; this bound only
        // keeps a runaway from going unnoticed.
        assert!(
            self.output.len() + buf.len() <= 1 << 24,
            "the adapter writes without bound"
        );
        self.output.extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), ErrorKind> {
        Ok(())
    }
}

/// Runs the embedded adapter (handshake, then the echo service) over
/// `input` delivered in `piece`-byte reads, with small MCU-sized buffers.
/// Returns what it wrote.
pub fn embedded(input: &[u8], piece: usize) -> Vec<u8> {
    let mut io = Pieces {
        input,
        piece: piece.max(1),
        output: Vec::new(),
    };
    let (mut raw, mut message, mut response, mut transmit) =
        ([0u8; 512], [0u8; 1024], [0u8; 1024], [0u8; 1024]);
    let buffers = Buffers {
        raw: &mut raw,
        message: &mut message,
        response: &mut response,
        transmit: &mut transmit,
    };
    let mut conn = Connection::new(buffers, None);
    embassy_futures::block_on(async {
        if conn.accept(&mut io).await.is_ok() {
            let _ = conn.run(&mut io, &Echo).await;
        }
    });
    io.output
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
/// `request`, and once the server has answered it (as RFC 6455 requires a
/// client to wait; tungstenite drops a client that sends frames earlier)
/// writes `frames`, then ends the stream. Returns everything the server wrote.
pub fn host(request: &[u8], frames: &[u8]) -> Vec<u8> {
    RUNTIME.with(|rt| {
        rt.borrow().block_on(async {
            let (client, server) = tokio::io::duplex(1 << 16);
            let (_stop_tx, stop) = tokio::sync::watch::channel(false);
            let limits = lluav_host::ws::Limits {
                max_message: 4096,
                ..Default::default()
            };
            let handler = Arc::new(lluav_host::ws::Echo);
            let peer: SocketAddr = ([127, 0, 0, 1], 1).into();
            let serve = lluav_host::ws::connection(server, peer, &*handler, limits, stop);
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
