//! An in-memory [`Transport`] for tests and fuzzing (feature `testing`,
//! which needs `std`): the peer's bytes arrive in pieces of a chosen size
//! into a receive ring of a chosen capacity, and what the connection
//! writes goes through a transmit ring of a chosen capacity, so frame
//! boundaries, ring wrap-around and a full transmit buffer fall anywhere.
//!
//! Like smoltcp's rings (which embassy-net's `TcpSocket` lends out),
//! `read_with` offers the contiguous part of the received bytes,
//! `write_with` the contiguous free run of the transmit ring, which starts
//! over at the ring's beginning when the ring is empty. The peer reads
//! (and so acknowledges) everything sent when the connection reads (unless
//! it is a [`Pipe::slow_peer`]), when it flushes, and when the transmit
//! ring is full.

use std::vec::Vec;

use crate::transport::Transport;

/// Why a [`Pipe`] refused to go on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PipeError {
    /// The connection wrote more than the pipe's output bound.
    OutputBound,
    /// Every byte of the input was read: the peer has closed its side.
    Ended,
}

/// A ring buffer with smoltcp's contiguous-window semantics.
#[derive(Debug)]
struct Ring {
    storage: Vec<u8>,
    start: usize,
    len: usize,
}

impl Ring {
    fn new(capacity: usize) -> Self {
        Ring {
            storage: std::vec![0; capacity],
            start: 0,
            len: 0,
        }
    }

    fn capacity(&self) -> usize {
        self.storage.len()
    }

    /// The contiguous queued bytes.
    fn queued(&mut self) -> &mut [u8] {
        let end = (self.start + self.len).min(self.capacity());
        self.storage.get_mut(self.start..end).unwrap_or_default()
    }

    fn dequeue(&mut self, n: usize) {
        assert!(n <= self.len, "dequeued more than queued");
        self.start = (self.start + n) % self.capacity().max(1);
        self.len -= n;
    }

    /// The contiguous free run (from the ring's beginning when empty).
    fn free(&mut self) -> &mut [u8] {
        if self.len == 0 {
            self.start = 0;
        }
        let cap = self.capacity();
        let at = (self.start + self.len) % cap.max(1);
        let end = if at >= self.start && self.len < cap {
            cap
        } else {
            self.start
        };
        self.storage.get_mut(at..end).unwrap_or_default()
    }

    fn enqueue(&mut self, n: usize) {
        assert!(n <= self.capacity() - self.len, "enqueued more than free");
        self.len += n;
    }

    /// Moves up to `bytes.len()` bytes in, wrapping; returns how many.
    fn push(&mut self, mut bytes: &[u8]) -> usize {
        let mut pushed = 0;
        while !bytes.is_empty() && self.len < self.capacity() {
            let room = self.free();
            let n = room.len().min(bytes.len());
            let (now, later) = bytes.split_at(n);
            room.iter_mut().zip(now).for_each(|(d, s)| *d = *s);
            self.enqueue(n);
            bytes = later;
            pushed += n;
        }
        pushed
    }

    /// Moves everything out, in order.
    fn pop_all(&mut self, out: &mut Vec<u8>) {
        while self.len > 0 {
            let part = self.queued();
            let n = part.len();
            out.extend_from_slice(part);
            self.dequeue(n);
        }
    }
}

/// An in-memory connection to a scripted peer.
#[derive(Debug)]
pub struct Pipe {
    input: Vec<u8>,
    at: usize,
    piece: usize,
    rx: Ring,
    tx: Ring,
    output: Vec<u8>,
    max_output: usize,
    /// Whether the peer reads what was sent whenever the connection reads.
    eager_peer: bool,
}

impl Pipe {
    /// A peer that sends `input` at most `piece` bytes at a time into a
    /// receive ring of `rx` bytes, then closes its side; the connection's
    /// transmit ring holds `tx` bytes, and it may write at most
    /// `max_output` bytes in all.
    pub fn new(input: &[u8], piece: usize, rx: usize, tx: usize, max_output: usize) -> Self {
        Pipe {
            input: input.to_vec(),
            at: 0,
            piece: piece.max(1),
            rx: Ring::new(rx.max(1)),
            tx: Ring::new(tx),
            output: Vec::new(),
            max_output,
            eager_peer: true,
        }
    }

    /// A peer that reads (and so acknowledges) what the connection sent
    /// only when the connection flushes or its transmit ring is full, not
    /// whenever the connection reads: frames pile up in the transmit ring
    /// and its free run shrinks towards the ring's end.
    pub fn slow_peer(mut self) -> Self {
        self.eager_peer = false;
        self
    }

    /// Everything the connection wrote, including what is still in the
    /// transmit ring.
    pub fn output(&mut self) -> &[u8] {
        self.tx.pop_all(&mut self.output);
        &self.output
    }

    /// Whether every input byte was consumed.
    pub fn consumed(&self) -> bool {
        self.at == self.input.len() && self.rx.len == 0
    }

    fn acknowledge(&mut self) -> Result<(), PipeError> {
        self.tx.pop_all(&mut self.output);
        if self.output.len() > self.max_output {
            return Err(PipeError::OutputBound);
        }
        Ok(())
    }
}

impl Transport for Pipe {
    type Error = PipeError;

    async fn read_with<R, F>(&mut self, f: F) -> Result<R, PipeError>
    where
        F: FnOnce(&mut [u8]) -> (usize, R),
    {
        if self.eager_peer {
            self.acknowledge()?;
        }
        let end = (self.at + self.piece).min(self.input.len());
        self.at += self.rx.push(self.input.get(self.at..end).unwrap_or_default());
        if self.rx.len == 0 {
            return Err(PipeError::Ended);
        }
        let (n, r) = f(self.rx.queued());
        self.rx.dequeue(n);
        Ok(r)
    }

    fn peer_closed(&self) -> bool {
        self.at == self.input.len() && self.rx.len == 0
    }

    async fn write_with<R, F>(&mut self, f: F) -> Result<R, PipeError>
    where
        F: FnOnce(&mut [u8]) -> (usize, R),
    {
        if self.tx.free().is_empty() {
            self.acknowledge()?;
        }
        let (n, r) = f(self.tx.free());
        self.tx.enqueue(n);
        Ok(r)
    }

    async fn flush(&mut self) -> Result<(), PipeError> {
        self.acknowledge()
    }

    fn send_capacity(&self) -> usize {
        self.tx.capacity()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_run_ends_at_the_ring_end_or_the_queued_bytes() {
        let mut r = Ring::new(8);
        assert_eq!(r.free().len(), 8);
        r.enqueue(5);
        r.dequeue(3);
        // Queued: [3, 5); free: [5, 8) contiguous, then [0, 3).
        assert_eq!(r.free().len(), 3);
        r.enqueue(3);
        assert_eq!(r.free().len(), 3);
        r.enqueue(3);
        assert_eq!(r.free().len(), 0);
        r.dequeue(8);
        assert_eq!(r.free().len(), 8, "an empty ring starts over");
    }

    #[test]
    fn pushed_bytes_come_out_in_order_across_the_wrap() {
        let mut r = Ring::new(5);
        assert_eq!(r.push(b"abc"), 3);
        r.dequeue(2);
        assert_eq!(r.push(b"defgh"), 4);
        let mut out = Vec::new();
        r.pop_all(&mut out);
        assert_eq!(out, b"cdefg");
    }
}
