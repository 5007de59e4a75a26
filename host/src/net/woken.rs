//! A future that is polled again only once it has woken its task.
//!
//! A session waits for its socket, its timer and the news that it must
//! end (shutdown, reclaiming) in one `select!`, which polls every branch
//! each time the task runs: once per request. Polling tokio's `Notified`
//! takes the `Notify`'s lock, a timer is checked against the clock, and
//! both rarely fire; wrapped in [`Woken`], each is polled once to register,
//! then only after it woke the task.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::{Context, Poll, Wake, Waker};

use futures_util::task::AtomicWaker;

/// What the inner future's waker does: note the wake, pass it on.
#[derive(Default)]
struct Signal {
    woken: AtomicBool,
    task: AtomicWaker,
}

impl Wake for Signal {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }

    fn wake_by_ref(self: &Arc<Self>) {
        self.woken.store(true, Ordering::Release);
        self.task.wake();
    }
}

/// `F`, polled only when it has asked to be (see the module docs).
pub struct Woken<F> {
    inner: Pin<Box<F>>,
    signal: Arc<Signal>,
    waker: Waker,
    registered: bool,
}

impl<F: Future> Woken<F> {
    /// Wraps `inner`.
    pub fn new(inner: F) -> Self {
        let signal = Arc::new(Signal::default());
        Woken {
            inner: Box::pin(inner),
            waker: Waker::from(Arc::clone(&signal)),
            signal,
            registered: false,
        }
    }
}

impl<F: Future> Future for Woken<F> {
    type Output = F::Output;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<F::Output> {
        let this = self.get_mut();
        this.signal.task.register(cx.waker());
        if this.registered && !this.signal.woken.swap(false, Ordering::AcqRel) {
            return Poll::Pending;
        }
        this.registered = true;
        this.inner.as_mut().poll(&mut Context::from_waker(&this.waker))
    }
}

impl<F> Woken<F> {
    /// The wrapped future, to change; it is polled again on the next poll
    /// (a timer that was reset registers its new deadline).
    pub fn inner_mut(&mut self) -> Pin<&mut F> {
        self.registered = false;
        self.inner.as_mut()
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;
    use std::sync::atomic::AtomicUsize;

    use super::*;

    /// Pending forever; counts its polls and keeps the last waker.
    #[derive(Default)]
    struct Probe {
        polls: AtomicUsize,
        waker: Mutex<Option<Waker>>,
    }

    #[test]
    fn the_inner_future_is_polled_once_then_only_after_its_wake() {
        let probe = Arc::new(Probe::default());
        let inner = {
            let probe = Arc::clone(&probe);
            std::future::poll_fn(move |cx| {
                probe.polls.fetch_add(1, Ordering::SeqCst);
                *probe.waker.lock().expect("not poisoned") = Some(cx.waker().clone());
                Poll::<()>::Pending
            })
        };
        let mut woken = std::pin::pin!(Woken::new(inner));
        let mut cx = Context::from_waker(Waker::noop());
        for _ in 0..5 {
            assert!(woken.as_mut().poll(&mut cx).is_pending());
        }
        assert_eq!(
            probe.polls.load(Ordering::SeqCst),
            1,
            "not polled again until woken"
        );
        let waker = probe
            .waker
            .lock()
            .expect("not poisoned")
            .take()
            .expect("registered");
        waker.wake();
        assert!(woken.as_mut().poll(&mut cx).is_pending());
        assert!(woken.as_mut().poll(&mut cx).is_pending());
        assert_eq!(
            probe.polls.load(Ordering::SeqCst),
            2,
            "polled once after its wake"
        );
    }
}
