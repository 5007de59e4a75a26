//! The uplink: the protocol through an MQTT broker, for vehicles behind NAT
//! and for fleets (DESIGN.md, "Uplink: vehicles behind NAT, and fleets").
//!
//! lluavd connects OUT to a broker (`--uplink mqtt://HOST` or `mqtts://`),
//! beside its WebSocket port, and serves the same protocol there: a third
//! adapter on the core. Each operator's client id is one core session,
//! opened and served through the same path as a WebSocket session
//! ([`Sessions`], which the daemon implements on its protocol handler), so
//! the same gates and the same login throttle apply, and every answer is
//! exactly the JSON a WebSocket session would get, in an envelope.
//!
//! - [`topic`]: the topic layout and the id alphabet;
//! - [`envelope`]: request and response envelopes;
//! - [`crate::json`] (shared with the mission reader): JSON that refuses
//!   members named twice;
//! - [`table`]: sessions per client id, requests in flight, and the
//!   10-minute memory of request ids that makes repeats harmless;
//! - [`durable`]: the answers of requests that change the vehicle, kept in
//!   the data directory across a restart;
//! - [`serve`]: requests through the table to the workers, answers out;
//! - [`state`]: the retained `state` topic, on change and at a rate;
//! - [`events`]: the `events` topic, every event of the bus;
//! - [`link`]: the link's state (`state.uplink`) and the reconnect backoff;
//! - [`config`]: the flags and config keys;
//! - [`fleet`]: the operator's side, for `lluav --broker`.
//!
//! Broker connection: MQTT 5 (rumqttc's `v5` client), keep-alive 10 s,
//! clean start, no session expiry. The CONNECT's Maximum Packet Size keeps
//! anything larger than a request may be away from the vehicle (the broker
//! drops it), and the subscription's Retain Handling 2 keeps retained
//! messages away. A retained `online` status on every connection and a
//! retained will saying `offline`, which lluavd also publishes itself on a
//! clean stop. The WebSocket side never waits on the broker: the uplink's
//! tasks take the vehicle's lock for one message at a time, as a WebSocket
//! session does, and never hold it across a wait for the broker.

pub mod broker;
pub mod config;
pub mod durable;
pub mod envelope;
pub mod events;
pub mod fleet;
pub mod link;
pub mod serve;
pub mod state;
pub mod table;
pub mod topic;

use std::future::Future;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use lluav_core::{Outcome, Session};
use rumqttc::Outgoing;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::{Filter, LastWill, Packet, RetainForwardRule};
use rumqttc::v5::{AsyncClient, Event, EventLoop, MqttOptions};
use tokio::sync::watch;
use tracing::{info, warn};

use crate::client::ClientError;

pub use config::{BrokerUrl, Settings, UplinkCli, UplinkKeys};
pub use link::{Status, StatusCell};

use broker::Dial;
use link::Backoff;
use serve::Shared;
use topic::Topics;

/// An opaque 16-byte key per client id, for the login throttle: a keyed
/// hash with a per-process random key.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ClientKey(pub [u8; 16]);

/// The protocol, as the uplink reaches it: the daemon's handler.
pub trait Sessions: Send + Sync + 'static {
    /// A session for client id `client` (`None`: the uplink's own), whose
    /// throttle key is `key`.
    fn open(&self, client: Option<&str>, key: ClientKey) -> Session;

    /// Answers `frame` in `session` as a WebSocket text message would be
    /// answered; never [`Outcome::Pending`].
    fn handle<'o>(
        &'o self,
        session: &'o mut Session,
        frame: &'o str,
        out: &'o mut [u8],
    ) -> impl Future<Output = Outcome<'o>> + Send + 'o;

    /// `session` has ended.
    fn close(&self, session: Session);

    /// The answer of `session`'s last request is on its way to the
    /// broker: what it caused may be told now (the events stream).
    fn answered(&self, session: lluav_core::SessionId) {
        let _ = session;
    }

    /// A subscriber of the events bus, for the `events` topic and the state
    /// on change (`None`: this protocol tells no events).
    fn events(&self) -> Option<crate::events::Subscriber> {
        None
    }

    /// Tells `event` on the events bus (the uplink's own: up and down),
    /// behind whatever events are held for answers not yet out.
    fn tell(&self, event: crate::events::Event) {
        let _ = event;
    }

    /// The whole `state` response, asked in `reporter`: a session the
    /// uplink keeps for its state topic, logged in here (with the
    /// vehicle's own password) when it must be.
    fn state(&self, reporter: &mut Session, out: &mut [u8]) -> Option<String>;
}

/// The uplink's bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// `--max-message`: the largest request envelope answered.
    pub max_message: usize,
    /// Bytes of a response buffer.
    pub response_capacity: usize,
    /// Sessions, requests in flight and remembered ids.
    pub table: table::Limits,
}

impl Limits {
    /// The vehicle's Maximum Packet Size: a request envelope of
    /// `--max-message` bytes with its topic and properties. The broker
    /// drops a larger message instead of sending it.
    pub fn max_packet(&self) -> u32 {
        u32::try_from(self.max_message.saturating_add(PACKET_ALLOWANCE)).unwrap_or(u32::MAX)
    }
}

/// What a PUBLISH may add to its payload: fixed header, topic (at most
/// `lluav/` + 64 + `/req/` + 64 bytes) and the properties a broker
/// forwards (Message Expiry, a content type, user properties).
pub const PACKET_ALLOWANCE: usize = 2048;

/// How long a clean stop waits for requests already running, and then
/// for the broker to take the `offline` status.
const STOP_GRACE: Duration = Duration::from_secs(3);

/// How often idle sessions and old request ids are swept, at most.
const SWEEP: Duration = Duration::from_secs(1);

/// Requests the connection's own queue holds (answers, state, status,
/// subscriptions): answers wait in the uplink's outbox, bounded in bytes,
/// and only a few of them here.
const QUEUE: usize = 16;

/// QoS 1 answers sent and not yet acknowledged by the broker, at most:
/// each waits in memory (Mosquitto grants 20).
const IN_FLIGHT: u16 = 32;

/// The uplink, configured and not yet running.
pub struct Uplink {
    options: MqttOptions,
    settings: Settings,
    limits: Limits,
    status: StatusCell,
    data_dir: Option<PathBuf>,
}

impl Uplink {
    /// An uplink with `settings` and `limits`, reporting its state in
    /// `status`, keeping the answers of requests that change the vehicle
    /// in `data_dir` (none: in memory only); fails on an unusable CA file.
    pub fn new(
        settings: Settings,
        limits: Limits,
        status: StatusCell,
        data_dir: Option<PathBuf>,
    ) -> Result<Uplink, ClientError> {
        let topics = Topics::new(&settings.vehicle_id);
        let client_id = settings.client_id();
        let dial = Dial {
            broker: &settings.broker,
            client_id: &client_id,
            user: settings.user.as_deref(),
            password: settings.password.as_deref(),
            cafile: settings.cafile.as_deref(),
            max_packet: limits.max_packet(),
            queue: QUEUE,
            in_flight: IN_FLIGHT,
        };
        let mut options = dial.options()?;
        let will = serde_json::json!({"vehicle": topics.vehicle(), "online": false}).to_string();
        options.set_last_will(LastWill::new(topics.status(), will, QoS::AtLeastOnce, true, None));
        Ok(Uplink {
            options,
            settings,
            limits,
            status,
            data_dir,
        })
    }

    /// The uplink's state (`up`/`down`), as `state.uplink` reports it.
    pub fn status(&self) -> &StatusCell {
        &self.status
    }

    /// Opens the store of answers in the data directory (reading what a
    /// previous run kept): before [`Uplink::run`], so that a daemon that
    /// cannot keep them does not start.
    pub fn open_store(&self) -> std::io::Result<Option<Store>> {
        let Some(dir) = &self.data_dir else {
            return Ok(None);
        };
        let window = Duration::from_millis(self.limits.table.window_ms);
        durable::Store::open(dir, window, serve::unix_ms()).map(Some)
    }

    /// Serves `sessions` through the broker until `stop` turns true, then
    /// stops cleanly: answers what is running, publishes `offline`,
    /// disconnects. `store`: what [`Uplink::open_store`] opened.
    pub async fn run<S: Sessions>(
        self,
        sessions: Arc<S>,
        store: Option<Store>,
        mut stop: watch::Receiver<bool>,
    ) {
        let topics = Topics::new(&self.settings.vehicle_id);
        let (client, events) = AsyncClient::new(self.options, QUEUE);
        let shared = Arc::new(Shared::new(
            sessions,
            client,
            topics,
            &self.limits,
            self.status.clone(),
            store,
        ));
        // Subscribed before the connection starts: its `uplink` `up` is
        // the first thing both hear of.
        let told = shared.sessions.events();
        let changes = shared.sessions.events();
        let mut tasks = vec![
            tokio::spawn(state::publish(
                Arc::clone(&shared),
                self.settings.state_hz,
                changes,
            )),
            tokio::spawn(sweep(Arc::clone(&shared))),
            tokio::spawn(serve::send(Arc::clone(&shared))),
        ];
        if let Some(told) = told {
            tasks.push(tokio::spawn(events::publish(Arc::clone(&shared), told)));
        }
        let workers: Vec<_> = (0..serve::WORKERS)
            .map(|_| tokio::spawn(serve::work(Arc::clone(&shared))))
            .collect();
        let (gone_tx, gone_rx) = watch::channel(false);
        let broker = self.settings.broker.to_string();
        let connection = tokio::spawn(connection(Arc::clone(&shared), events, broker, gone_rx));
        let _ = stop.wait_for(|stopping| *stopping).await;
        shared.stopping.store(true, Ordering::Relaxed);
        shared.wake_all();
        goodbye(&shared, connection, gone_tx).await;
        tasks.extend(workers);
        for task in tasks {
            task.abort();
        }
        set_status(&shared, Status::Down);
    }
}

/// The store of answers and what it kept of the last window.
pub type Store = (durable::Store, Vec<durable::Found>);

/// Sweeps idle sessions and old request ids when one is due (at most once
/// per [`SWEEP`]); sleeps while the table holds nothing, until a request
/// comes.
async fn sweep<S: Sessions>(shared: Arc<Shared<S>>) {
    let mut earliest = tokio::time::Instant::now();
    loop {
        let changed = shared.changed.notified();
        tokio::pin!(changed);
        changed.as_mut().enable();
        let due = shared.table().next_expiry().map(|at| {
            let wait = Duration::from_millis(at.saturating_sub(shared.now()));
            (tokio::time::Instant::now() + wait).max(earliest)
        });
        let Some(due) = due else {
            changed.await;
            continue;
        };
        tokio::select! {
            () = tokio::time::sleep_until(due) => {}
            () = changed => continue,
        }
        shared.sweep();
        earliest = tokio::time::Instant::now() + SWEEP;
    }
}

/// The clean stop: answers what is running, then `offline` (retained) and
/// a disconnect, each bounded by [`STOP_GRACE`].
async fn goodbye<S: Sessions>(
    shared: &Shared<S>,
    connection: tokio::task::JoinHandle<()>,
    gone: watch::Sender<bool>,
) {
    let deadline = Instant::now() + STOP_GRACE;
    // Answers waiting go out first, while there is a broker to take them.
    let waiting = || shared.busy() || (shared.status.get() == Status::Up && shared.outbox.bytes() > 0);
    while waiting() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    if shared.status.get() == Status::Up {
        let offline = serde_json::json!({"vehicle": shared.topics.vehicle(), "online": false}).to_string();
        let said = async {
            let topic = shared.topics.status().to_owned();
            shared
                .client
                .publish(topic, QoS::AtLeastOnce, true, offline)
                .await?;
            shared.client.disconnect().await
        };
        let _ = tokio::time::timeout(STOP_GRACE, said).await;
    }
    let _ = gone.send(true);
    let abort = connection.abort_handle();
    if tokio::time::timeout(STOP_GRACE, connection).await.is_err() {
        abort.abort();
    }
}

/// The connection's task: polls the broker connection (never cancelled
/// mid-poll), dispatches requests, and reconnects with [`Backoff`],
/// logging once per change of state. After a stop it runs until the
/// disconnect went out, or at once while the link is down.
async fn connection<S: Sessions>(
    shared: Arc<Shared<S>>,
    mut events: EventLoop,
    broker: String,
    mut gone: watch::Receiver<bool>,
) {
    let mut backoff = Backoff::default();
    let mut up_since = None;
    let mut tried = false;
    loop {
        match events.poll().await {
            Ok(Event::Incoming(Packet::ConnAck(connack))) => {
                up_since = Some(Instant::now());
                let max = connack.properties.and_then(|p| p.max_packet_size).unwrap_or(0);
                shared.broker_max.store(max, Ordering::Relaxed);
                if set_status(&shared, Status::Up) != Status::Up {
                    info!(%broker, vehicle = shared.topics.vehicle(), "uplink up");
                }
                tokio::spawn(announce(Arc::clone(&shared)));
            }
            Ok(Event::Incoming(Packet::Publish(publish))) => shared.dispatch(&publish),
            Ok(Event::Outgoing(Outgoing::Disconnect)) if *gone.borrow() => return,
            Ok(_) => {}
            Err(e) => {
                if *gone.borrow() {
                    return;
                }
                let was = set_status(&shared, Status::Down);
                if was == Status::Up || !tried {
                    warn!(%broker, error = %e, "uplink down; reconnecting with backoff (0.5 s to 30 s)");
                }
                tried = true;
                // A connection that held for a while starts the backoff
                // over; one that keeps dropping at once does not.
                if up_since.take().is_some_and(|t| t.elapsed() >= broker::KEEP_ALIVE) {
                    backoff.reset();
                }
                tokio::select! {
                    () = tokio::time::sleep(backoff.delay()) => {}
                    _ = gone.wait_for(|g| *g) => return,
                }
            }
        }
    }
}

/// Sets the link's state and tells a change between up and down on the
/// events bus; returns the state it replaces.
fn set_status<S: Sessions>(shared: &Shared<S>, status: Status) -> Status {
    let was = shared.status.set(status);
    if (was == Status::Up) != (status == Status::Up) {
        shared.sessions.tell(crate::events::Event::Uplink {
            up: status == Status::Up,
        });
    }
    was
}

/// After every (re)connection: subscribe to this vehicle's requests and
/// say it is online (retained). Clean start: the broker kept nothing.
async fn announce<S: Sessions>(shared: Arc<Shared<S>>) {
    let topics = &shared.topics;
    let online = serde_json::json!({
        "vehicle": topics.vehicle(),
        "online": true,
        "version": env!("CARGO_PKG_VERSION"),
        "ts": serve::unix_ms(),
    })
    .to_string();
    // Requests only live: no retained message is sent on subscribing
    // (Retain Handling 2), and nothing the vehicle sends comes back.
    let requests = Filter {
        path: topics.request_filter(),
        qos: QoS::AtLeastOnce,
        nolocal: true,
        preserve_retain: false,
        retain_forward_rule: RetainForwardRule::Never,
    };
    let _ = shared.client.subscribe_many([requests]).await;
    let _ = shared
        .client
        .publish(topics.status().to_owned(), QoS::AtLeastOnce, true, online)
        .await;
}
