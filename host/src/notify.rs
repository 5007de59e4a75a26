//! systemd's service notifications (`sd_notify`): `READY=1` once lluavd
//! accepts connections, `WATCHDOG=1` every half `WATCHDOG_USEC`, `STATUS=`
//! with the sessions and the links, `STOPPING=1` when a signal stops it.
//!
//! Each notification is one datagram to the Unix socket named by
//! `NOTIFY_SOCKET` (a path, or `@name` in the abstract namespace). Without
//! that variable (not started by systemd, or `Type=` other than `notify`)
//! nothing is sent. The watchdog is petted by a task of the runtime that
//! serves the sessions, after taking the vehicle's lock for the status: a
//! runtime whose workers are all stuck, or a vehicle lock that is never
//! released, stops the petting, and systemd restarts the service.

use std::fmt;
use std::io;
use std::net::SocketAddr;
use std::os::unix::net::{SocketAddr as UnixAddr, UnixDatagram};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use lluav_core::{Message, Outcome};
use tracing::{debug, warn};

use crate::net::Handler;

/// How often `STATUS=` is refreshed when systemd asked for no watchdog.
const STATUS_PERIOD: Duration = Duration::from_secs(1);

/// A connection to systemd's notification socket.
#[derive(Clone, Debug)]
pub struct Notifier {
    socket: Arc<UnixDatagram>,
    target: Arc<UnixAddr>,
    watchdog: Option<Duration>,
}

impl Notifier {
    /// The notifier systemd asked for through `NOTIFY_SOCKET`, or `None`
    /// when it is unset or empty (or unusable, which is logged).
    pub fn from_env() -> Option<Notifier> {
        let path = std::env::var_os("NOTIFY_SOCKET").filter(|p| !p.is_empty())?;
        let opened =
            target(path.as_encoded_bytes()).and_then(|target| Ok((UnixDatagram::unbound()?, target)));
        match opened {
            Ok((socket, target)) => Some(Notifier {
                socket: Arc::new(socket),
                target: Arc::new(target),
                watchdog: watchdog_from_env(),
            }),
            Err(e) => {
                warn!(error = %e, socket = %path.to_string_lossy(), "NOTIFY_SOCKET is unusable; not notifying systemd");
                None
            }
        }
    }

    /// How often the watchdog is petted: half of `WATCHDOG_USEC`, when it
    /// is set for this process.
    pub fn watchdog(&self) -> Option<Duration> {
        self.watchdog
    }

    /// Sends one notification (`KEY=value` lines). A failure is logged and
    /// otherwise ignored: systemd going away must not stop the vehicle.
    pub fn send(&self, state: &str) {
        if let Err(e) = self.socket.send_to_addr(state.as_bytes(), &self.target) {
            debug!(error = %e, "sd_notify failed");
        }
    }

    /// `READY=1`, with a first status (the sessions' and links' follows
    /// at once from [`keep_alive`]).
    pub fn ready(&self, status: &str) {
        self.send(&format!("READY=1\nSTATUS={status}"));
    }

    /// `STOPPING=1`: a signal asked lluavd to stop.
    pub fn stopping(&self) {
        self.send("STOPPING=1\nSTATUS=stopping");
    }
}

/// The socket address `NOTIFY_SOCKET` names.
fn target(path: &[u8]) -> io::Result<UnixAddr> {
    use std::os::linux::net::SocketAddrExt as _;
    use std::os::unix::ffi::OsStrExt as _;
    match path.split_first() {
        Some((b'@', name)) => UnixAddr::from_abstract_name(name),
        Some((b'/', _)) => UnixAddr::from_pathname(std::ffi::OsStr::from_bytes(path)),
        _ => Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "neither an absolute path nor @name",
        )),
    }
}

/// Half of `WATCHDOG_USEC`, unless `WATCHDOG_PID` names another process
/// (the variables were inherited) or the value is unusable.
fn watchdog_from_env() -> Option<Duration> {
    if let Some(pid) = std::env::var_os("WATCHDOG_PID")
        && pid.to_str().and_then(|p| p.parse::<u32>().ok()) != Some(std::process::id())
    {
        return None;
    }
    let usec: u64 = std::env::var("WATCHDOG_USEC").ok()?.parse().ok()?;
    (usec > 0).then(|| Duration::from_micros(usec / 2))
}

/// The state of an outside link, for `STATUS=`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Link {
    /// There is no such link (the simulator has no autopilot; no uplink
    /// configured).
    None,
    /// Connected and heard from.
    Up,
    /// Configured, but lost or not yet up.
    Down,
}

impl From<Option<bool>> for Link {
    fn from(up: Option<bool>) -> Self {
        match up {
            None => Link::None,
            Some(true) => Link::Up,
            Some(false) => Link::Down,
        }
    }
}

/// What `STATUS=` says: `3 sessions; autopilot link up; uplink down`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    /// Protocol sessions open now.
    pub sessions: usize,
    /// The autopilot's link; [`Link::None`] for the simulator.
    pub autopilot: Link,
    /// The MQTT uplink's connection to its broker; [`Link::None`] when
    /// there is no uplink.
    pub uplink: Link,
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let plural = if self.sessions == 1 { "" } else { "s" };
        write!(f, "{} session{plural}; ", self.sessions)?;
        match self.autopilot {
            Link::None => f.write_str("simulated vehicle")?,
            Link::Up => f.write_str("autopilot link up")?,
            Link::Down => f.write_str("autopilot link down")?,
        }
        match self.uplink {
            Link::None => Ok(()),
            Link::Up => f.write_str("; uplink up"),
            Link::Down => f.write_str("; uplink down"),
        }
    }
}

/// Pets the watchdog (when systemd asked for it) and sends `STATUS=` when
/// it changed, forever; `status` is read at every period on this runtime.
pub async fn keep_alive(notifier: Notifier, mut status: impl FnMut() -> Status) {
    let period = notifier.watchdog().unwrap_or(STATUS_PERIOD);
    let mut interval = tokio::time::interval(period);
    // A late tick is followed by a full period, never by a burst.
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last = None;
    loop {
        interval.tick().await;
        let now = status();
        let mut message = String::new();
        if notifier.watchdog().is_some() {
            message.push_str("WATCHDOG=1\n");
        }
        if last != Some(now) {
            message.push_str(&format!("STATUS={now}\n"));
            last = Some(now);
        }
        if !message.is_empty() {
            notifier.send(&message);
        }
    }
}

/// A [`Handler`] that counts the sessions it has open, for `STATUS=`.
pub struct Counted<H> {
    inner: H,
    open: Arc<AtomicUsize>,
}

impl<H> Counted<H> {
    /// Counts `inner`'s sessions.
    pub fn new(inner: H) -> Self {
        Counted {
            inner,
            open: Arc::new(AtomicUsize::new(0)),
        }
    }

    /// The count, shared: sessions open now.
    pub fn counter(&self) -> Arc<AtomicUsize> {
        Arc::clone(&self.open)
    }
}

impl<H: Handler> Handler for Counted<H> {
    type Session = H::Session;

    fn session(&self, peer: SocketAddr) -> Self::Session {
        self.open.fetch_add(1, Ordering::Relaxed);
        self.inner.session(peer)
    }

    fn admitted(&self, session: &Self::Session) -> bool {
        self.inner.admitted(session)
    }

    fn handle<'o>(
        &'o self,
        session: &'o mut Self::Session,
        message: Message<'o>,
        out: &'o mut [u8],
    ) -> impl Future<Output = Outcome<'o>> + Send + 'o {
        self.inner.handle(session, message, out)
    }

    fn written(&self, session: &Self::Session) {
        self.inner.written(session);
    }

    fn closed(&self, session: Self::Session) {
        self.open.fetch_sub(1, Ordering::Relaxed);
        self.inner.closed(session);
    }

    fn subscribe(&self) -> Option<crate::events::Subscriber> {
        self.inner.subscribe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_names_sessions_and_links() {
        let status = Status {
            sessions: 1,
            autopilot: Link::Up,
            uplink: Link::None,
        };
        assert_eq!(status.to_string(), "1 session; autopilot link up");
        let status = Status {
            sessions: 0,
            autopilot: Link::None,
            uplink: Link::Down,
        };
        assert_eq!(status.to_string(), "0 sessions; simulated vehicle; uplink down");
    }

    /// Discards what waits in `socket`.
    fn drain(socket: &UnixDatagram) {
        socket.set_nonblocking(true).expect("non-blocking");
        let mut buf = [0u8; 256];
        while socket.recv(&mut buf).is_ok() {}
        socket.set_nonblocking(false).expect("blocking");
    }

    /// Pets received within `window`.
    fn pets_within(socket: &UnixDatagram, window: Duration) -> usize {
        let end = std::time::Instant::now() + window;
        let mut buf = [0u8; 256];
        let mut pets = 0;
        while let Some(left) = end.checked_duration_since(std::time::Instant::now()) {
            socket
                .set_read_timeout(Some(left.max(Duration::from_millis(1))))
                .expect("timeout set");
            match socket.recv(&mut buf) {
                Ok(n) if buf[..n].starts_with(b"WATCHDOG=1") => pets += 1,
                Ok(_) => {}
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => break,
            }
        }
        pets
    }

    /// Whether `n` pets arrive within `limit` (a bound for a failing test,
    /// not a measure: a loaded machine pets late, never not at all).
    fn pets_arrive(socket: &UnixDatagram, n: usize, limit: Duration) -> bool {
        let end = std::time::Instant::now() + limit;
        let mut pets = 0;
        while pets < n {
            let Some(left) = end.checked_duration_since(std::time::Instant::now()) else {
                return false;
            };
            pets += pets_within(socket, left.min(Duration::from_millis(100)));
        }
        true
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_vehicle_lock_never_released_stops_the_petting() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("notify");
        let systemd = UnixDatagram::bind(&path).expect("bound");
        let notifier = Notifier {
            socket: Arc::new(UnixDatagram::unbound().expect("socket")),
            target: Arc::new(UnixAddr::from_pathname(&path).expect("address")),
            watchdog: Some(Duration::from_millis(20)),
        };
        let vehicle = Arc::new(std::sync::Mutex::new(()));
        // The keep-alive asks for the status (and so takes the vehicle's
        // lock) before every pet: how often it asked, and got the lock.
        let asked = Arc::new([AtomicUsize::new(0), AtomicUsize::new(0)]);
        let (locked, count) = (Arc::clone(&vehicle), Arc::clone(&asked));
        let task = tokio::spawn(keep_alive(notifier, move || {
            count[0].fetch_add(1, Ordering::SeqCst);
            let _vehicle = locked.lock();
            count[1].fetch_add(1, Ordering::SeqCst);
            Status {
                sessions: 0,
                autopilot: Link::None,
                uplink: Link::None,
            }
        }));
        let probe = systemd.try_clone().expect("clone");
        let healthy = tokio::task::spawn_blocking(move || pets_arrive(&probe, 5, Duration::from_secs(20)));
        assert!(healthy.await.expect("joined"), "petted while healthy");
        // The vehicle's lock held, as by a command that never returns.
        let probe = systemd.try_clone().expect("clone");
        let (wedge, count) = (Arc::clone(&vehicle), Arc::clone(&asked));
        let during = tokio::task::spawn_blocking(move || {
            let _held = wedge.lock();
            // Once the keep-alive waits for the lock (asked, not got), every
            // pet it sent before is in the socket (a datagram is queued when
            // sent), and none can follow while the lock is held.
            while count[0].load(Ordering::SeqCst) == count[1].load(Ordering::SeqCst) {
                std::thread::yield_now();
            }
            drain(&probe);
            // Ten watchdog periods: a keep-alive that petted on its own
            // timer would pet here.
            pets_within(&probe, Duration::from_millis(200))
        });
        assert_eq!(
            during.await.expect("joined"),
            0,
            "petted while the vehicle was wedged"
        );
        let probe = systemd.try_clone().expect("clone");
        let after = tokio::task::spawn_blocking(move || pets_arrive(&probe, 5, Duration::from_secs(20)));
        assert!(after.await.expect("joined"), "petting resumes with the vehicle");
        task.abort();
    }

    #[test]
    fn notify_socket_is_a_path_or_an_abstract_name() {
        assert!(target(b"/run/systemd/notify").is_ok());
        assert!(target(b"@lluavd-test").is_ok());
        assert!(target(b"relative").is_err());
    }
}
