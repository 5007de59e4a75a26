//! A deadline that wakes its task once.
//!
//! tokio's timer wheel keeps a deadline more than 64 ms away in a coarser
//! level and wakes the runtime at the start of that level's slot to move
//! it down, then again at the deadline: a 1 s period is two wake-ups. An
//! idle lluavd's one regular task is the uplink's `state` at 1 Hz, and on
//! the shared VMs we run on a wake-up costs about 50 µs of CPU (a C loop
//! of `nanosleep`s), a third of the whole publication. So on Linux an
//! [`Alarm`] is a timerfd in tokio's reactor, which the kernel makes
//! readable once, at the deadline; elsewhere, or should the timerfd fail,
//! it is tokio's sleep.

use tokio::time::{Instant, sleep_until};

/// One deadline at a time, waited for with [`Alarm::until`].
pub struct Alarm {
    #[cfg(any(target_os = "linux", target_os = "android"))]
    fd: Option<linux::Fd>,
}

impl Alarm {
    /// An alarm set to nothing.
    pub fn new() -> Alarm {
        Alarm {
            #[cfg(any(target_os = "linux", target_os = "android"))]
            fd: linux::Fd::new(),
        }
    }

    /// Waits until `at`, for ever when `None`. Cancel-safe: dropped before
    /// it is due, the next wait for the same instant does not set it again.
    pub async fn until(&mut self, at: Option<Instant>) {
        let Some(at) = at else {
            return std::future::pending().await;
        };
        #[cfg(any(target_os = "linux", target_os = "android"))]
        if let Some(fd) = &mut self.fd {
            match fd.until(at).await {
                Ok(()) => return,
                // Never seen; the wheel still keeps time.
                Err(e) => {
                    tracing::debug!(error = %e, "timerfd failed; tokio's timer instead");
                    self.fd = None;
                }
            }
        }
        sleep_until(at).await;
    }
}

impl Default for Alarm {
    fn default() -> Alarm {
        Alarm::new()
    }
}

#[cfg(any(target_os = "linux", target_os = "android"))]
mod linux {
    use std::io;
    use std::os::fd::{AsFd, AsRawFd, RawFd};

    use nix::sys::time::TimeSpec;
    use nix::sys::timerfd::{ClockId, Expiration, TimerFd, TimerFlags, TimerSetTimeFlags};
    use tokio::io::Interest;
    use tokio::io::unix::AsyncFd;
    use tokio::time::Instant;

    /// A non-blocking monotonic timerfd in tokio's reactor.
    pub struct Fd {
        timer: AsyncFd<Timer>,
        /// What it is set to, if that has not fired yet.
        set: Option<Instant>,
    }

    /// What AsyncFd needs of the timerfd.
    struct Timer(TimerFd);

    impl AsRawFd for Timer {
        fn as_raw_fd(&self) -> RawFd {
            self.0.as_fd().as_raw_fd()
        }
    }

    impl Fd {
        /// `None` outside a tokio runtime or when the kernel refuses one.
        pub fn new() -> Option<Fd> {
            // Registering outside a runtime would panic.
            tokio::runtime::Handle::try_current().ok()?;
            let flags = TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC;
            let timer = TimerFd::new(ClockId::CLOCK_MONOTONIC, flags).ok()?;
            // SAFETY: the TimerFd owns its descriptor and is never replaced
            // or closed while the AsyncFd holds it: `as_raw_fd` returns the
            // same open descriptor for the AsyncFd's whole life.
            let registered = unsafe { AsyncFd::register_with_interest(Timer(timer), Interest::READABLE) };
            let timer = registered.ok()?;
            Some(Fd { timer, set: None })
        }

        /// Waits until `at`.
        pub async fn until(&mut self, at: Instant) -> io::Result<()> {
            loop {
                // A zero TimeSpec would disarm it: a deadline now or past is due.
                let left = at.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    self.set = None;
                    return Ok(());
                }
                if self.set != Some(at) {
                    let when = Expiration::OneShot(TimeSpec::from_duration(left));
                    self.timer.get_ref().0.set(when, TimerSetTimeFlags::empty())?;
                    self.set = Some(at);
                }
                let mut ready = self.timer.readable().await?;
                // The expiry count's read; would block when the readiness
                // was an earlier deadline's, already read.
                match ready.try_io(|t| t.get_ref().0.wait().map_err(io::Error::from)) {
                    Ok(Ok(())) => {
                        // The read took the whole count: nothing is left to
                        // read until the next deadline.
                        ready.clear_ready();
                        self.set = None;
                        return Ok(());
                    }
                    Ok(Err(e)) => return Err(e),
                    Err(_would_block) => continue,
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    /// Starts waiting for `at` and gives up at once, as a `select!` does
    /// when another branch is ready first.
    async fn start_and_drop(alarm: &mut Alarm, at: Instant) {
        tokio::select! {
            biased;
            () = alarm.until(Some(at)) => {}
            () = std::future::ready(()) => {}
        }
    }

    #[tokio::test]
    async fn it_wakes_at_the_deadline_not_before() {
        let mut alarm = Alarm::new();
        #[cfg(any(target_os = "linux", target_os = "android"))]
        assert!(alarm.fd.is_some(), "a timerfd, not tokio's wheel");
        for ms in [30, 1, 80] {
            let at = Instant::now() + Duration::from_millis(ms);
            alarm.until(Some(at)).await;
            assert!(Instant::now() >= at);
        }
    }

    #[tokio::test]
    async fn a_past_deadline_is_due_at_once_and_a_dropped_wait_keeps_its_deadline() {
        let mut alarm = Alarm::new();
        alarm.until(Some(Instant::now())).await;
        let at = Instant::now() + Duration::from_millis(50);
        start_and_drop(&mut alarm, at).await;
        alarm.until(Some(at)).await;
        assert!(Instant::now() >= at);
        // Set, fired and never read, then replaced by a later deadline.
        let fired = Instant::now() + Duration::from_millis(5);
        start_and_drop(&mut alarm, fired).await;
        alarm.until(Some(fired)).await;
        let later = Instant::now() + Duration::from_millis(20);
        alarm.until(Some(later)).await;
        assert!(Instant::now() >= later);
    }

    #[tokio::test]
    async fn a_new_deadline_replaces_a_pending_one() {
        let mut alarm = Alarm::new();
        start_and_drop(&mut alarm, Instant::now() + Duration::from_secs(3600)).await;
        let near = Instant::now() + Duration::from_millis(10);
        alarm.until(Some(near)).await;
        assert!(Instant::now() >= near);
    }
}
