//! `lluavd` put together: the companion computer and a vehicle (the
//! simulator, or an autopilot over MAVLink) composed into an [`Onboard`]
//! behind lluav-core's [`Server`], served over [`crate::net`], ticked on a
//! timer, flushed at shutdown.
//!
//! The daemon holds one `Server` for the vehicle behind a mutex. Critical
//! sections are one [`Server::handle`] call per frame and one tick per
//! [`TICK`]; no protocol logic lives here.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, TryLockError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use lluav_core::throttle::{DEFAULT_MAX_LOCKOUT_MS, Slot, Throttle};
use lluav_core::{Auth, AuthError, Clock, Failure, Message, Outcome, Peer, Server, Session, Via};
use tokio::net::TcpListener;
use tokio::runtime::{Handle, RuntimeFlavor};
use tokio::sync::{Notify, watch};
use tracing::{error, info, warn};

use crate::companion::{self, Companion, CompanionConfig, UplinkReport};
use crate::config::{Settings, TlsFiles};
use crate::console;
use crate::events::{Bus, Event, Outbox};
use crate::mavlink::{MavlinkConfig, MavlinkVehicle};
use crate::net::{self, Echo, Handler};
use crate::notify::{self, Counted, Notifier, Status};
use crate::onboard::Onboard;
use crate::recent_log::{RecentLog, Warning};
use crate::sim::{SimConfig, Simulator};
use crate::uplink::{self, StatusCell, Uplink};
use crate::vehicle::{Vehicle, Wait};

pub use crate::vehicle::TICK;

/// Attempts to take a contended vehicle lock before waiting for it off the
/// worker: a few microseconds, several times a typical critical section.
const LOCK_SPINS: u32 = 256;

/// `ts` from the system clock.
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn unix_ms(&self) -> i64 {
        // A clock before 1970 is answered as 0 rather than refused: `ts` is
        // informational and the command itself must still run.
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
    }
}

/// The login throttle's table: as many records as `--login-addresses`.
pub type LoginTable = Box<[Slot]>;

/// The protocol server of the companion computer and vehicle `V`.
pub type OnboardServer<V> = Server<Onboard<V>, SystemClock, LoginTable>;

/// The protocol server, shared by every connection.
pub type Shared<V> = Arc<Mutex<OnboardServer<V>>>;

fn lock<V>(server: &Mutex<OnboardServer<V>>) -> MutexGuard<'_, OnboardServer<V>> {
    // The core never panics on input and the simulator catches its own
    // panics, so a poisoned lock means a bug elsewhere; the vehicle state
    // is still the best there is, so keep serving it.
    server.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The protocol handler: every message goes through [`Server::handle`];
/// what it changed goes out as events once its answer is written.
pub struct Protocol<V> {
    server: Shared<V>,
    outbox: Arc<Outbox>,
    /// Wakes the ticker: a command may have set the vehicle moving.
    wake: Arc<Notify>,
}

impl<V> Protocol<V> {
    /// A handler serving `server`, telling what happens through `outbox`
    /// and waking the ticker through `wake` after every command.
    pub fn new(server: Shared<V>, outbox: Arc<Outbox>, wake: Arc<Notify>) -> Self {
        Protocol { server, outbox, wake }
    }
}

/// Who holds control, as far as telling its changes goes.
fn pilot<V: Vehicle>(server: &OnboardServer<V>) -> Option<(lluav_core::SessionId, i64, String)> {
    server
        .control()
        .pilot()
        .map(|p| (p.session(), p.since_ms(), p.label().to_owned()))
}

/// Runs `f` on `server` and returns what it changed, as events: control
/// passing (compared before and after) and what the vehicle told.
pub(crate) fn observed<V: Vehicle, R>(
    server: &mut OnboardServer<V>,
    f: impl FnOnce(&mut OnboardServer<V>) -> R,
) -> (R, Vec<Event>) {
    let before = pilot(server);
    let r = f(server);
    let after = pilot(server);
    let mut events = Vec::new();
    if before.as_ref().map(|p| (p.0, p.1)) != after.as_ref().map(|p| (p.0, p.1)) {
        // DESIGN: a take-over is logged; so is every other change of who
        // flies, for whoever reads the log after a flight.
        info!(
            by = after.as_ref().map_or("free", |p| p.2.as_str()),
            from = before.as_ref().map_or("free", |p| p.2.as_str()),
            "control changed"
        );
        events.push(Event::Control {
            by: after.map(|p| p.2),
            from: before.map(|p| p.2),
        });
    }
    server.backend_mut().drain_events(&mut events);
    (r, events)
}

impl<V: Vehicle> Protocol<V> {
    /// Runs `f` on the server, locked.
    fn locked<R>(&self, f: impl FnOnce(&mut OnboardServer<V>) -> R) -> R {
        // The common case, a free lock, runs right here: handing the worker
        // to another thread for every frame (block_in_place) cost more than
        // the frame itself (the load bench's profile: most of lluavd's CPU
        // in futex wake-ups and sched_yield). A command that touches the
        // disk (save_param fsyncs) then blocks this worker for that long;
        // tokio's other workers steal its queued connections meanwhile.
        // Another frame or the tick holds the lock for a microsecond or
        // so: spin briefly rather than hand the worker over at once, since
        // the hand-off wakes another thread, many times that long.
        for _ in 0..LOCK_SPINS {
            match self.server.try_lock() {
                Ok(mut server) => return f(&mut server),
                Err(TryLockError::Poisoned(p)) => return f(&mut p.into_inner()),
                Err(TryLockError::WouldBlock) => std::hint::spin_loop(),
            }
        }
        // Still held, perhaps by a slow command: wait off the worker so its
        // other connections keep moving.
        let multi_thread =
            Handle::try_current().is_ok_and(|h| h.runtime_flavor() == RuntimeFlavor::MultiThread);
        if multi_thread {
            tokio::task::block_in_place(move || f(&mut lock(&self.server)))
        } else {
            f(&mut lock(&self.server))
        }
    }
}

impl<V: Vehicle> Handler for Protocol<V> {
    type Session = Session;

    fn session(&self, peer: SocketAddr) -> Session {
        let addr = peer.to_string();
        self.locked(|server| server.open_via(Some(peer.ip().into()), Via::WebSocket(&addr)))
    }

    async fn handle<'o>(
        &'o self,
        session: &'o mut Session,
        message: Message<'o>,
        out: &'o mut [u8],
    ) -> Outcome<'o> {
        let hold = Some(session.id().0);
        let (mut outcome, mut wait) = self.locked(|server| {
            // A vehicle left alone while idle is brought up to now first.
            server.backend_mut().advance_to(Instant::now());
            let ((outcome, wait), events) = observed(server, |server| {
                let outcome = server.handle(session, message, out);
                let wait = take_wait(server, &outcome);
                (outcome, wait)
            });
            self.outbox.stage(hold, events, SystemClock.unix_ms());
            (outcome, wait)
        });
        self.wake.notify_one();
        // The vehicle waits for something outside (an autopilot's ACK):
        // wait with the lock released, so other sessions go on; the reply
        // goes back in and out as the response in one critical section.
        while let Outcome::Pending(ticket, buf) = outcome {
            let reply = match wait.take() {
                Some(wait) => wait.await,
                None => Box::new(|_: &mut lluav_core::Fields<'_>| Err(Failure::unhandled())),
            };
            (outcome, wait) = self.locked(|server| {
                let ((outcome, wait), events) = observed(server, |server| {
                    server.backend_mut().arrive(ticket, reply);
                    let outcome = server.resume(session, buf);
                    let wait = take_wait(server, &outcome);
                    (outcome, wait)
                });
                self.outbox.stage(hold, events, SystemClock.unix_ms());
                (outcome, wait)
            });
        }
        outcome
    }

    fn admitted(&self, session: &Session) -> bool {
        session.logged_in() || !self.locked(|server| server.auth().password_required())
    }

    fn written(&self, session: &Session) {
        self.outbox.release(session.id().0);
    }

    fn closed(&self, session: Session) {
        self.locked(|server| {
            let ((), events) = observed(server, |server| server.close(&session));
            self.outbox.stage(None, events, SystemClock.unix_ms());
        });
        // Answers it never wrote hold nothing back any longer.
        self.outbox.release(session.id().0);
    }

    fn subscribe(&self) -> Option<crate::events::Subscriber> {
        Some(self.outbox.bus().subscribe())
    }
}

impl<V: Vehicle> uplink::Sessions for Protocol<V> {
    fn open(&self, client: Option<&str>, key: uplink::ClientKey) -> Session {
        let via = client.map_or(Via::Local, Via::Uplink);
        self.locked(|server| server.open_via(Some(Peer::Client(key.0)), via))
    }

    fn handle<'o>(
        &'o self,
        session: &'o mut Session,
        frame: &'o str,
        out: &'o mut [u8],
    ) -> impl Future<Output = Outcome<'o>> + Send + 'o {
        Handler::handle(self, session, Message::Text(frame.as_bytes()), out)
    }

    fn close(&self, session: Session) {
        Handler::closed(self, session);
    }

    fn answered(&self, session: lluav_core::SessionId) {
        self.outbox.release(session.0);
    }

    fn events(&self) -> Option<crate::events::Subscriber> {
        Some(self.outbox.bus().subscribe())
    }

    fn tell(&self, event: Event) {
        self.outbox.stage(None, [event], SystemClock.unix_ms());
    }

    fn state(&self, reporter: &mut Session, out: &mut [u8]) -> Option<String> {
        self.locked(|server| {
            // The state topic is for whoever the broker lets read it: the
            // uplink asks in a session of its own, logged in with the
            // vehicle's password (never a wrong one).
            if !reporter.logged_in()
                && let Some(password) = server.auth().password().map(str::to_owned)
            {
                let now = SystemClock.unix_ms();
                server.auth_mut().login(reporter, &password, now);
            }
            server
                .handle(reporter, Message::Text(b"state"), out)
                .reply()
                .map(str::to_owned)
        })
    }
}

/// The wait of the command `outcome` left pending, if it did.
fn take_wait<V: Vehicle>(server: &mut OnboardServer<V>, outcome: &Outcome<'_>) -> Option<Wait> {
    match outcome {
        Outcome::Pending(ticket, _) => server.backend_mut().take_wait(*ticket),
        _ => None,
    }
}

/// Why the daemon cannot start or did not stop cleanly.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    /// The data directory or the simulator's files could not be opened.
    #[error("cannot open the simulated vehicle in {dir}: {source}")]
    Open {
        /// The data directory.
        dir: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Listening beyond loopback needs a password or `--allow-no-password`.
    #[error(
        "refusing to listen on {0} without a password: anyone who can reach it could fly the vehicle. \
         Set --password (or LLUAV_PASSWORD, or `password` in the config file), \
         bind to 127.0.0.1, or pass --allow-no-password"
    )]
    NoPassword(SocketAddr),
    /// Listening beyond loopback with the public admin value needs
    /// `admin_password` or `--allow-default-admin`.
    #[error(
        "refusing to listen on {0} with the public admin login value 1025: anyone who can reach it \
         could log in as admin. Set `admin_password = \"...\"` in the config file (--config FILE), \
         bind to 127.0.0.1, or pass --allow-default-admin"
    )]
    PublicAdmin(SocketAddr),
    /// An uplink with the public admin value needs `admin_password` or
    /// `--allow-default-admin`: the broker's users are beyond loopback.
    #[error(
        "refusing to serve through the broker (--uplink) with the public admin login value 1025: anyone \
         the broker lets publish to this vehicle's requests could log in as admin. Set \
         `admin_password = \"...\"` in the config file (--config FILE), or pass --allow-default-admin"
    )]
    UplinkPublicAdmin,
    /// An uplink needs a password or `--allow-no-password`.
    #[error(
        "refusing to serve through the broker (--uplink) without a password: anyone the broker lets \
         publish to this vehicle's requests could fly it. Set --password (or LLUAV_PASSWORD, or \
         `password` in the config file), or pass --allow-no-password"
    )]
    UplinkNoPassword,
    /// The password or the special login values break the rules.
    #[error("invalid password settings: {0}")]
    Password(&'static str),
    /// The address could not be bound.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
    /// The TLS certificate or key cannot be used.
    #[error("cannot serve wss://: {0}")]
    Tls(#[from] net::tls::TlsError),
    /// Persisting state at shutdown failed.
    #[error("cannot persist the vehicle's state at shutdown: {0}")]
    Flush(std::io::Error),
    /// The uplink's CA file cannot be used.
    #[error("cannot use the uplink: {0}")]
    Uplink(crate::client::ClientError),
    /// The uplink's answers cannot be kept in the data directory.
    #[error("cannot keep the uplink's answers in {dir}: {source}")]
    UplinkStore {
        /// The directory.
        dir: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The autopilot's MAVLink link could not be opened.
    #[error("cannot open the MAVLink link {address}: {source}")]
    Mavlink {
        /// The `--mavlink` address.
        address: String,
        /// Why.
        source: std::io::Error,
    },
}

enum Mode<V> {
    Protocol(Box<OnboardServer<V>>),
    Echo,
}

/// A daemon that is listening and not yet serving.
pub struct Daemon<V> {
    listener: TcpListener,
    net: net::Config,
    mode: Mode<V>,
    notifier: Option<Notifier>,
    uplink: Option<(Uplink, Option<uplink::Store>)>,
    /// What happens goes out through here: `/events`, the uplink.
    outbox: Arc<Outbox>,
    /// The log whose warnings and errors are told as events.
    log: Option<RecentLog>,
}

/// `lluavd`'s default backend: the companion computer and the simulated
/// vehicle, both keeping their files in `companion.data_dir`; the
/// simulation runs at `speed`.
pub fn simulated(companion: CompanionConfig, speed: f64) -> std::io::Result<Onboard<Simulator>> {
    let data_dir = companion.data_dir.clone();
    let companion = Companion::open(companion)?;
    let seed = companion::machine_id().unwrap_or_else(|_| "lluav-sim".into());
    let sim = Simulator::open(SimConfig {
        data_dir,
        speed,
        seed,
    })?;
    Ok(Onboard::new(companion, sim))
}

impl Daemon<Simulator> {
    /// Opens the companion computer and the simulated vehicle (unless
    /// `settings.echo`), decides the password and binds the listener.
    pub async fn open(settings: &Settings, log: RecentLog) -> Result<Self, DaemonError> {
        let status = StatusCell::new(settings.uplink.is_some());
        let onboard = if settings.echo {
            None
        } else {
            let companion = CompanionConfig {
                data_dir: settings.data_dir.clone(),
                log: log.clone(),
                password_pinned: settings.password.is_some(),
                uplink: Some(report(&status)),
            };
            let onboard = simulated(companion, settings.sim_speed).map_err(|source| DaemonError::Open {
                dir: settings.data_dir.clone(),
                source,
            })?;
            Some(onboard)
        };
        Daemon::with_vehicle(settings, onboard)
            .await?
            .telling(log)
            .uplinked(settings, status)
    }
}

impl Daemon<MavlinkVehicle> {
    /// Opens the companion computer and the MAVLink link to the autopilot
    /// at `address`, decides the password and binds the listener.
    pub async fn open_mavlink(
        settings: &Settings,
        log: RecentLog,
        address: &str,
    ) -> Result<Self, DaemonError> {
        let status = StatusCell::new(settings.uplink.is_some());
        let companion = Companion::open(CompanionConfig {
            data_dir: settings.data_dir.clone(),
            log: log.clone(),
            password_pinned: settings.password.is_some(),
            uplink: Some(report(&status)),
        })
        .map_err(|source| DaemonError::Open {
            dir: settings.data_dir.clone(),
            source,
        })?;
        let cfg = MavlinkConfig {
            wanted: settings.mavlink_system,
            signing: settings.mavlink_signing_key.as_ref().map(|k| k.key.clone()),
            limits: settings.mavlink_limits,
            ..MavlinkConfig::new(address)
        };
        let vehicle =
            MavlinkVehicle::open(cfg, SystemClock)
                .await
                .map_err(|source| DaemonError::Mavlink {
                    address: address.to_owned(),
                    source,
                })?;
        Daemon::with_vehicle(settings, Some(Onboard::new(companion, vehicle)))
            .await?
            .telling(log)
            .uplinked(settings, status)
    }
}

impl<V: Vehicle> Daemon<V> {
    /// A daemon serving `onboard`, or the echo handler when it is `None`.
    pub async fn with_vehicle(settings: &Settings, vehicle: Option<Onboard<V>>) -> Result<Self, DaemonError> {
        let mode = match vehicle {
            Some(v) => {
                let mut auth = auth(settings, v.stored_password())?;
                auth.set_lock_mode(v.stored_lock_mode());
                Mode::Protocol(Box::new(Server::new(v, SystemClock, auth)))
            }
            None => Mode::Echo,
        };
        let tls = match &settings.tls {
            Some(files) => Some(tls_acceptor(settings, files)?),
            None => None,
        };
        let net = net::Config {
            limits: settings.limits,
            policy: settings.policy.clone(),
            tls,
            http: Some(console::handler(settings.console)),
        };
        let listener = TcpListener::bind(settings.bind)
            .await
            .map_err(|source| DaemonError::Bind {
                addr: settings.bind,
                source,
            })?;
        Ok(Daemon {
            listener,
            net,
            mode,
            notifier: None,
            uplink: None,
            outbox: Arc::new(Outbox::new(Bus::fresh())),
            log: None,
        })
    }

    /// Tells the warnings and errors of `log` as `log` events.
    pub fn telling(mut self, log: RecentLog) -> Self {
        self.log = Some(log);
        self
    }

    /// Adds the uplink of `settings` (not in echo mode), reporting its
    /// state in `status`.
    pub fn uplinked(mut self, settings: &Settings, status: StatusCell) -> Result<Self, DaemonError> {
        let Some(uplink) = settings.uplink.clone().filter(|_| !settings.echo) else {
            return Ok(self);
        };
        let limits = uplink::Limits {
            max_message: settings.limits.max_message,
            response_capacity: settings.limits.response_capacity,
            table: uplink::table::Limits {
                idle_ms: u64::try_from(settings.limits.idle_timeout.as_millis()).unwrap_or(u64::MAX),
                ..uplink::table::Limits::default()
            },
        };
        let uplink = Uplink::new(uplink, limits, status, Some(settings.data_dir.clone()))
            .map_err(DaemonError::Uplink)?;
        let store = uplink.open_store().map_err(|source| DaemonError::UplinkStore {
            dir: settings.data_dir.join(uplink::durable::DIR),
            source,
        })?;
        self.uplink = Some((uplink, store));
        Ok(self)
    }

    /// The address actually bound (the port, when 0 was asked for).
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    /// The URL scheme clients use: `wss` with TLS, else `ws`.
    pub fn scheme(&self) -> &'static str {
        if self.net.tls.is_some() { "wss" } else { "ws" }
    }

    /// Tells systemd about the daemon while it serves: the watchdog and
    /// `STATUS=` (see [`crate::notify`]).
    pub fn notify(mut self, notifier: Option<Notifier>) -> Self {
        self.notifier = notifier;
        self
    }

    /// Serves until `shutdown` completes, then lets connections finish and
    /// flushes the vehicle's state.
    pub async fn run(self, shutdown: impl Future<Output = ()>) -> Result<(), DaemonError> {
        let server = match self.mode {
            Mode::Echo => {
                info!("serving the echo handler (Autobahn mode)");
                net::serve(self.listener, Arc::new(Echo), self.net, shutdown).await;
                return Ok(());
            }
            Mode::Protocol(server) => Arc::new(Mutex::new(*server)),
        };
        let teller = self
            .log
            .map(|log| tokio::spawn(tell(log.tell_warnings(), Arc::clone(&self.outbox))));
        let wake = Arc::new(Notify::new());
        let ticker = tokio::spawn(tick(
            Arc::clone(&server),
            Arc::clone(&self.outbox),
            Arc::clone(&wake),
        ));
        let protocol = |server: &Shared<V>| {
            Protocol::new(Arc::clone(server), Arc::clone(&self.outbox), Arc::clone(&wake))
        };
        let handler = Arc::new(Counted::new(protocol(&server)));
        let sessions = handler.counter();
        let vehicle = Arc::clone(&server);
        let uplink_status = self.uplink.as_ref().map(|(u, _)| u.status().clone());
        let keep_alive = self.notifier.map(|notifier| {
            tokio::spawn(notify::keep_alive(notifier, move || Status {
                sessions: sessions.load(Ordering::Relaxed),
                autopilot: lock(&vehicle).backend().link_up(SystemClock.unix_ms()).into(),
                uplink: uplink_status
                    .as_ref()
                    .map(|s| s.get() == uplink::Status::Up)
                    .into(),
            }))
        });
        let (stop, stopped) = watch::channel(false);
        let uplink = self.uplink.map(|(u, store)| {
            // Sessions of its own, not counted among the connections.
            let protocol = Arc::new(protocol(&server));
            tokio::spawn(u.run(protocol, store, stopped))
        });
        let shutdown = async move {
            shutdown.await;
            let _ = stop.send(true);
        };
        net::serve(self.listener, handler, self.net, shutdown).await;
        if let Some(uplink) = uplink {
            let _ = uplink.await;
        }
        ticker.abort();
        for task in keep_alive.into_iter().chain(teller) {
            task.abort();
        }
        let flushed = tokio::task::spawn_blocking(move || {
            let mut server = lock(&server);
            server.backend_mut().stop();
            server.backend_mut().flush()
        })
        .await;
        match flushed {
            Ok(Ok(())) => {
                info!("state flushed; bye");
                Ok(())
            }
            Ok(Err(e)) => {
                error!(error = %e, "flush at shutdown failed");
                Err(DaemonError::Flush(e))
            }
            Err(join) => Err(DaemonError::Flush(std::io::Error::other(join))),
        }
    }
}

/// The login state: the configured password, else the vehicle's stored
/// one, else none — which is refused beyond loopback unless allowed, as
/// the public admin value is (the uplink counts as beyond loopback, whatever
/// `--bind` says); and the login throttle as configured.
pub(crate) fn auth(settings: &Settings, stored: Option<String>) -> Result<Auth<LoginTable>, DaemonError> {
    let password = settings.password.clone().or(stored);
    if let Some(refused) = refusal(settings, password.is_some()) {
        return Err(refused);
    }
    let lockout_ms = |d: Duration| u32::try_from(d.as_millis()).unwrap_or(u32::MAX);
    Auth::with_specials(
        password.as_deref(),
        &settings.admin_password,
        &settings.logout_password,
    )
    .map(|auth| {
        let base = lockout_ms(settings.login_lockout);
        let table = vec![Slot::EMPTY; settings.login_addresses].into_boxed_slice();
        auth.with_throttle(
            Throttle::new(base, base.max(DEFAULT_MAX_LOCKOUT_MS))
                .with_table(table)
                .with_rate(settings.login_rate),
        )
    })
    .map_err(|e| {
        DaemonError::Password(match e {
            AuthError::BadPassword => "a password must be 1-32 printable ASCII characters without spaces",
            AuthError::Ambiguous => "the password and the admin and logout values must all differ",
        })
    })
}

/// What the start-up rules refuse in `settings`, the first one in the
/// order they are checked; `password` says whether a password is known.
/// The uplink is beyond loopback whatever `--bind` says: anyone the broker
/// lets publish to the vehicle's requests reaches its login.
pub(crate) fn refusal(settings: &Settings, password: bool) -> Option<DaemonError> {
    let beyond_loopback = !settings.bind.ip().is_loopback();
    let public_admin = settings.admin_password == lluav_core::session::DEFAULT_ADMIN_PASSWORD;
    let uplink = settings.uplink.is_some();
    if !password && beyond_loopback && !settings.allow_no_password {
        Some(DaemonError::NoPassword(settings.bind))
    } else if public_admin && beyond_loopback && !settings.allow_default_admin {
        Some(DaemonError::PublicAdmin(settings.bind))
    } else if !password && uplink && !settings.allow_no_password {
        Some(DaemonError::UplinkNoPassword)
    } else if public_admin && uplink && !settings.allow_default_admin {
        Some(DaemonError::UplinkPublicAdmin)
    } else {
        None
    }
}

/// The `wss://` acceptor, refused when no client would take the
/// certificate; warns when it names nothing clients reach this daemon by.
fn tls_acceptor(settings: &Settings, files: &TlsFiles) -> Result<tokio_rustls::TlsAcceptor, DaemonError> {
    let served = net::tls::acceptor(&files.cert, &files.key, SystemTime::now())?;
    let names = net::tls::reachable_names(settings.bind.ip(), &settings.policy.hosts());
    if !served.names_any(names.iter().map(String::as_str)) {
        warn!(
            cert = %files.cert.display(),
            names = %names.join(", "),
            "the TLS certificate names none of the addresses lluavd is bound to nor any --allow-host: \
             clients will refuse it unless they reach lluavd by a name it holds"
        );
    }
    Ok(served.acceptor)
}

/// `state.uplink` read from `status`.
fn report(status: &StatusCell) -> UplinkReport {
    let status = status.clone();
    UplinkReport::new(move || status.get().as_str())
}

/// Publishes the log's warnings and errors as `log` events.
async fn tell(mut warnings: tokio::sync::mpsc::Receiver<Warning>, outbox: Arc<Outbox>) {
    while let Some(Warning { level, msg, ts }) = warnings.recv().await {
        outbox.stage(None, [Event::Log { level, msg }], ts);
    }
}

/// Advances the vehicle while it does something (as often as it asks,
/// [`Onboard::next_tick`]), tells what happened, and ends control that
/// lapsed; sleeps while nothing goes on until a command wakes it (`wake`)
/// or control is due to lapse. An idle, disarmed vehicle costs nothing.
async fn tick<V: Vehicle>(server: Shared<V>, outbox: Arc<Outbox>, wake: Arc<Notify>) {
    loop {
        let (next, lapse) = {
            let mut server = lock(&server);
            let ((), events) = observed(&mut server, |server| {
                server.backend_mut().advance_to(Instant::now());
                server.expire_control();
            });
            outbox.stage(None, events, SystemClock.unix_ms());
            let lapse = server.control_lapses_at().map(|at| {
                let ms = at.saturating_sub(SystemClock.unix_ms()).max(0);
                Duration::from_millis(u64::try_from(ms).unwrap_or(0))
            });
            (server.backend().next_tick(), lapse)
        };
        match next.into_iter().chain(lapse).min() {
            Some(wait) => {
                tokio::select! {
                    () = tokio::time::sleep(wait) => {}
                    () = wake.notified() => {}
                }
            }
            None => wake.notified().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use lluav_core::{Command, Context, Fields, SessionId};
    use tokio::sync::oneshot;

    use super::*;
    use crate::files::Files;
    use crate::vehicle::{Ned, Progress, Reply, Snapshot};

    /// A vehicle whose `takeoff` waits for the test to release it, and
    /// counts how often it is asked anything.
    struct Gated {
        release: Option<oneshot::Receiver<()>>,
        executed: Arc<AtomicUsize>,
    }

    impl Vehicle for Gated {
        fn armed(&self) -> bool {
            false
        }
        fn execute(
            &mut self,
            cmd: &Command<'_>,
            _: &Context,
            _: &Files,
            out: &mut Fields<'_>,
        ) -> Result<Progress, Failure> {
            self.executed.fetch_add(1, Ordering::SeqCst);
            if cmd.id() != lluav_core::CommandId::Takeoff {
                out.str("fsm", "ground");
                return Ok(Progress::Done);
            }
            let release = self.release.take().expect("one takeoff");
            Ok(Progress::Waiting(Box::pin(async move {
                let _ = release.await;
                let reply: Reply = Box::new(|out: &mut Fields<'_>| {
                    out.str("fsm", "takeoff");
                    Ok(())
                });
                reply
            })))
        }
        fn write_state(&self, _: &Context, state: &mut Fields<'_>) {
            state.bool("armed", false).str("fsm", "ground");
        }
        fn snapshot(&self) -> Snapshot {
            Snapshot {
                backend: "gated",
                time_s: 0.0,
                position: Ned::default(),
                yaw: 0.0,
                fsm: "ground",
                distance_m: 0.0,
            }
        }
        fn tick(&mut self, _: Duration) {}
        fn session_closed(&mut self, _: SessionId) {}
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_waiting_command_is_answered_with_its_reply_and_other_sessions_go_on_meanwhile() {
        let dir = tempfile::tempdir().unwrap();
        let companion = Companion::open(CompanionConfig {
            data_dir: dir.path().to_path_buf(),
            log: RecentLog::new(8),
            password_pinned: false,
            uplink: None,
        })
        .unwrap();
        let (release, released) = oneshot::channel();
        let executed = Arc::new(AtomicUsize::new(0));
        let vehicle = Gated {
            release: Some(released),
            executed: Arc::clone(&executed),
        };
        let server = Server::new(
            Onboard::new(companion, vehicle),
            SystemClock,
            Auth::new(None).unwrap().with_throttle(
                Throttle::new(30_000, 900_000).with_table(vec![Slot::EMPTY; 4].into_boxed_slice()),
            ),
        );
        let protocol = Arc::new(Protocol::new(
            Arc::new(Mutex::new(server)),
            Arc::new(Outbox::new(Bus::fresh())),
            Arc::new(Notify::new()),
        ));
        let peer: SocketAddr = "127.0.0.1:9".parse().unwrap();
        let waiting = {
            let protocol = Arc::clone(&protocol);
            tokio::spawn(async move {
                let mut session = protocol.session(peer);
                let mut out = vec![0u8; 1024];
                let reply = protocol
                    .handle(&mut session, Message::Text(b"takeoff"), &mut out)
                    .await;
                reply.reply().map(str::to_owned)
            })
        };
        while executed.load(Ordering::SeqCst) == 0 {
            tokio::task::yield_now().await;
        }
        let mut other = protocol.session(peer);
        let mut out = vec![0u8; 1024];
        let state = protocol
            .handle(&mut other, Message::Text(b"land"), &mut out)
            .await;
        assert!(state.reply().unwrap().contains(r#""fsm":"ground""#), "{state:?}");
        assert!(!waiting.is_finished());
        release.send(()).unwrap();
        let answer = waiting.await.unwrap().unwrap();
        assert!(
            answer.starts_with(r#"{"ret":0,"cmd":18,"#) && answer.ends_with(r#""fsm":"takeoff"}"#),
            "{answer}"
        );
        assert_eq!(
            executed.load(Ordering::SeqCst),
            2,
            "the reply is not asked of the vehicle again"
        );
    }
}
