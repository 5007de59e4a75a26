//! The vehicle's side: requests from the broker through the table to the
//! client's session, answers back to the broker.
//!
//! The connection's task ([`Shared::dispatch`]) never waits: it reads the
//! envelope, asks the [`Table`] what becomes of the request and either
//! answers at once (a bad envelope, a repeat, too much in flight) or
//! queues it. A fixed pool of workers ([`WORKERS`], each with one response
//! buffer) takes queued requests, the clients in turn, and runs each
//! through [`Sessions::handle`] (the same path a WebSocket session takes).
//!
//! Answers leave through the [`Outbox`], bounded in bytes: a worker waits
//! for room (a broker that stops reading slows the uplink down), an
//! answer given at once is dropped when there is none (and noted). No
//! task is started per message, so nothing a broker sends grows lluavd's
//! memory beyond the table's bounds and the outbox's.

use std::collections::{HashMap, VecDeque};
use std::fmt;
use std::hash::{BuildHasher, RandomState};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use bytes::Bytes;
use lluav_core::{Effect, Failure, Outcome, Ret, Session, SessionId};
use rumqttc::v5::AsyncClient;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::Publish;
use tokio::sync::Notify;
use tracing::warn;

use super::durable::{Entry, Found, Outcome as Previously, Store};
use super::envelope;
use super::link::StatusCell;
use super::table::{Admit, Job, Restored, Table, Take};
use super::topic::{Stray, Topics};
use super::{ClientKey, Limits, Sessions};

/// How often a kind of trouble is logged.
pub const NOTE_EVERY: Duration = Duration::from_secs(60);

/// Workers running requests at once: commands that wait on an autopilot
/// wait side by side, and each worker holds one response buffer.
pub const WORKERS: usize = 16;

/// Bytes of answers waiting for the broker connection, at most.
pub const OUTBOX_BYTES: usize = 2 << 20;

/// Bytes a PUBLISH adds to its payload besides the topic: fixed header,
/// topic length, packet id, properties.
const PUBLISH_OVERHEAD: usize = 16;

/// The answer when the client has too much in flight.
pub const TOO_MANY: &str = "Too many requests in flight";
/// The answer when the id store is full.
pub const IDS_FULL: &str = "Too many requests, retry later";
/// The answer when every client slot is held.
pub const FULL: &str = "Too many clients, retry later";
/// The answer to a repeat whose stored answer was dropped.
pub const FORGOTTEN: &str = "Request id already answered; its response is no longer kept";
/// The answer to a repeat of a request that was running when lluavd
/// stopped.
pub const INTERRUPTED: &str = "Interrupted by a restart; check state";
/// The core's answer to a response that did not fit.
pub const TOO_LARGE: &str = "Response too large";

/// Trouble worth a log line, at most one per kind per [`NOTE_EVERY`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Trouble {
    /// A message that is not a request.
    Stray(Stray),
    /// An answer dropped because the outbox was full.
    Dropped,
    /// A new client refused because every slot is held.
    Full,
    /// A new request refused because the id store is full.
    IdsFull,
    /// Requests whose Message Expiry passed before they could run.
    Expired,
    /// More repeats of a running request than are answered.
    Copies,
    /// The store of answers in the data directory failed.
    Store,
}

impl fmt::Display for Trouble {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Trouble::Stray(s) => s.fmt(f),
            Trouble::Dropped => {
                f.write_str("an answer was dropped: the broker does not take them fast enough")
            }
            Trouble::Full => f.write_str("a new client was refused: every client slot is held"),
            Trouble::IdsFull => f.write_str("a request was refused: the store of request ids is full"),
            Trouble::Expired => {
                f.write_str("a request expired (its Message Expiry) before it could run; dropped")
            }
            Trouble::Copies => f.write_str("repeats of a running request beyond those answered; ignored"),
            Trouble::Store => f.write_str("an answer could not be written to the data directory"),
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

/// One message for the broker.
#[derive(Debug)]
struct Letter {
    topic: String,
    payload: Bytes,
    /// The session whose request this answers, told once it is published
    /// ([`Sessions::answered`]): what the request caused may be told then.
    answers: Option<SessionId>,
}

impl Letter {
    fn size(&self) -> usize {
        self.topic.len() + self.payload.len()
    }
}

/// Answers waiting for the broker connection, bounded in bytes.
#[derive(Debug)]
pub struct Outbox {
    queue: Mutex<(VecDeque<Letter>, usize)>,
    limit: usize,
    posted: Notify,
    room: Notify,
}

impl Outbox {
    /// An empty outbox holding at most `limit` bytes (one letter always
    /// fits).
    pub fn new(limit: usize) -> Outbox {
        Outbox {
            queue: Mutex::new((VecDeque::new(), 0)),
            limit,
            posted: Notify::new(),
            room: Notify::new(),
        }
    }

    fn queue(&self) -> MutexGuard<'_, (VecDeque<Letter>, usize)> {
        self.queue.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Posts `payload` on `topic` if there is room.
    pub fn try_post(&self, topic: String, payload: Bytes) -> bool {
        self.try_post_letter(Letter {
            topic,
            payload,
            answers: None,
        })
        .is_ok()
    }

    /// Posts `letter` if there is room; gives it back if not.
    fn try_post_letter(&self, letter: Letter) -> Result<(), Letter> {
        let mut queue = self.queue();
        if !queue.0.is_empty() && queue.1 + letter.size() > self.limit {
            return Err(letter);
        }
        queue.1 += letter.size();
        queue.0.push_back(letter);
        drop(queue);
        self.posted.notify_one();
        Ok(())
    }

    /// Posts `payload` on `topic`, waiting for room.
    pub async fn post(&self, topic: String, payload: Bytes) {
        self.post_answer(topic, payload, None).await;
    }

    /// Posts `payload` on `topic`, waiting for room; once it is published,
    /// `answers` (if any) is told that its answer went out.
    async fn post_answer(&self, topic: String, payload: Bytes, answers: Option<SessionId>) {
        let mut letter = Letter {
            topic,
            payload,
            answers,
        };
        loop {
            let room = self.room.notified();
            tokio::pin!(room);
            room.as_mut().enable();
            match self.try_post_letter(letter) {
                Ok(()) => return,
                Err(back) => letter = back,
            }
            room.await;
        }
    }

    /// The next letter, waiting for one.
    async fn next(&self) -> Letter {
        loop {
            let posted = self.posted.notified();
            tokio::pin!(posted);
            posted.as_mut().enable();
            let letter = {
                let mut queue = self.queue();
                let letter = queue.0.pop_front();
                if let Some(l) = &letter {
                    queue.1 -= l.size();
                }
                letter
            };
            if let Some(letter) = letter {
                self.room.notify_waiters();
                return letter;
            }
            posted.await;
        }
    }

    /// Bytes waiting.
    pub fn bytes(&self) -> usize {
        self.queue().1
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
    /// Answers waiting for the connection.
    pub outbox: Outbox,
    /// Answers of requests that change the vehicle, on disk.
    pub store: Option<Store>,
    /// `--max-message`.
    pub max_message: usize,
    /// Bytes of a response buffer.
    pub response_capacity: usize,
    /// The broker's Maximum Packet Size (0: it set none).
    pub broker_max: AtomicU32,
    /// The link's state.
    pub status: StatusCell,
    /// Set once the daemon stops: requests are no longer taken.
    pub stopping: AtomicBool,
    /// Rate-limited log lines.
    pub notes: Notes,
    ready: Notify,
    /// Told when the table may have something new to expire.
    pub changed: Notify,
    keys: (RandomState, RandomState),
    start: Instant,
    window_ms: u64,
}

impl<S: Sessions> Shared<S> {
    /// What the tasks share, before any request; `found`: what the store
    /// kept of the last window.
    pub fn new(
        sessions: Arc<S>,
        client: AsyncClient,
        topics: Topics,
        limits: &Limits,
        status: StatusCell,
        store: Option<(Store, Vec<Found>)>,
    ) -> Self {
        let (store, found) = store.map_or((None, Vec::new()), |(s, f)| (Some(s), f));
        let shared = Shared {
            sessions,
            client,
            topics,
            table: Mutex::new(Table::new(limits.table)),
            outbox: Outbox::new(OUTBOX_BYTES),
            store,
            max_message: limits.max_message,
            response_capacity: limits.response_capacity.max(lluav_core::MIN_RESPONSE_CAPACITY),
            broker_max: AtomicU32::new(0),
            status,
            stopping: AtomicBool::new(false),
            notes: Notes::default(),
            ready: Notify::new(),
            changed: Notify::new(),
            keys: (RandomState::new(), RandomState::new()),
            start: Instant::now(),
            window_ms: limits.table.window_ms,
        };
        shared.restore(found);
        shared
    }

    /// Milliseconds on the table's clock: since the uplink started, plus a
    /// window, so that requests of a previous run fit before it.
    pub fn now(&self) -> u64 {
        let elapsed = u64::try_from(self.start.elapsed().as_millis()).unwrap_or(u64::MAX);
        elapsed.saturating_add(self.window_ms)
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

    /// Puts what a previous run left into the table.
    fn restore(&self, found: Vec<Found>) {
        let (now, unix) = (self.now(), unix_ms());
        let mut table = self.table();
        for f in found {
            let age = u64::try_from(unix.saturating_sub(f.at)).unwrap_or(0);
            let restored = match f.outcome {
                Previously::Answered(answer) => Restored::Answer(exact(answer)),
                Previously::AnsweredNotKept => Restored::Answered,
                Previously::Interrupted(cmd) => {
                    let response = envelope::error(Ret::SystemCall, cmd, unix, INTERRUPTED);
                    Restored::Answer(exact(envelope::response(Some(&f.id), &response)))
                }
            };
            table.restore(&f.client, &f.id, age, now, restored);
        }
    }

    /// Takes one message off the broker connection; never waits.
    pub fn dispatch(&self, publish: &Publish) {
        if self.stopping.load(Ordering::Relaxed) {
            return;
        }
        let topic = std::str::from_utf8(&publish.topic).map_err(|_| Stray::Layout);
        let client = match topic.and_then(|t| self.topics.client_of(t)) {
            // Retain Handling 2 keeps retained messages away; a broker
            // that sends one anyway sends it late.
            Ok(_) if publish.retain => Err(Stray::Retained),
            other => other,
        };
        let client = match client {
            Ok(c) => c,
            Err(stray) => return self.notes.note(Trouble::Stray(stray)),
        };
        let request = match envelope::read(&publish.payload, self.max_message) {
            Ok(r) => r,
            Err(refused) => return self.answer_now(client, exact(envelope::refused(&refused, unix_ms()))),
        };
        let now = self.now();
        let expires = publish
            .properties
            .as_ref()
            .and_then(|p| p.message_expiry_interval)
            .map(|s| now.saturating_add(u64::from(s) * 1000));
        let admit = self
            .table()
            .request(client, &request.id, &request.frame, now, expires);
        let refuse = |ret: Ret, msg: &str| {
            let response = envelope::error(ret, command_id(&request.frame), unix_ms(), msg);
            exact(envelope::response(Some(&request.id), &response))
        };
        match admit {
            Admit::Queued => {
                self.ready.notify_one();
                self.changed.notify_one();
            }
            Admit::Copy => {}
            Admit::Ignored => self.notes.note(Trouble::Copies),
            Admit::Repeat(answer) => self.answer_now(client, answer),
            Admit::Forgotten => self.answer_now(client, refuse(Ret::Failed, FORGOTTEN)),
            Admit::TooMany => self.answer_now(client, refuse(Ret::Failed, TOO_MANY)),
            Admit::IdsFull => {
                self.notes.note(Trouble::IdsFull);
                self.answer_now(client, refuse(Ret::Failed, IDS_FULL));
            }
            Admit::Full => {
                self.notes.note(Trouble::Full);
                self.answer_now(client, refuse(Ret::Failed, FULL));
            }
        }
    }

    /// Posts an answer without waiting; when the outbox is full the answer
    /// is dropped (and noted): a client may ask again.
    fn answer_now(&self, client: &str, answer: Bytes) {
        if !self.outbox.try_post(self.topics.response(client), answer) {
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

    /// Whether a worker is still running a request.
    pub fn busy(&self) -> bool {
        self.table().running() > 0
    }

    /// Wakes the idle workers (to see that the uplink stops).
    pub fn wake_all(&self) {
        self.ready.notify_waiters();
    }
}

/// A worker: runs queued requests, the clients in turn, until the uplink
/// stops.
pub async fn work<S: Sessions>(shared: Arc<Shared<S>>) {
    let mut out = vec![0u8; shared.response_capacity];
    loop {
        let ready = shared.ready.notified();
        tokio::pin!(ready);
        ready.as_mut().enable();
        let (take, expired) = shared.table().take(shared.now());
        if expired > 0 {
            shared.notes.note(Trouble::Expired);
        }
        match take {
            Some(take) => serve(&shared, take, &mut out).await,
            None if shared.stopping.load(Ordering::Relaxed) => return,
            None => ready.await,
        }
    }
}

/// Posts the answers to the broker connection, one at a time.
pub async fn send<S: Sessions>(shared: Arc<Shared<S>>) {
    loop {
        let letter = shared.outbox.next().await;
        // Fails only once the connection's task is gone (shutdown).
        let _ = shared
            .client
            .publish_bytes(letter.topic, QoS::AtLeastOnce, false, letter.payload)
            .await;
        if let Some(session) = letter.answers {
            shared.sessions.answered(session);
        }
    }
}

/// Runs one request: recorded first when it changes the vehicle, then
/// answered (recorded again), its answer posted once per copy asked.
async fn serve<S: Sessions>(shared: &Shared<S>, take: Take, out: &mut [u8]) {
    let Take { client, job, session } = take;
    let session = session.unwrap_or_else(|| shared.sessions.open(Some(&client), shared.key(&client)));
    let id = session.id();
    let cmd = command_id(&job.frame);
    // When the request came, on the wall clock (the store's clock).
    let at = unix_ms().saturating_sub(i64::try_from(shared.now().saturating_sub(job.at)).unwrap_or(0));
    let store = shared.store.as_ref().filter(|_| durable(&job.frame));
    let started = match store {
        Some(store) => {
            let entry = Entry::Started {
                client: client.to_string(),
                id: job.id.to_string(),
                at,
                cmd,
            };
            store.write(entry).await
        }
        None => Ok(()),
    };
    let (response, session) = match started {
        Ok(()) => run(&*shared.sessions, session, &job, out).await,
        Err(e) => {
            shared.notes.note(Trouble::Store);
            let msg = format!("Request not run: it cannot be recorded in the data directory ({e})");
            (
                envelope::error(Ret::SystemCall, cmd, unix_ms(), &msg),
                Some(session),
            )
        }
    };
    let answer = shared.fit(&client, &job, cmd, envelope::response(Some(&job.id), &response));
    if let Some(store) = store {
        let entry = Entry::Answered {
            client: client.to_string(),
            id: job.id.to_string(),
            at,
            answer: Some(String::from_utf8_lossy(&answer).into_owned()),
        };
        if store.write(entry).await.is_err() {
            shared.notes.note(Trouble::Store);
        }
    }
    // The answer and its copies go out before the client's next request
    // runs: whoever sent a repeat gets its answer before the next one's.
    let copies = shared.table().answered(&job, answer.clone());
    let topic = shared.topics.response(&client);
    // The first tells the session that its answer went out (the events
    // its request caused may follow it).
    for copy in 0..=copies {
        let answers = (copy == 0).then_some(id);
        shared
            .outbox
            .post_answer(topic.clone(), answer.clone(), answers)
            .await;
    }
    let ended = {
        let mut table = shared.table();
        table.release(&client, &job, session);
        table.ended()
    };
    shared.changed.notify_one();
    for session in ended {
        shared.sessions.close(session);
    }
}

impl<S: Sessions> Shared<S> {
    /// `answer`, or the core's `Response too large` when it would not fit
    /// the broker's Maximum Packet Size (the broker would end the
    /// connection for it).
    fn fit(&self, client: &str, job: &Job, cmd: u8, answer: String) -> Bytes {
        let max = self.broker_max.load(Ordering::Relaxed) as usize;
        let size = answer.len() + self.topics.response(client).len() + PUBLISH_OVERHEAD;
        if max == 0 || size <= max {
            return exact(answer);
        }
        let response = envelope::error(Ret::Failed, cmd, unix_ms(), TOO_LARGE);
        exact(envelope::response(Some(&job.id), &response))
    }
}

/// `text` in an allocation of its own size: an answer is kept for 10
/// minutes, and the bounds count its bytes (a `String` built by `format!`
/// may hold twice as many).
fn exact(text: String) -> Bytes {
    Bytes::from(text.into_bytes().into_boxed_slice())
}

/// Whether the answer to `frame` is kept on disk: its command changes the
/// vehicle (the table's effect column), except `set_sp_ned`, whose repeat
/// sets the same target (and which streams too fast to sync each).
pub fn durable(frame: &str) -> bool {
    lluav_core::parse::split(frame)
        .and_then(|s| lluav_core::table::lookup(s.name))
        .is_some_and(|spec| spec.effect == Effect::Vehicle && spec.id != lluav_core::CommandId::SetSpNed)
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
pub fn command_id(frame: &str) -> u8 {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_of_commands_that_change_the_vehicle_are_durable_except_setpoints() {
        for frame in ["takeoff", "save_param 1", "siyi_sync", "land", "set_param a:1"] {
            assert!(durable(frame), "{frame}");
        }
        for frame in [
            "state",
            "help",
            "login x",
            "set_sp_ned 1:2:-3:0",
            "control",
            "bogus",
            "",
        ] {
            assert!(!durable(frame), "{frame}");
        }
    }

    #[tokio::test]
    async fn the_outbox_holds_its_bytes_and_a_poster_waits_for_room() {
        let outbox = Arc::new(Outbox::new(100));
        assert!(outbox.try_post("t".into(), Bytes::from(vec![0u8; 90])));
        assert!(
            !outbox.try_post("t".into(), Bytes::from(vec![0u8; 20])),
            "no room"
        );
        let waiting = {
            let outbox = Arc::clone(&outbox);
            tokio::spawn(async move { outbox.post("u".into(), Bytes::from(vec![1u8; 20])).await })
        };
        tokio::task::yield_now().await;
        assert!(!waiting.is_finished());
        assert_eq!(outbox.next().await.payload.len(), 90);
        waiting.await.expect("posted once there was room");
        assert_eq!(outbox.bytes(), 21);
        assert_eq!(outbox.next().await.topic, "u");
        // One letter always fits, however large.
        assert!(outbox.try_post("t".into(), Bytes::from(vec![0u8; 500])));
    }
}
