//! A session's bytes on the socket: reads into its [`Reader`], writes of
//! its queued frames. Shared by the read loop ([`super::connection`]) and
//! the reading done while a command is pending ([`super::waiting`]).

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Poll};
use std::time::Duration;

use futures_util::FutureExt;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::timeout;

use super::reader::Reader;

/// Reads more bytes into `reader`; 0 at the end of the stream. `drained`
/// tells whether the read took less than it had room for (the socket had
/// nothing more then). While it waits, the reader holds no buffer.
pub fn poll_read<S: AsyncRead + Unpin>(
    stream: &mut S,
    reader: &mut Reader,
    cx: &mut Context<'_>,
    drained: &mut bool,
) -> Poll<std::io::Result<usize>> {
    let buf = reader.buffer();
    let room = buf.capacity() - buf.len();
    let polled = pin!(stream.read_buf(buf)).poll(cx);
    match &polled {
        Poll::Ready(Ok(n)) => *drained = *n < room,
        Poll::Ready(Err(_)) => {}
        Poll::Pending => reader.release(),
    }
    polled
}

/// Writes `outbox` and empties it; false if the peer does not take it
/// within `io_timeout` (the connection is then dropped).
pub async fn write<S: AsyncWrite + Unpin>(
    stream: &mut S,
    outbox: &mut Vec<u8>,
    io_timeout: Duration,
) -> bool {
    let mut write = pin!(async {
        stream.write_all(outbox).await?;
        stream.flush().await
    });
    // Usually the socket takes it all at once: then no timer is made
    // (a timer reads the clock and the runtime's handle).
    let written = match write.as_mut().now_or_never() {
        Some(done) => Ok(done),
        None => timeout(io_timeout, write).await,
    };
    outbox.clear();
    matches!(written, Ok(Ok(())))
}
