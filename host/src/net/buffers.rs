//! Buffers a session holds only while it has bytes to handle, reused
//! rather than allocated per message.
//!
//! - Response buffers ([`Buffers`]): the core writes a reply into a
//!   caller's buffer of [`super::Limits::response_capacity`] bytes (64 KiB
//!   by default). Held by every session for its whole life, those would be
//!   most of an idle session's memory; allocated per message, each would be
//!   zeroed again. So a session borrows one while a message is handled: a
//!   few are in use at any time (about one per worker thread, plus commands
//!   waiting for the vehicle).
//! - Byte vectors for reading and for queued replies ([`spare`],
//!   [`recycle`]), given back whenever a session waits with nothing in
//!   them.
//!
//! Each thread keeps one of each kind at hand, so the common case (take,
//! handle one request, give back) neither locks nor allocates.

use std::cell::RefCell;
use std::ops::{Deref, DerefMut};
use std::sync::{Mutex, PoisonError};

/// Most idle response buffers a pool keeps for reuse; more are freed.
const MAX_IDLE: usize = 32;

/// Most byte vectors a thread keeps for reuse.
const MAX_SPARE: usize = 4;

/// Larger byte vectors (after a long message) are freed, not kept.
const MAX_SPARE_CAPACITY: usize = 64 * 1024;

thread_local! {
    /// This thread's spare byte vectors, empty.
    static SPARE: RefCell<Vec<Vec<u8>>> = const { RefCell::new(Vec::new()) };
    /// This thread's spare response buffer, of some pool's size.
    static RESPONSE: RefCell<Vec<u8>> = const { RefCell::new(Vec::new()) };
}

/// An empty vector with room for at least `capacity` bytes: one this
/// thread kept, or a new one.
pub fn spare(capacity: usize) -> Vec<u8> {
    let kept = SPARE.with_borrow_mut(|spare| spare.pop());
    let mut v = kept.unwrap_or_default();
    v.reserve(capacity);
    v
}

/// Keeps `v`, emptied, for [`spare`] on this thread, or frees it.
pub fn recycle(mut v: Vec<u8>) {
    if v.capacity() == 0 || v.capacity() > MAX_SPARE_CAPACITY {
        return;
    }
    v.clear();
    SPARE.with_borrow_mut(|spare| {
        if spare.len() < MAX_SPARE {
            spare.push(v);
        }
    });
}

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
        let mut buf = RESPONSE.with_borrow_mut(std::mem::take);
        if buf.len() != self.size {
            if !buf.is_empty() {
                // Another pool's (another listener's limits): keep it there.
                RESPONSE.set(buf);
            }
            let reused = self.idle.lock().unwrap_or_else(PoisonError::into_inner).pop();
            buf = reused.unwrap_or_else(|| vec![0; self.size]);
        }
        Lent { buf, pool: self }
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
        let Some(buf) = RESPONSE.with_borrow_mut(|kept| {
            if kept.is_empty() {
                *kept = buf;
                None
            } else {
                Some(buf)
            }
        }) else {
            return;
        };
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
        drop(first);
        let again = pool.lend();
        assert_eq!(&again[..], &[7; 16], "the one returned, reused");
        drop((second, again));
        let both = [pool.lend(), pool.lend()];
        assert!(both.iter().any(|b| b[..] == [7; 16]) && both.iter().any(|b| b[..] == [0; 16]));
    }

    #[test]
    fn a_recycled_vector_comes_back_empty_and_a_huge_one_does_not() {
        let mut v = spare(100);
        v.extend_from_slice(b"request");
        let address = v.as_ptr();
        recycle(v);
        let again = spare(10);
        assert!(again.is_empty() && again.capacity() >= 100);
        assert_eq!(again.as_ptr(), address, "the same allocation");
        recycle(again);
        recycle(Vec::with_capacity(MAX_SPARE_CAPACITY + 1));
        assert!(spare(0).capacity() <= MAX_SPARE_CAPACITY);
    }
}
