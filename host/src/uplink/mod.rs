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
//! - [`table`]: sessions per client id, requests in flight, and the
//!   10-minute memory of request ids that makes repeats harmless;
//! - [`link`]: the link's state (`state.uplink`) and the reconnect backoff;
//! - [`config`]: the flags and config keys;
//! - [`fleet`]: the operator's side, for `lluav --broker`.
//!
//! Broker connection: MQTT 3.1.1 (rumqttc), keep-alive 10 s, clean
//! session; a retained `online` status on every connection and a retained
//! will saying `offline`, which lluavd also publishes itself on a clean
//! stop. The WebSocket side never waits on the broker: the uplink's tasks
//! take the vehicle's lock for one message at a time, as a WebSocket
//! session does, and never hold it across a wait for the broker.

pub mod broker;
pub mod config;
pub mod envelope;
pub mod fleet;
pub mod link;
pub mod serve;
pub mod state;
pub mod table;
pub mod topic;

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use lluav_core::{Outcome, Session};
use rumqttc::{AsyncClient, Event, EventLoop, LastWill, MqttOptions, Outgoing, Packet, QoS};
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

/// How long a clean stop waits for requests already running, and then
/// for the broker to take the `offline` status.
const STOP_GRACE: Duration = Duration::from_secs(3);

/// How often idle sessions and old request ids are swept.
const SWEEP: Duration = Duration::from_secs(1);

/// Requests the connection's queue holds (answers, acknowledgements,
/// state, status): room for an answer and an acknowledgement to each of
/// the messages a broker queues for one client (Mosquitto: 1000), so that
/// a burst of QoS 1 requests is answered whole. (A broker sends that
/// queue at once: it does not wait for acknowledgements.)
const QUEUE: usize = 4096;

/// The uplink, configured and not yet running.
pub struct Uplink {
    options: MqttOptions,
    settings: Settings,
    limits: Limits,
    status: StatusCell,
}

impl Uplink {
    /// An uplink with `settings` and `limits`, reporting its state in
    /// `status`; fails on an unusable CA file.
    pub fn new(settings: Settings, limits: Limits, status: StatusCell) -> Result<Uplink, ClientError> {
        let topics = Topics::new(&settings.vehicle_id);
        let client_id = format!("lluavd-{}", settings.vehicle_id);
        let dial = Dial {
            broker: &settings.broker,
            client_id: &client_id,
            user: settings.user.as_deref(),
            password: settings.password.as_deref(),
            cafile: settings.cafile.as_deref(),
            // Room for an envelope over --max-message, so that it can be
            // answered rather than cost the connection.
            max_packet: (
                limits
                    .max_message
                    .saturating_mul(2)
                    .max(limits.max_message + 4096),
                limits.response_capacity + 4096,
            ),
            queue: QUEUE,
            manual_acks: true,
        };
        let mut options = dial.options()?;
        let will = serde_json::json!({"vehicle": topics.vehicle(), "online": false}).to_string();
        options.set_last_will(LastWill::new(topics.status(), will, QoS::AtLeastOnce, true));
        Ok(Uplink {
            options,
            settings,
            limits,
            status,
        })
    }

    /// The uplink's state (`up`/`down`), as `state.uplink` reports it.
    pub fn status(&self) -> &StatusCell {
        &self.status
    }

    /// Serves `sessions` through the broker until `stop` turns true, then
    /// stops cleanly: answers what is running, publishes `offline`,
    /// disconnects.
    pub async fn run<S: Sessions>(self, sessions: Arc<S>, mut stop: watch::Receiver<bool>) {
        let topics = Topics::new(&self.settings.vehicle_id);
        let (client, mut events) = AsyncClient::new(self.options, QUEUE);
        broker::tune(&mut events);
        let shared = Arc::new(Shared::new(
            sessions,
            client,
            topics,
            &self.limits,
            self.status.clone(),
        ));
        let publisher = tokio::spawn(state::publish(Arc::clone(&shared), self.settings.state_hz));
        let sweeper = tokio::spawn(sweep(Arc::clone(&shared)));
        let (gone_tx, gone_rx) = watch::channel(false);
        let broker = self.settings.broker.to_string();
        let connection = tokio::spawn(connection(Arc::clone(&shared), events, broker, gone_rx));
        let _ = stop.wait_for(|stopping| *stopping).await;
        shared.stopping.store(true, Ordering::Relaxed);
        publisher.abort();
        sweeper.abort();
        goodbye(&shared, connection, gone_tx).await;
        shared.status.set(Status::Down);
    }
}

/// Sweeps idle sessions and old request ids.
async fn sweep<S: Sessions>(shared: Arc<Shared<S>>) {
    let mut tick = tokio::time::interval(SWEEP);
    loop {
        tick.tick().await;
        shared.sweep();
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
    while shared.busy() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    if shared.status.get() == Status::Up {
        let offline = serde_json::json!({"vehicle": shared.topics.vehicle(), "online": false}).to_string();
        let said = async {
            let topic = shared.topics.status().to_owned();
            shared
                .client
                .publish(topic, QoS::AtLeastOnce, true, offline.into_bytes())
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
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                up_since = Some(Instant::now());
                if shared.status.set(Status::Up) != Status::Up {
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
                let was = shared.status.set(Status::Down);
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

/// After every (re)connection: subscribe to this vehicle's requests and
/// say it is online (retained). Clean session: the broker kept nothing.
async fn announce<S: Sessions>(shared: Arc<Shared<S>>) {
    let topics = &shared.topics;
    let online = serde_json::json!({
        "vehicle": topics.vehicle(),
        "online": true,
        "version": env!("CARGO_PKG_VERSION"),
        "ts": serve::unix_ms(),
    })
    .to_string();
    let _ = shared
        .client
        .subscribe(topics.request_filter(), QoS::AtLeastOnce)
        .await;
    let _ = shared
        .client
        .publish(
            topics.status().to_owned(),
            QoS::AtLeastOnce,
            true,
            online.into_bytes(),
        )
        .await;
}
