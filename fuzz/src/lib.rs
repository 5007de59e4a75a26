//! Drivers shared by the WebSocket fuzz targets: both adapters' connection
//! code over in-memory streams, in-process.

use std::cell::RefCell;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::Arc;

use lluav_embedded::policy::Policy;
use lluav_embedded::testing::{Pipe, PipeError};
use lluav_embedded::{Connection, Echo, Error, Limits};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// A valid upgrade request, for targets whose input is the frame stream.
pub const UPGRADE: &[u8] = b"GET / HTTP/1.1\r\nHost: drone\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n";

/// Runs the embedded adapter (handshake, then the echo service) over
/// `input` delivered in `piece`-byte pieces into a 512-byte receive ring,
/// with small MCU-sized buffers (1 KiB messages and replies). Returns what
/// it wrote.
pub fn embedded(input: &[u8], piece: usize) -> Vec<u8> {
    // The adapter's output is bounded by what it reads; this bound only
    // keeps a runaway from going unnoticed.
    let mut io = Pipe::new(input, piece, 512, 1028, 1 << 24);
    let mut message = [0u8; 1024];
    let limits = Limits {
        reply: 1024,
        idle: None,
        close: embassy_time::Duration::from_secs(1),
    };
    // `drone` is the Host of UPGRADE; loopback names pass as well.
    let policy = Policy {
        address: IpAddr::V4(Ipv4Addr::LOCALHOST),
        allowed_origins: &[],
        allowed_hosts: &["drone"],
    };
    let mut conn = Connection::new(&mut message, limits);
    let ended = embassy_futures::block_on(async {
        conn.accept(&mut io, &policy, |_| true).await?;
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
                    max_message: 4096,
                    ..Default::default()
                },
                // UPGRADE names the server `drone`: allowed, so that
                // frames reach the connection code.
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
