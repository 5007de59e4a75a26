//! The link to the broker: its state, for `state.uplink` and the logs, and
//! how long to wait before dialling again.

use std::fmt;
use std::hash::{BuildHasher, RandomState};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

/// The uplink's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// No uplink configured.
    Off,
    /// Configured, not connected to the broker.
    Down,
    /// Connected to the broker.
    Up,
}

impl Status {
    /// `off`, `down` or `up`, as `state.uplink` says.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Off => "off",
            Status::Down => "down",
            Status::Up => "up",
        }
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The uplink's state, shared: the uplink writes it, `state` and the
/// service manager read it, and the uplink's own tasks wait on it (events
/// go out only while it is up).
#[derive(Clone, Debug)]
pub struct StatusCell(Arc<watch::Sender<Status>>);

impl StatusCell {
    /// `Down` when an uplink is configured (until it connects), else `Off`.
    pub fn new(configured: bool) -> StatusCell {
        let status = if configured { Status::Down } else { Status::Off };
        StatusCell(Arc::new(watch::Sender::new(status)))
    }

    /// The state now.
    pub fn get(&self) -> Status {
        *self.0.borrow()
    }

    /// Sets the state; returns the one it replaces.
    pub fn set(&self, status: Status) -> Status {
        self.0.send_replace(status)
    }

    /// Returns once the state is `Up` (at once if it is).
    pub async fn up(&self) {
        let mut seen = self.0.subscribe();
        // The sender lives in `self`: waiting cannot fail.
        let _ = seen.wait_for(|s| *s == Status::Up).await;
    }
}

/// The first wait before dialling again.
pub const BACKOFF_MIN: Duration = Duration::from_millis(500);
/// The longest wait.
pub const BACKOFF_MAX: Duration = Duration::from_secs(30);

/// Waits between attempts to reach the broker: doubling from
/// [`BACKOFF_MIN`] to [`BACKOFF_MAX`], each drawn at random from its upper
/// half so that a fleet that lost its broker together does not come back
/// together.
#[derive(Debug)]
pub struct Backoff {
    next: Duration,
    random: RandomState,
    draws: u64,
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff {
            next: BACKOFF_MIN,
            random: RandomState::new(),
            draws: 0,
        }
    }
}

impl Backoff {
    /// The next wait.
    pub fn delay(&mut self) -> Duration {
        self.draws += 1;
        let fraction = (self.random.hash_one(self.draws) >> 11) as f64 / (1u64 << 53) as f64;
        let wait = self.next.mul_f64(0.5 + 0.5 * fraction);
        self.next = (self.next * 2).min(BACKOFF_MAX);
        wait
    }

    /// Starts again from [`BACKOFF_MIN`].
    pub fn reset(&mut self) {
        self.next = BACKOFF_MIN;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_double_from_half_a_second_to_thirty_with_jitter() {
        let mut b = Backoff::default();
        let waits: Vec<Duration> = (0..12).map(|_| b.delay()).collect();
        let mut ceiling = BACKOFF_MIN;
        for w in &waits {
            assert!(*w >= ceiling / 2 && *w <= ceiling, "{w:?} outside {ceiling:?}");
            ceiling = (ceiling * 2).min(BACKOFF_MAX);
        }
        assert!(waits[11] >= BACKOFF_MAX / 2);
        b.reset();
        assert!(b.delay() <= BACKOFF_MIN);
    }

    #[test]
    fn the_cell_reads_what_was_set() {
        let cell = StatusCell::new(true);
        assert_eq!(cell.get(), Status::Down);
        assert_eq!(cell.set(Status::Up), Status::Down);
        assert_eq!(cell.clone().get(), Status::Up);
        assert_eq!(StatusCell::new(false).get().as_str(), "off");
    }

    #[tokio::test]
    async fn waiting_for_up_returns_once_it_is_set() {
        let cell = StatusCell::new(true);
        let waiting = tokio::spawn({
            let cell = cell.clone();
            async move { cell.up().await }
        });
        tokio::task::yield_now().await;
        assert!(!waiting.is_finished());
        cell.set(Status::Up);
        waiting.await.expect("returned");
        cell.up().await;
    }
}
