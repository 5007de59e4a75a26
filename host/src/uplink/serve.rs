//! The vehicle's side: requests from the broker through the table to the
//! client's session, answers back to the broker.
//!
//! The connection's task ([`Shared::dispatch`]) never waits: it reads the
//! envelope, asks the [`Table`] what becomes of the request and either
//! answers at once (a bad envelope, a repeat, too much in flight) or
//! starts the client's worker. A worker runs one client's requests in
//! order, each through [`Sessions::handle`] (the same path a WebSocket
//! session takes), and publishes each answer; while it waits for the
//! broker to take an answer, only that client waits.

use std::collections::HashMap;
use std::fmt;
use std::hash::{BuildHasher, RandomState};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use bytes::Bytes;
use lluav_core::{Failure, Outcome, Ret, Session};
use rumqttc::{AsyncClient, Publish, QoS};
use tracing::warn;

use super::envelope;
use super::link::StatusCell;
use super::table::{Admit, Job, Table, Take};
use super::topic::{Stray, Topics};
use super::{ClientKey, Limits, Sessions};

/// How often a kind of trouble is logged.
pub const NOTE_EVERY: Duration = Duration::from_secs(60);

/// The answer when the client has too much in flight.
pub const TOO_MANY: &str = "Too many requests in flight";
/// The answer when every client slot is held.
pub const FULL: &str = "Too many clients, retry later";
/// The answer to a repeat whose stored answer was dropped.
pub const FORGOTTEN: &str = "Request id already answered; its response is no longer kept";

/// Trouble worth a log line, at most one per kind per [`NOTE_EVERY`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Trouble {
    /// A message that is not a request.
    Stray(Stray),
    /// An answer dropped because the connection's queue was full.
    Dropped,
    /// A new client refused because every slot is held.
    Full,
}

impl fmt::Display for Trouble {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Trouble::Stray(s) => s.fmt(f),
            Trouble::Dropped => {
                f.write_str("an answer was dropped: the broker does not take them fast enough")
            }
            Trouble::Full => f.write_str("a new client was refused: every client slot is held"),
        }
    }
}

/// The log's memory of trouble: when each kind was last logged and how
/// often it happened since.
#[derive(Debug, Default)]
pub struct Notes(Mutex<HashMap<Trouble, (Instant, u64)>>);

impl Notes {
    /// Logs `trouble` unless it was logged within [`NOTE_EVERY`].
    pub fn note(&self, trouble: Trouble) {
        let mut seen = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let now = Instant::now();
        match seen.get_mut(&trouble) {
            Some((at, since)) if now.duration_since(*at) < NOTE_EVERY => *since += 1,
            Some((at, since)) => {
                warn!(times = *since + 1, "uplink: {trouble}");
                (*at, *since) = (now, 0);
            }
            None => {
                warn!("uplink: {trouble}");
                seen.insert(trouble, (now, 0));
            }
        }
    }
}

/// What the uplink's tasks share.
pub struct Shared<S> {
    /// The protocol.
    pub sessions: Arc<S>,
    /// The broker connection's request queue.
    pub client: AsyncClient,
    /// This vehicle's topics.
    pub topics: Topics,
    /// Sessions and remembered requests.
    pub table: Mutex<Table>,
    /// `--max-message`.
    pub max_message: usize,
    /// Bytes of a response buffer.
    pub response_capacity: usize,
    /// The link's state.
    pub status: StatusCell,
    /// Set once the daemon stops: requests are no longer taken.
    pub stopping: AtomicBool,
    /// Rate-limited log lines.
    pub notes: Notes,
    keys: (RandomState, RandomState),
    start: Instant,
}

impl<S: Sessions> Shared<S> {
    /// What the tasks share, before any request.
    pub fn new(
        sessions: Arc<S>,
        client: AsyncClient,
        topics: Topics,
        limits: &Limits,
        status: StatusCell,
    ) -> Self {
        Shared {
            sessions,
            client,
            topics,
            table: Mutex::new(Table::new(limits.table)),
            max_message: limits.max_message,
            response_capacity: limits.response_capacity.max(lluav_core::MIN_RESPONSE_CAPACITY),
            status,
            stopping: AtomicBool::new(false),
            notes: Notes::default(),
            keys: (RandomState::new(), RandomState::new()),
            start: Instant::now(),
        }
    }

    /// Milliseconds since the uplink started: the table's clock.
    pub fn now(&self) -> u64 {
        u64::try_from(self.start.elapsed().as_millis()).unwrap_or(u64::MAX)
    }

    /// The table, locked.
    pub fn table(&self) -> MutexGuard<'_, Table> {
        self.table.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The throttle's key for `client`: a keyed hash, so that no client id
    /// can be chosen to share another's key.
    pub fn key(&self, client: &str) -> ClientKey {
        let (a, b) = (self.keys.0.hash_one(client), self.keys.1.hash_one(client));
        let mut key = [0u8; 16];
        key[..8].copy_from_slice(&a.to_be_bytes());
        key[8..].copy_from_slice(&b.to_be_bytes());
        ClientKey(key)
    }

    /// Takes one message off the broker connection, then acknowledges it;
    /// never waits.
    pub fn dispatch(self: &Arc<Self>, publish: &Publish) {
        if !self.stopping.load(Ordering::Relaxed) {
            self.take(publish);
        }
        self.acknowledge(publish);
    }

    /// Acknowledges a QoS 1 message once its request is queued or answered,
    /// not when it is read: a vehicle that stops before taking it leaves
    /// it unacknowledged.
    fn acknowledge(&self, publish: &Publish) {
        if self.client.try_ack(publish).is_err() {
            // The connection's queue is full: wait for room elsewhere (at
            // most the broker's window of these wait at once).
            let client = self.client.clone();
            let publish = publish.clone();
            tokio::spawn(async move { client.ack(&publish).await });
        }
    }

    fn take(self: &Arc<Self>, publish: &Publish) {
        let client = match self.topics.client_of(&publish.topic) {
            Ok(_) if publish.retain => Err(Stray::Retained),
            other => other,
        };
        let client = match client {
            Ok(c) => c,
            Err(stray) => return self.notes.note(Trouble::Stray(stray)),
        };
        let request = match envelope::read(&publish.payload, self.max_message) {
            Ok(r) => r,
            Err(refused) => return self.answer_now(client, envelope::refused(&refused, unix_ms()).into()),
        };
        let admit = self
            .table()
            .request(client, &request.id, &request.frame, self.now());
        let refuse = |ret: Ret, msg: &str| {
            let response = envelope::error(ret, command_id(&request.frame), unix_ms(), msg);
            envelope::response(Some(&request.id), &response).into()
        };
        match admit {
            Admit::Start => {
                tokio::spawn(work(Arc::clone(self), Arc::from(client)));
            }
            Admit::Queued | Admit::Running => {}
            Admit::Repeat(answer) => self.answer_now(client, answer),
            Admit::Forgotten => self.answer_now(client, refuse(Ret::Failed, FORGOTTEN)),
            Admit::TooMany => self.answer_now(client, refuse(Ret::Failed, TOO_MANY)),
            Admit::Full => {
                self.notes.note(Trouble::Full);
                self.answer_now(client, refuse(Ret::Failed, FULL));
            }
        }
    }

    /// Queues an answer without waiting; when the connection's queue is
    /// full the answer is dropped (and noted): a client may ask again.
    fn answer_now(&self, client: &str, answer: Bytes) {
        let topic = self.topics.response(client);
        if self
            .client
            .try_publish(topic, QoS::AtLeastOnce, false, answer.to_vec())
            .is_err()
        {
            self.notes.note(Trouble::Dropped);
        }
    }

    /// Ends idle sessions and forgets old request ids.
    pub fn sweep(&self) {
        let ended = {
            let mut table = self.table();
            table.expire(self.now());
            table.ended()
        };
        for session in ended {
            self.sessions.close(session);
        }
    }

    /// Whether a worker is still running requests.
    pub fn busy(&self) -> bool {
        self.table().workers() > 0
    }
}

/// A client's worker: runs its requests in order until none is left.
async fn work<S: Sessions>(shared: Arc<Shared<S>>, client: Arc<str>) {
    let mut out = vec![0u8; shared.response_capacity];
    loop {
        let next = shared.table().take(&client);
        let Some(Take { job, session }) = next else {
            return;
        };
        let session = session.unwrap_or_else(|| shared.sessions.open(Some(&client), shared.key(&client)));
        let id = session.id();
        let (response, session) = run(&*shared.sessions, session, &job, &mut out).await;
        let answer = Bytes::from(envelope::response(Some(&job.id), &response));
        let ended = {
            let mut table = shared.table();
            table.finish(&client, &job, session, answer.clone(), shared.now());
            table.ended()
        };
        for session in ended {
            shared.sessions.close(session);
        }
        let topic = shared.topics.response(&client);
        // Fails only once the connection's task is gone (shutdown).
        let _ = shared
            .client
            .publish_bytes(topic, QoS::AtLeastOnce, false, answer)
            .await;
        shared.sessions.answered(id);
    }
}

/// Runs one request in `session`; the response, and the session unless
/// it ended with this request (closed by the core, or logged out).
async fn run<S: Sessions>(
    sessions: &S,
    mut session: Session,
    job: &Job,
    out: &mut [u8],
) -> (String, Option<Session>) {
    let (response, closed) = match sessions.handle(&mut session, &job.frame, out).await {
        Outcome::Reply(text) => (text.to_owned(), false),
        Outcome::ReplyThenClose(text, _) => (text.to_owned(), true),
        // A text frame is closed only for a buffer too small to answer
        // in: a fault of ours, answered as one.
        Outcome::Close(_) | Outcome::Pending(..) => (
            envelope::error(
                Ret::Unhandled,
                command_id(&job.frame),
                unix_ms(),
                Failure::unhandled().msg(),
            ),
            true,
        ),
    };
    let ended = closed || logged_out(&job.frame, &response, &session);
    if ended {
        sessions.close(session);
        (response, None)
    } else {
        (response, Some(session))
    }
}

/// Whether `frame` was a `login` that logged the session out: the uplink
/// session then ends, as a connection would.
fn logged_out(frame: &str, response: &str, session: &Session) -> bool {
    let is_login = lluav_core::parse::split(frame).is_some_and(|s| s.name == "login");
    is_login
        && !session.logged_in()
        && serde_json::from_str::<serde_json::Value>(response).is_ok_and(|r| r["ret"] == 0)
}

/// The id of the command `frame` names, 0 if none.
fn command_id(frame: &str) -> u8 {
    lluav_core::parse::split(frame)
        .and_then(|s| lluav_core::table::lookup(s.name))
        .map_or(0, |spec| u8::from(spec.id))
}

/// `ts` for answers written here.
pub fn unix_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}
