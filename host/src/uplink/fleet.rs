//! The operator's side of the uplink: vehicles reached through a broker,
//! for `lluav --broker` (DESIGN.md, "Uplink").
//!
//! A [`Fleet`] is one MQTT connection with one client id, so one session
//! on each vehicle it talks to. It follows every vehicle's retained
//! `status` and `state`, and sends requests in envelopes with ids of its
//! own; an answer is matched by id, so a late one can never be taken for
//! another's.
//!
//! ```no_run
//! # async fn demo() -> Result<(), lluav_host::uplink::fleet::FleetError> {
//! use std::time::Duration;
//! use lluav_host::uplink::fleet::{Fleet, FleetOptions};
//! let fleet = Fleet::connect("mqtt://127.0.0.1", &FleetOptions::default()).await?;
//! for v in fleet.vehicles().await {
//!     println!("{} online={:?}", v.id, v.online);
//! }
//! let state = fleet.request("drone-1", "state", Duration::from_secs(5)).await?;
//! println!("{}", state.to_json());
//! # Ok(()) }
//! ```

use std::collections::{BTreeMap, HashMap};
use std::hash::{BuildHasher, RandomState};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use rumqttc::Outgoing;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::{Filter, Packet, Publish};
use rumqttc::v5::{AsyncClient, Event, EventLoop};
use serde_json::{Value, json};
use tokio::sync::oneshot;

use super::broker::Dial;
use super::config::BrokerUrl;
use super::serve::unix_ms;
use super::topic::{self, Topics, valid_name};
use crate::client::{ClientError, Response};
use crate::json;
use crate::terminal;

/// How long the first listing waits for the retained messages at most.
pub const LISTING_WAIT: Duration = Duration::from_secs(1);

/// Retained messages come in a burst after the subscription is granted:
/// once none came for this long, the listing is complete.
const LISTING_QUIET: Duration = Duration::from_millis(150);

/// How long [`Fleet::events`] waits for its subscription's grant at most.
const SUBSCRIBE_WAIT: Duration = Duration::from_secs(5);

/// How a [`Fleet`] connects.
#[derive(Clone, Debug, Default)]
pub struct FleetOptions {
    /// The client id (1-64 of `[A-Za-z0-9_-]`); default: the user name
    /// when one is given (the broker account is the identity: with the
    /// recommended broker config the broker makes it so), else
    /// `lluav-<random>`.
    pub client_id: Option<String>,
    /// User name at the broker.
    pub user: Option<String>,
    /// Password at the broker.
    pub password: Option<String>,
    /// CA certificates for `mqtts://` instead of the system's.
    pub cafile: Option<PathBuf>,
}

/// What went wrong reaching a vehicle through the broker.
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    /// The broker URL or client id is unusable.
    #[error("{0}")]
    Usage(String),
    /// The CA file cannot be used.
    #[error(transparent)]
    Tls(#[from] ClientError),
    /// The broker could not be reached or refused the connection.
    #[error("cannot connect to the broker {url}: {why}")]
    Connect {
        /// The broker.
        url: String,
        /// Why.
        why: String,
    },
    /// The connection to the broker was lost.
    #[error("the connection to the broker was lost: {0}")]
    Lost(String),
    /// No answer within the timeout, from a vehicle not known to be online.
    #[error("vehicle {0} is offline")]
    Offline(String),
    /// No answer within the timeout from a vehicle that says it is online.
    #[error("vehicle {0} did not answer within {1:?}")]
    NoAnswer(String, Duration),
    /// The vehicle answered something that is not a protocol response.
    #[error("vehicle {vehicle} answered something that is not a protocol response: {text}")]
    BadAnswer {
        /// The vehicle.
        vehicle: String,
        /// What it sent.
        text: String,
    },
}

/// One vehicle as the fleet last heard of it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VehicleInfo {
    /// Its id.
    pub id: String,
    /// Its retained status; `None` if it never published one.
    pub online: Option<bool>,
    /// Its latest `state` response.
    pub state: Option<Value>,
    /// Seconds since that state was read on the vehicle (by its `ts`).
    pub age_s: Option<f64>,
}

impl VehicleInfo {
    /// `{"online": bool, "state": ... or null, "age_s": ... or null}`, as
    /// `lluav --broker URL fleet --json` prints per vehicle.
    pub fn to_json(&self) -> Value {
        json!({"online": self.online == Some(true), "state": self.state, "age_s": self.age_s})
    }

    /// A row of the fleet table: id, online, fsm, armed, battery,
    /// position, age; what the vehicle wrote is escaped for a terminal.
    pub fn row(&self) -> [String; 7] {
        let s = self.state.as_ref().map(|r| &r["state"]);
        let field = |key: &str| s.map(|s| &s[key]).filter(|v| !v.is_null());
        let text = |v: Option<&Value>| match v {
            Some(Value::String(s)) => terminal::escape(s).into_owned(),
            Some(v) => terminal::escape(&v.to_string()).into_owned(),
            None => "-".to_owned(),
        };
        let battery = field("battery")
            .and_then(Value::as_f64)
            .map_or("-".into(), |b| format!("{b:.0}%"));
        let position = field("position").map_or("-".into(), |p| {
            let c = |k: &str| p[k].as_f64().map_or("?".into(), |v| format!("{v:.1}"));
            format!("{},{},{}", c("x"), c("y"), c("z"))
        });
        let online = match self.online {
            Some(true) => "yes",
            Some(false) => "no",
            None => "?",
        };
        let age = self.age_s.map_or("-".into(), |a| format!("{a:.1}s"));
        [
            self.id.clone(),
            online.into(),
            text(field("fsm")),
            text(field("armed")),
            battery,
            position,
            age,
        ]
    }
}

/// The fleet as a table with a header, one vehicle per line.
pub fn table(vehicles: &[VehicleInfo]) -> String {
    let header = ["VEHICLE", "ONLINE", "FSM", "ARMED", "BATTERY", "POSITION", "AGE"].map(String::from);
    let rows: Vec<[String; 7]> = std::iter::once(header)
        .chain(vehicles.iter().map(VehicleInfo::row))
        .collect();
    let widths: Vec<usize> = (0..7)
        .map(|i| rows.iter().map(|r| r[i].chars().count()).max().unwrap_or(0))
        .collect();
    let mut out = String::new();
    for row in rows {
        let cells: Vec<String> = row
            .iter()
            .zip(&widths)
            .map(|(cell, w)| format!("{cell:w$}"))
            .collect();
        out.push_str(cells.join("  ").trim_end());
        out.push('\n');
    }
    out
}

#[derive(Default)]
struct Heard {
    online: Option<bool>,
    state: Option<Value>,
}

/// What the connection's task shares with the callers.
#[derive(Default)]
struct Inner {
    waiting: HashMap<String, oneshot::Sender<Value>>,
    vehicles: BTreeMap<String, Heard>,
    /// Why the link is down, while it is.
    down: Option<String>,
    /// When the subscriptions were granted, and the last retained message.
    granted: Option<Instant>,
    last_retained: Option<Instant>,
    /// The events filter subscribed to by [`Fleet::events`], and where its
    /// events go: `(vehicle, event)`.
    events: Option<(String, tokio::sync::mpsc::UnboundedSender<(String, Value)>)>,
    /// Subscribe requests sent and granted (the broker answers them in
    /// order): [`Fleet::events`] returns once its own is granted.
    subscribes: u64,
    granted_count: u64,
}

/// Vehicles reached through one broker connection.
pub struct Fleet {
    client: AsyncClient,
    client_id: String,
    inner: Arc<Mutex<Inner>>,
    task: tokio::task::JoinHandle<()>,
    nonce: u64,
    next: AtomicU64,
    listed: std::sync::atomic::AtomicBool,
}

impl Fleet {
    /// Connects to `url` (`mqtt://HOST[:PORT]`, `mqtts://HOST[:PORT]`) and
    /// follows every vehicle's status and state.
    pub async fn connect(url: &str, options: &FleetOptions) -> Result<Fleet, FleetError> {
        let broker: BrokerUrl = url
            .parse()
            .map_err(|e| FleetError::Usage(format!("{e}: {url}")))?;
        let client_id = match &options.client_id {
            Some(id) if valid_name(id) => id.clone(),
            Some(id) => {
                return Err(FleetError::Usage(format!(
                    "client id {id:?} is not 1-64 of [A-Za-z0-9_-]"
                )));
            }
            None => match &options.user {
                Some(user) if valid_name(user) => user.clone(),
                Some(user) => {
                    return Err(FleetError::Usage(format!(
                        "the client id defaults to the broker user name, and {user:?} is not 1-64 of \
                         [A-Za-z0-9_-]: give one with --client-id"
                    )));
                }
                None => default_client_id(),
            },
        };
        let dial = Dial {
            broker: &broker,
            client_id: &client_id,
            user: options.user.as_deref(),
            password: options.password.as_deref(),
            cafile: options.cafile.as_deref(),
            max_packet: MAX_PACKET,
            queue: 256,
            in_flight: 64,
        };
        let (client, mut events) = AsyncClient::new(dial.options()?, 256);
        // The first connection is the caller's to wait for: a wrong URL or
        // password fails here, not at the first request.
        match events.poll().await {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {}
            Ok(other) => {
                return Err(FleetError::Connect {
                    url: broker.to_string(),
                    why: format!("{other:?}"),
                });
            }
            Err(e) => {
                return Err(FleetError::Connect {
                    url: broker.to_string(),
                    why: e.to_string(),
                });
            }
        }
        // Queued before any request, so the broker grants them first.
        client
            .subscribe_many(filters(&client_id))
            .await
            .map_err(|e| FleetError::Lost(e.to_string()))?;
        let inner = Arc::new(Mutex::new(Inner {
            subscribes: 1,
            ..Inner::default()
        }));
        let task = tokio::spawn(follow(
            events,
            client.clone(),
            client_id.clone(),
            Arc::clone(&inner),
        ));
        Ok(Fleet {
            client,
            client_id,
            inner,
            task,
            nonce: RandomState::new().hash_one(unix_ms()),
            next: AtomicU64::new(0),
            listed: Default::default(),
        })
    }

    /// This fleet's client id.
    pub fn client_id(&self) -> &str {
        &self.client_id
    }

    fn inner(&self) -> MutexGuard<'_, Inner> {
        lock(&self.inner)
    }

    /// Every vehicle heard of, by id. The first call waits (at most
    /// [`LISTING_WAIT`]) for the retained statuses and states.
    pub async fn vehicles(&self) -> Vec<VehicleInfo> {
        if !self.listed.swap(true, Ordering::Relaxed) {
            let start = Instant::now();
            while start.elapsed() < LISTING_WAIT {
                let settled = {
                    let inner = self.inner();
                    let quiet_since = inner.last_retained.max(inner.granted);
                    inner.granted.is_some() && quiet_since.is_some_and(|t| t.elapsed() >= LISTING_QUIET)
                };
                if settled {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        }
        let now = unix_ms();
        self.inner()
            .vehicles
            .iter()
            .map(|(id, heard)| VehicleInfo {
                id: id.clone(),
                online: heard.online,
                age_s: heard
                    .state
                    .as_ref()
                    .and_then(|s| s["ts"].as_i64())
                    .map(|ts| (now.saturating_sub(ts).max(0) as f64) / 1000.0),
                state: heard.state.clone(),
            })
            .collect()
    }

    /// Sends `frame` to `vehicle` and waits up to `timeout` for its answer.
    pub async fn request(
        &self,
        vehicle: &str,
        frame: &str,
        timeout: Duration,
    ) -> Result<Response, FleetError> {
        if !valid_name(vehicle) {
            return Err(FleetError::Usage(format!(
                "vehicle id {vehicle:?} is not 1-64 of [A-Za-z0-9_-]"
            )));
        }
        let id = format!("{:x}-{}", self.nonce, self.next.fetch_add(1, Ordering::Relaxed));
        let (tx, rx) = oneshot::channel();
        {
            let mut inner = self.inner();
            if let Some(why) = &inner.down {
                return Err(FleetError::Lost(why.clone()));
            }
            inner.waiting.insert(id.clone(), tx);
        }
        let envelope = json!({"id": id, "frame": frame}).to_string();
        let topic = Topics::new(vehicle).request(&self.client_id);
        let sent = self
            .client
            .publish(topic, QoS::AtLeastOnce, false, envelope.into_bytes())
            .await;
        let answer = match sent {
            Ok(()) => tokio::time::timeout(timeout, rx).await,
            Err(e) => {
                self.inner().waiting.remove(&id);
                return Err(FleetError::Lost(e.to_string()));
            }
        };
        match answer {
            Ok(Ok(response)) => serde_json::from_value(response.clone()).map_err(|_| FleetError::BadAnswer {
                vehicle: vehicle.to_owned(),
                text: response.to_string(),
            }),
            Ok(Err(_)) => Err(FleetError::Lost(self.inner().down.clone().unwrap_or_default())),
            Err(_) => {
                let mut inner = self.inner();
                inner.waiting.remove(&id);
                if inner.vehicles.get(vehicle).and_then(|h| h.online) == Some(true) {
                    Err(FleetError::NoAnswer(vehicle.to_owned(), timeout))
                } else {
                    Err(FleetError::Offline(vehicle.to_owned()))
                }
            }
        }
    }

    /// Follows the events of `vehicle`, or of every vehicle (`lluav/V/events`
    /// or `lluav/+/events`, DESIGN.md "Events"): each comes as `(vehicle,
    /// event object)` in the order the broker delivers them (QoS 1). A
    /// message that is not a JSON object is skipped. The subscription is
    /// made again after a reconnection; what was published while the
    /// connection was down is not delivered (a clean session): `seq` shows
    /// the hole. A second call replaces the first one's subscription.
    pub async fn events(
        &self,
        vehicle: Option<&str>,
    ) -> Result<tokio::sync::mpsc::UnboundedReceiver<(String, Value)>, FleetError> {
        let filter = match vehicle {
            Some(v) if !valid_name(v) => {
                return Err(FleetError::Usage(format!(
                    "vehicle id {v:?} is not 1-64 of [A-Za-z0-9_-]"
                )));
            }
            Some(v) => Topics::new(v).events().to_owned(),
            None => topic::every_vehicle("events"),
        };
        let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
        let (old, mine) = {
            let mut inner = self.inner();
            inner.subscribes += 1;
            (inner.events.replace((filter.clone(), tx)), inner.subscribes)
        };
        if let Some((old, _)) = old
            && old != filter
        {
            let _ = self.client.unsubscribe(old).await;
        }
        self.client
            .subscribe(filter, QoS::AtLeastOnce)
            .await
            .map_err(|e| FleetError::Lost(e.to_string()))?;
        // Events published once this returns are delivered: wait for the
        // grant (bounded: a broker that never grants still gets us going).
        let start = Instant::now();
        while self.inner().granted_count < mine && start.elapsed() < SUBSCRIBE_WAIT {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        Ok(rx)
    }

    /// Disconnects from the broker.
    pub async fn close(self) {
        let _ = self.client.disconnect().await;
        let _ = tokio::time::timeout(Duration::from_secs(2), self.task).await;
    }
}

fn lock(inner: &Mutex<Inner>) -> MutexGuard<'_, Inner> {
    inner.lock().unwrap_or_else(PoisonError::into_inner)
}

/// `lluav-<random>`: a client id for a broker without accounts.
fn default_client_id() -> String {
    let random = RandomState::new().hash_one(unix_ms()) & 0xffff_ffff;
    format!("lluav-{random:08x}")
}

/// The largest message a fleet takes: answers are at most a response
/// buffer (64 KiB); the broker drops anything larger rather than send it.
const MAX_PACKET: u32 = 1 << 20;

/// What a fleet subscribes to: its answers, every vehicle's status and
/// state (their retained messages included).
fn filters(client_id: &str) -> [Filter; 3] {
    [
        format!("{}/+/res/{client_id}", topic::ROOT),
        topic::every_vehicle("status"),
        topic::every_vehicle("state"),
    ]
    .map(|path| Filter::new(path, QoS::AtLeastOnce))
}

/// Subscribes again after a reconnection (the session is clean), the
/// events filter of [`Fleet::events`] too.
fn subscribe(client: &AsyncClient, client_id: &str, events: Option<String>) {
    let client = client.clone();
    let mut filters = filters(client_id).to_vec();
    filters.extend(events.map(|path| Filter::new(path, QoS::AtLeastOnce)));
    tokio::spawn(async move {
        let _ = client.subscribe_many(filters).await;
    });
}

/// The connection's task: answers to their callers, statuses and states
/// into the listing; on a lost connection, every caller waiting is told,
/// and the connection is dialled again with backoff.
async fn follow(mut events: EventLoop, client: AsyncClient, client_id: String, inner: Arc<Mutex<Inner>>) {
    let mut backoff = super::link::Backoff::default();
    loop {
        match events.poll().await {
            Ok(Event::Incoming(Packet::Publish(p))) => heard(&inner, &p),
            Ok(Event::Incoming(Packet::SubAck(_))) => {
                let mut inner = lock(&inner);
                inner.granted = Some(Instant::now());
                inner.granted_count += 1;
            }
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                let events = {
                    let mut inner = lock(&inner);
                    inner.down = None;
                    inner.subscribes += 1;
                    inner.events.as_ref().map(|(filter, _)| filter.clone())
                };
                backoff.reset();
                subscribe(&client, &client_id, events);
            }
            Ok(Event::Outgoing(Outgoing::Disconnect)) => return,
            Ok(_) => {}
            Err(e) => {
                {
                    let mut inner = lock(&inner);
                    inner.down = Some(e.to_string());
                    // Dropping the senders fails every request waiting.
                    inner.waiting.clear();
                }
                tokio::time::sleep(backoff.delay()).await;
            }
        }
    }
}

/// Files one message from the broker; JSON with a member named twice is
/// no message (which of the two would be the vehicle's word?).
fn heard(inner: &Mutex<Inner>, p: &Publish) {
    let Some((vehicle, kind)) = std::str::from_utf8(&p.topic).ok().and_then(topic::split_vehicle) else {
        return;
    };
    let Some(value) = json::unique(&p.payload) else {
        return;
    };
    let mut inner = lock(inner);
    match kind {
        "status" => {
            inner.vehicles.entry(vehicle.to_owned()).or_default().online = value["online"].as_bool();
        }
        "state" => inner.vehicles.entry(vehicle.to_owned()).or_default().state = Some(value),
        "events" => {
            if value.is_object()
                && let Some((_, tx)) = &inner.events
            {
                let _ = tx.send((vehicle.to_owned(), value));
            }
            return;
        }
        _ if kind.starts_with("res/") => {
            let waiter = value["id"].as_str().and_then(|id| inner.waiting.remove(id));
            if let Some(tx) = waiter {
                let _ = tx.send(value["response"].clone());
            }
            return;
        }
        _ => return,
    }
    if p.retain {
        inner.last_retained = Some(Instant::now());
    }
}
