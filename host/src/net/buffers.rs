//! The response buffers of a listener's sessions, lent for one message at
//! a time.
//!
//! The core writes a reply into a caller's buffer of
//! [`super::Limits::response_capacity`] bytes (64 KiB by default). Held by
//! every session for its whole life, those would be most of an idle
//! session's memory; allocated per message, each would be zeroed again.
//! So a session borrows one only while a message is being handled: a few
//! are in use at any time (about one per worker thread, plus commands
//! waiting for the vehicle), and they are reused.

use std::ops::{Deref, DerefMut};
use std::sync::{Mutex, PoisonError};

/// Most idle buffers kept for reuse; more are freed when returned.
const MAX_IDLE: usize = 32;

/// A pool of equally sized response buffers.
#[derive(Debug)]
pub struct Buffers {
    size: usize,
    idle: Mutex<Vec<Vec<u8>>>,
}

impl Buffers {
    /// A pool of buffers of `size` bytes.
    pub fn new(size: usize) -> Self {
        Buffers {
            size,
            idle: Mutex::new(Vec::new()),
        }
    }

    /// A buffer of the pool's size, returned to it when dropped. Its
    /// contents are whatever its last user left.
    pub fn lend(&self) -> Lent<'_> {
        let reused = self.idle.lock().unwrap_or_else(PoisonError::into_inner).pop();
        Lent {
            buf: reused.unwrap_or_else(|| vec![0; self.size]),
            pool: self,
        }
    }
}

/// A buffer lent by [`Buffers::lend`].
#[derive(Debug)]
pub struct Lent<'p> {
    buf: Vec<u8>,
    pool: &'p Buffers,
}

impl Deref for Lent<'_> {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        &self.buf
    }
}

impl DerefMut for Lent<'_> {
    fn deref_mut(&mut self) -> &mut [u8] {
        &mut self.buf
    }
}

impl Drop for Lent<'_> {
    fn drop(&mut self) {
        let buf = std::mem::take(&mut self.buf);
        let mut idle = self.pool.idle.lock().unwrap_or_else(PoisonError::into_inner);
        if idle.len() < MAX_IDLE {
            idle.push(buf);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_returned_buffer_is_lent_again_and_one_in_use_is_not() {
        let pool = Buffers::new(16);
        let mut first = pool.lend();
        first.fill(7);
        let second = pool.lend();
        assert_eq!(&second[..], &[0; 16], "a fresh buffer while the first is out");
        drop(second);
        drop(first);
        let again = pool.lend();
        assert_eq!(&again[..], &[7; 16], "the last one returned, reused");
    }
}
