//! What a connection runs over: a byte stream whose receive and transmit
//! buffers it reads and writes in place, as embassy-net's [`TcpSocket`]
//! offers with `read_with` and `write_with`.
//!
//! The connection keeps no staging buffer of its own: frames are parsed
//! and unmasked straight out of the socket's receive buffer into the
//! message buffer (the one copy a message takes), and replies are written
//! by the protocol core straight into the socket's transmit buffer (see
//! [`crate::connection`] for why, and what it costs).

use embassy_net::tcp::{Error as TcpError, State, TcpSocket};

/// A byte stream with in-place access to its buffers.
// Futures of embassy tasks never cross threads, so the `Send` bound that
// `async_fn_in_trait` warns about would only exclude single-core executors.
#[allow(async_fn_in_trait)]
pub trait Transport {
    /// Why the stream failed.
    type Error: core::fmt::Debug;

    /// Waits until received bytes are buffered, then calls `f` with the
    /// longest contiguous run of them; `f` returns how many it consumed
    /// (they leave the buffer) and a value. Fails when the stream failed,
    /// and when the peer has closed its side and every byte was consumed
    /// ([`Transport::peer_closed`] tells the two apart).
    async fn read_with<R, F>(&mut self, f: F) -> Result<R, Self::Error>
    where
        F: FnOnce(&mut [u8]) -> (usize, R);

    /// Whether the peer has closed its side of the stream: after a failed
    /// [`Transport::read_with`], an orderly end rather than a failure.
    fn peer_closed(&self) -> bool;

    /// Waits until transmit space is free, then calls `f` with the longest
    /// contiguous run of it; `f` returns how many bytes it filled (they are
    /// sent) and a value. The run only grows while nothing is written, and
    /// once everything written is acknowledged it is the whole buffer.
    async fn write_with<R, F>(&mut self, f: F) -> Result<R, Self::Error>
    where
        F: FnOnce(&mut [u8]) -> (usize, R);

    /// Waits until everything written has been sent and acknowledged.
    async fn flush(&mut self) -> Result<(), Self::Error>;

    /// The size of the transmit buffer.
    fn send_capacity(&self) -> usize;
}

impl Transport for TcpSocket<'_> {
    type Error = TcpError;

    // embassy-net's futures themselves, not wrapped in one more state
    // machine: every connection's state holds them.
    fn read_with<R, F>(&mut self, f: F) -> impl Future<Output = Result<R, TcpError>>
    where
        F: FnOnce(&mut [u8]) -> (usize, R),
    {
        TcpSocket::read_with(self, f)
    }

    // embassy-net reports the peer's FIN like a reset; the state tells
    // them apart.
    fn peer_closed(&self) -> bool {
        matches!(
            self.state(),
            State::CloseWait | State::LastAck | State::Closing | State::TimeWait
        )
    }

    fn write_with<R, F>(&mut self, f: F) -> impl Future<Output = Result<R, TcpError>>
    where
        F: FnOnce(&mut [u8]) -> (usize, R),
    {
        TcpSocket::write_with(self, f)
    }

    fn flush(&mut self) -> impl Future<Output = Result<(), TcpError>> {
        TcpSocket::flush(self)
    }

    fn send_capacity(&self) -> usize {
        TcpSocket::send_capacity(self)
    }
}

/// Waits until the transmit buffer offers `len` contiguous bytes: at once
/// if the free run is long enough, otherwise once everything written so
/// far is acknowledged (then the run is the whole buffer, which the caller
/// made at least `len` long).
pub(crate) async fn reserve<T: Transport>(io: &mut T, len: usize) -> Result<bool, T::Error> {
    for _ in 0..2 {
        if write(io, &mut |_| 0).await? >= len {
            return Ok(true);
        }
        io.flush().await?;
    }
    Ok(false)
}

/// Waits until the transmit buffer has free space, then calls `fill` with
/// its free run and sends the bytes `fill` says it wrote; returns the
/// run's length. The small writers (the `101`, refusals, control frames,
/// [`reserve`]'s probe) share this one `write_with` in flash through a
/// `dyn` filler. A reply is written through a `write_with` of its own:
/// behind a `dyn` filler the compiler inlines the protocol core into the
/// server task's poll, whose stack frame grows from 6.7 KB to 9.9 KB.
pub(crate) async fn write<T: Transport>(
    io: &mut T,
    fill: &mut dyn FnMut(&mut [u8]) -> usize,
) -> Result<usize, T::Error> {
    io.write_with(|room| {
        let run = room.len();
        (fill(room), run)
    })
    .await
}

/// Waits until received bytes are buffered, then calls `take` with their
/// longest contiguous run and consumes the bytes `take` says it took;
/// returns the run's length (see [`received`] for the peer's orderly
/// end). Like [`write`], one `read_with` in flash.
pub(crate) async fn read<T: Transport>(
    io: &mut T,
    take: &mut dyn FnMut(&mut [u8]) -> usize,
) -> Result<usize, T::Error> {
    io.read_with(|run| {
        let len = run.len();
        (take(run), len)
    })
    .await
}

/// What a [`read`] came to: `Ok(None)` when the peer has closed its side
/// and every byte was consumed. (Apart from [`read`]: inside it, this
/// costs 100 bytes of flash more.)
pub(crate) fn received<T: Transport, R>(io: &T, got: Result<R, T::Error>) -> Result<Option<R>, T::Error> {
    match got {
        Ok(r) => Ok(Some(r)),
        Err(_) if io.peer_closed() => Ok(None),
        Err(e) => Err(e),
    }
}
