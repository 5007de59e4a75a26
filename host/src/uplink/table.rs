//! The uplink's sessions, one per client id, the requests waiting for a
//! worker, and the request ids of the last 10 minutes (DESIGN.md,
//! "Uplink").
//!
//! Sans-IO: the caller passes the time (milliseconds on any monotonic
//! clock), runs the requests and keeps the durable copy; the table decides
//! what becomes of each message and keeps everything bounded:
//! - sessions ([`Limits::clients`]): a new client id takes the seat of one
//!   that holds nothing that matters (not logged in, nothing queued or
//!   running); when none can go, [`Admit::Full`];
//! - requests queued or running, per client ([`Limits::in_flight`]) and in
//!   all ([`Limits::in_flight_total`], [`Limits::in_flight_bytes`]):
//!   beyond them, [`Admit::TooMany`];
//! - request ids ([`Limits::ids`] per client, [`Limits::ids_total`] in
//!   all): an id is forgotten only [`Limits::window_ms`] after its request,
//!   never earlier, so a full store refuses new requests
//!   ([`Admit::IdsFull`]) rather than forget an id that may come again.
//!   Ids are kept apart from sessions: a session that gives up its seat
//!   leaves its ids behind;
//! - stored answers ([`Limits::bytes`] per client, [`Limits::bytes_total`]
//!   in all): the oldest go first, and their ids stay
//!   ([`Admit::Forgotten`]).
//!
//! A repeated id within the window never runs again: it gets the stored
//! answer ([`Admit::Repeat`]), or, while the first copy still runs, the
//! same answer once it exists ([`Admit::Copy`]: [`Table::answered`] says
//! how many copies wait for it). Ids are kept as keyed 64-bit hashes of
//! (client, id), so no client can make its ids collide with another's.
//!
//! Requests wait in a queue per client and clients take turns: a worker
//! [`Table::take`]s the next request of the client whose turn it is, one
//! request of a client at a time, so each client's requests run in order.

use std::collections::{HashMap, VecDeque};
use std::hash::{BuildHasher, RandomState};
use std::sync::Arc;

use bytes::Bytes;
use lluav_core::Session;

/// The table's bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Sessions at once.
    pub clients: usize,
    /// Requests one client may have queued or running.
    pub in_flight: usize,
    /// Requests queued or running, all clients together.
    pub in_flight_total: usize,
    /// Bytes of frames queued or running, all clients together.
    pub in_flight_bytes: usize,
    /// How long a request id is remembered, from its request.
    pub window_ms: u64,
    /// Request ids remembered per client.
    pub ids: usize,
    /// Request ids remembered in all.
    pub ids_total: usize,
    /// Bytes of stored answers per client.
    pub bytes: usize,
    /// Bytes of stored answers in all.
    pub bytes_total: usize,
    /// Repeats of one running request waiting for its answer.
    pub copies: u16,
    /// A session without requests for this long ends.
    pub idle_ms: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            clients: 1024,
            in_flight: 32,
            in_flight_total: 4096,
            in_flight_bytes: 4 << 20,
            window_ms: 10 * 60 * 1000,
            ids: 32 << 10,
            ids_total: 64 << 10,
            bytes: 256 << 10,
            bytes_total: 4 << 20,
            copies: 16,
            idle_ms: 300 * 1000,
        }
    }
}

/// What becomes of a request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Admit {
    /// Queued: a worker will [`Table::take`] it.
    Queued,
    /// A repeat of an answered request: send this stored answer again.
    Repeat(Bytes),
    /// A repeat of a request still queued or running: its answer will be
    /// sent once more for this copy.
    Copy,
    /// A repeat of a running request that already has as many copies
    /// waiting as [`Limits::copies`]: nothing more to send.
    Ignored,
    /// A repeat of a request whose answer was dropped to stay in bounds:
    /// not run again, and nothing to send but that.
    Forgotten,
    /// The client (or all clients together) has too much in flight.
    TooMany,
    /// The id store is full (in all, or this client's share).
    IdsFull,
    /// Every session seat is held by a client that matters.
    Full,
}

/// A request waiting for or taken by a worker.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Job {
    /// The client's id for it.
    pub id: Box<str>,
    /// The protocol frame.
    pub frame: Box<str>,
    /// When it came, on the table's clock.
    pub at: u64,
    /// When it stops being worth running (its Message Expiry), if ever.
    pub expires: Option<u64>,
    key: u64,
}

/// What a worker takes: a request, its client and the client's session.
#[derive(Debug)]
pub struct Take {
    /// The client id.
    pub client: Arc<str>,
    /// The request.
    pub job: Job,
    /// The client's session, if it has one.
    pub session: Option<Session>,
}

/// What a restart found of a request (see [`Table::restore`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Restored {
    /// Its answer, as sent.
    Answer(Bytes),
    /// Answered, the answer not kept.
    Answered,
}

/// A remembered request id.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// Queued or running; `copies` repeats wait for its answer.
    Running { copies: u16 },
    /// Answered, the answer in [`Ids::answers`].
    Kept,
    /// Answered; the answer was dropped to stay within bounds.
    Dropped,
}

#[derive(Clone, Copy, Debug)]
struct Rec {
    client: u64,
    at: u64,
    state: State,
}

/// What one client holds in the id store (each within `u32`: the bounds
/// are).
#[derive(Clone, Copy, Debug, Default)]
struct Use {
    ids: u32,
    bytes: u32,
}

/// Every client's request ids of the last window, and the answers kept.
#[derive(Debug)]
struct Ids {
    recs: HashMap<u64, Rec>,
    /// (request time, key), oldest first: the order ids expire in.
    order: VecDeque<(u64, u64)>,
    answers: HashMap<u64, Bytes>,
    /// (request time, key) in the order answers were kept, oldest first;
    /// entries whose id has gone since are skipped.
    kept: VecDeque<(u64, u64)>,
    clients: HashMap<u64, Use>,
    bytes: usize,
}

impl Ids {
    /// An empty store with room for `limits.ids_total` ids made at once:
    /// growing by doubling would leave the smaller tables behind as
    /// fragments of the heap, and untouched room costs no memory.
    fn new(limits: &Limits) -> Ids {
        Ids {
            recs: HashMap::with_capacity(limits.ids_total),
            order: VecDeque::with_capacity(limits.ids_total),
            answers: HashMap::new(),
            kept: VecDeque::new(),
            clients: HashMap::with_capacity(limits.ids_total),
            bytes: 0,
        }
    }

    fn usage(&self, client: u64) -> Use {
        self.clients.get(&client).copied().unwrap_or_default()
    }

    fn insert(&mut self, key: u64, rec: Rec) {
        self.recs.insert(key, rec);
        self.order.push_back((rec.at, key));
        self.clients.entry(rec.client).or_default().ids += 1;
    }

    /// Forgets `key` (its answer too).
    fn remove(&mut self, key: u64) {
        let Some(rec) = self.recs.remove(&key) else {
            return;
        };
        let freed = self.answers.remove(&key).map_or(0, |a| a.len());
        self.bytes -= freed;
        if let Some(usage) = self.clients.get_mut(&rec.client) {
            usage.ids -= 1;
            usage.bytes -= freed as u32;
            if usage.ids == 0 {
                self.clients.remove(&rec.client);
            }
        }
    }

    /// Keeps `answer` for `key`, then drops the oldest answers beyond the
    /// bounds (the client's own first).
    fn keep(&mut self, key: u64, answer: Bytes, limits: &Limits) {
        let Some(rec) = self.recs.get_mut(&key) else {
            return;
        };
        rec.state = State::Kept;
        let (client, at) = (rec.client, rec.at);
        self.bytes += answer.len();
        if let Some(usage) = self.clients.get_mut(&client) {
            usage.bytes += answer.len() as u32;
        }
        self.answers.insert(key, answer);
        self.kept.push_back((at, key));
        while self.usage(client).bytes as usize > limits.bytes {
            let Some(at) = self
                .kept
                .iter()
                .position(|(at, k)| self.live(*at, *k, Some(client)))
            else {
                break;
            };
            let (_, key) = self.kept.remove(at).unwrap_or_default();
            self.drop_answer(key);
        }
        while self.bytes > limits.bytes_total {
            let Some((at, key)) = self.kept.pop_front() else {
                break;
            };
            if self.live(at, key, None) {
                self.drop_answer(key);
            }
        }
        // Entries of ids that went stay until they reach the front: keep
        // the queue within twice the ids it can be about.
        if self.kept.len() > 2 * limits.ids_total.max(1) {
            let (recs, answers) = (&self.recs, &self.answers);
            self.kept.retain(|(at, k)| {
                answers.contains_key(k) && recs.get(k).is_some_and(|r| r.at == *at && r.state == State::Kept)
            });
        }
    }

    /// Whether a `kept` entry still stands for a kept answer (of `client`).
    fn live(&self, at: u64, key: u64, client: Option<u64>) -> bool {
        self.recs
            .get(&key)
            .is_some_and(|r| r.at == at && r.state == State::Kept && client.is_none_or(|c| c == r.client))
    }

    fn drop_answer(&mut self, key: u64) {
        let freed = self.answers.remove(&key).map_or(0, |a| a.len());
        self.bytes -= freed;
        if let Some(rec) = self.recs.get_mut(&key) {
            rec.state = State::Dropped;
            if let Some(usage) = self.clients.get_mut(&rec.client) {
                usage.bytes -= freed as u32;
            }
        }
    }

    /// Forgets the ids whose window has passed (one still running stays,
    /// and the younger ones behind it: its answer is still to come).
    fn expire(&mut self, now: u64, window: u64) {
        while let Some(&(at, key)) = self.order.front() {
            if now.saturating_sub(at) < window {
                break;
            }
            match self.recs.get(&key) {
                Some(rec) if rec.at == at && matches!(rec.state, State::Running { .. }) => break,
                Some(rec) if rec.at == at => self.remove(key),
                // Forgotten already (a request that expired unrun).
                _ => {}
            }
            self.order.pop_front();
        }
        while let Some(&(at, key)) = self.kept.front() {
            if self.live(at, key, None) {
                break;
            }
            self.kept.pop_front();
        }
    }
}

/// Where a client's session is.
#[derive(Debug)]
enum Slot {
    /// None yet, or it ended.
    Empty,
    /// Between requests.
    Idle(Session),
    /// Out with a worker, running a request.
    Busy,
}

/// One client's seat: its session and its queue.
#[derive(Debug)]
struct Seat {
    name: Arc<str>,
    slot: Slot,
    queue: VecDeque<Job>,
    /// In [`Table::ready`], waiting for a worker.
    ready: bool,
    last_request: u64,
}

impl Seat {
    fn busy(&self) -> bool {
        matches!(self.slot, Slot::Busy)
    }

    /// Whether the seat may be given up to make room: nothing running or
    /// queued, and no session that is logged in.
    fn reclaimable(&self) -> bool {
        !self.busy() && self.queue.is_empty() && !matches!(&self.slot, Slot::Idle(s) if s.logged_in())
    }

    fn in_flight(&self) -> usize {
        self.queue.len() + usize::from(self.busy())
    }
}

/// The sessions, queues and remembered requests of every client.
#[derive(Debug)]
pub struct Table {
    limits: Limits,
    seats: HashMap<u64, Seat>,
    /// Clients with a request waiting and none running, in turn.
    ready: VecDeque<u64>,
    ids: Ids,
    keys: RandomState,
    queued: usize,
    queued_bytes: usize,
    running: usize,
    /// Sessions that ended in the table (idle, or their seat given up),
    /// for the caller to close.
    ended: Vec<Session>,
}

impl Table {
    /// An empty table.
    pub fn new(limits: Limits) -> Table {
        Table {
            limits,
            seats: HashMap::new(),
            ready: VecDeque::new(),
            ids: Ids::new(&limits),
            keys: RandomState::new(),
            queued: 0,
            queued_bytes: 0,
            running: 0,
            ended: Vec::new(),
        }
    }

    /// The bounds.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    fn client_key(&self, client: &str) -> u64 {
        self.keys.hash_one(("client", client))
    }

    fn id_key(&self, client: &str, id: &str) -> u64 {
        self.keys.hash_one((client, id))
    }

    /// Decides what becomes of request `id` from `client` at `now`, which
    /// stops being worth running at `expires` if that comes first.
    pub fn request(&mut self, client: &str, id: &str, frame: &str, now: u64, expires: Option<u64>) -> Admit {
        self.ids.expire(now, self.limits.window_ms);
        let key = self.id_key(client, id);
        if let Some(rec) = self.ids.recs.get_mut(&key) {
            return match rec.state {
                State::Kept => Admit::Repeat(self.ids.answers.get(&key).cloned().unwrap_or_default()),
                State::Dropped => Admit::Forgotten,
                State::Running { ref mut copies } if *copies < self.limits.copies => {
                    *copies += 1;
                    Admit::Copy
                }
                State::Running { .. } => Admit::Ignored,
            };
        }
        let who = self.client_key(client);
        let limits = self.limits;
        if self.ids.recs.len() >= limits.ids_total || self.ids.usage(who).ids as usize >= limits.ids {
            return Admit::IdsFull;
        }
        let in_flight = self.seats.get(&who).map_or(0, Seat::in_flight);
        if in_flight >= limits.in_flight
            || self.queued + self.running >= limits.in_flight_total
            || self.queued_bytes + frame.len() > limits.in_flight_bytes
        {
            return Admit::TooMany;
        }
        if !self.seats.contains_key(&who) {
            if !self.make_room() {
                return Admit::Full;
            }
            let seat = Seat {
                name: Arc::from(client),
                slot: Slot::Empty,
                queue: VecDeque::new(),
                ready: false,
                last_request: now,
            };
            self.seats.insert(who, seat);
        }
        self.ids.insert(
            key,
            Rec {
                client: who,
                at: now,
                state: State::Running { copies: 0 },
            },
        );
        let job = Job {
            id: id.into(),
            frame: frame.into(),
            at: now,
            expires,
            key,
        };
        self.queued += 1;
        self.queued_bytes += frame.len();
        let Some(seat) = self.seats.get_mut(&who) else {
            return Admit::TooMany;
        };
        seat.queue.push_back(job);
        seat.last_request = now;
        if !seat.busy() && !seat.ready {
            seat.ready = true;
            self.ready.push_back(who);
        }
        Admit::Queued
    }

    /// The next request to run, or `None` when none waits. The client's
    /// other requests wait until this one is [`Table::release`]d. Requests
    /// whose expiry passed by `now` are dropped unrun, as never received
    /// (in the second value: how many).
    pub fn take(&mut self, now: u64) -> (Option<Take>, usize) {
        let mut expired = 0;
        while let Some(who) = self.ready.pop_front() {
            let Some(seat) = self.seats.get_mut(&who) else {
                continue;
            };
            seat.ready = false;
            while let Some(job) = seat.queue.pop_front() {
                self.queued -= 1;
                if job.expires.is_some_and(|e| e <= now) {
                    self.queued_bytes -= job.frame.len();
                    self.ids.remove(job.key);
                    expired += 1;
                    continue;
                }
                self.running += 1;
                let session = match std::mem::replace(&mut seat.slot, Slot::Busy) {
                    Slot::Idle(s) => Some(s),
                    Slot::Empty | Slot::Busy => None,
                };
                let client = Arc::clone(&seat.name);
                return (Some(Take { client, job, session }), expired);
            }
        }
        (None, expired)
    }

    /// Keeps the answer to `job` (as sent) for its repeats; the answer is
    /// to be sent `1 +` the returned number of times (the copies that came
    /// while it ran). The client's next request waits for
    /// [`Table::release`]: its answers go out after these.
    pub fn answered(&mut self, job: &Job, answer: Bytes) -> u16 {
        let copies = match self.ids.recs.get(&job.key) {
            Some(Rec {
                state: State::Running { copies },
                at,
                ..
            }) if *at == job.at => *copies,
            _ => return 0,
        };
        self.ids.keep(job.key, answer, &self.limits);
        copies
    }

    /// Gives back the session of `client` after `job` (`None` when it
    /// ended with the request): its next request may run.
    pub fn release(&mut self, client: &str, job: &Job, session: Option<Session>) {
        self.running -= 1;
        self.queued_bytes -= job.frame.len();
        let who = self.client_key(client);
        if let Some(seat) = self.seats.get_mut(&who) {
            seat.slot = session.map_or(Slot::Empty, Slot::Idle);
            if !seat.queue.is_empty() && !seat.ready {
                seat.ready = true;
                self.ready.push_back(who);
            } else if seat.queue.is_empty() && matches!(seat.slot, Slot::Empty) {
                self.seats.remove(&who);
            }
        }
    }

    /// Remembers, at start, a request of the last window that a previous
    /// run answered (or was running when it stopped: its answer says so),
    /// `age_ms` old.
    pub fn restore(&mut self, client: &str, id: &str, age_ms: u64, now: u64, restored: Restored) {
        if age_ms >= self.limits.window_ms || self.ids.recs.len() >= self.limits.ids_total {
            return;
        }
        let key = self.id_key(client, id);
        if self.ids.recs.contains_key(&key) {
            return;
        }
        let rec = Rec {
            client: self.client_key(client),
            at: now.saturating_sub(age_ms),
            state: State::Dropped,
        };
        self.ids.insert(key, rec);
        if let Restored::Answer(answer) = restored {
            self.ids.keep(key, answer, &self.limits);
        }
    }

    /// Ends the sessions idle for [`Limits::idle_ms`] and forgets request
    /// ids older than [`Limits::window_ms`]. The ended sessions are in
    /// [`Table::ended`].
    pub fn expire(&mut self, now: u64) {
        let limits = self.limits;
        self.ids.expire(now, limits.window_ms);
        let ended = &mut self.ended;
        self.seats.retain(|_, seat| {
            let idle = now.saturating_sub(seat.last_request) >= limits.idle_ms;
            if idle
                && seat.queue.is_empty()
                && let Slot::Idle(_) = seat.slot
                && let Slot::Idle(s) = std::mem::replace(&mut seat.slot, Slot::Empty)
            {
                ended.push(s);
            }
            !(matches!(seat.slot, Slot::Empty) && seat.queue.is_empty())
        });
    }

    /// When [`Table::expire`] next has something to do, on the table's
    /// clock: the oldest id's window ends, or an idle session's time is up
    /// (a session out with a worker is due only once given back); `None`
    /// when nothing is remembered and no session is held.
    pub fn next_expiry(&self) -> Option<u64> {
        let limits = self.limits;
        let ids = self
            .ids
            .order
            .front()
            .map(|(at, _)| at.saturating_add(limits.window_ms));
        let seats = self.seats.values().filter_map(|seat| match seat.slot {
            _ if !seat.queue.is_empty() => None,
            Slot::Idle(_) => Some(seat.last_request.saturating_add(limits.idle_ms)),
            Slot::Empty => Some(seat.last_request),
            Slot::Busy => None,
        });
        ids.into_iter().chain(seats).min()
    }

    /// Sessions that ended in the table since the last call, to close.
    pub fn ended(&mut self) -> Vec<Session> {
        std::mem::take(&mut self.ended)
    }

    /// Requests running.
    pub fn running(&self) -> usize {
        self.running
    }

    /// Sessions held.
    pub fn clients(&self) -> usize {
        self.seats.len()
    }

    /// Totals: requests queued or running, their bytes, request ids
    /// remembered, bytes of stored answers.
    pub fn totals(&self) -> (usize, usize, usize, usize) {
        (
            self.queued + self.running,
            self.queued_bytes,
            self.ids.recs.len(),
            self.ids.bytes,
        )
    }

    /// Makes room for one more session; false when nothing can go.
    fn make_room(&mut self) -> bool {
        if self.seats.len() < self.limits.clients {
            return true;
        }
        let victim = self
            .seats
            .iter()
            .filter(|(_, s)| s.reclaimable())
            .min_by_key(|(_, s)| s.last_request)
            .map(|(who, _)| *who);
        let Some(seat) = victim.and_then(|who| self.seats.remove(&who)) else {
            return false;
        };
        if let Slot::Idle(s) = seat.slot {
            self.ended.push(s);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> Limits {
        Limits {
            clients: 2,
            in_flight: 2,
            in_flight_total: 100,
            in_flight_bytes: 1000,
            window_ms: 1000,
            ids: 5,
            ids_total: 8,
            bytes: 20,
            bytes_total: 30,
            copies: 2,
            idle_ms: 500,
        }
    }

    /// Runs every queued request, answering each with its frame, the
    /// session given back not logged in; how many ran and the copies of
    /// each answer to send.
    fn run_all(t: &mut Table, now: u64) -> Vec<(String, u16)> {
        let mut ran = Vec::new();
        while let (Some(Take { client, job, session }), _) = t.take(now) {
            let answer = Bytes::from(job.frame.to_string());
            let copies = t.answered(&job, answer);
            t.release(&client, &job, Some(session.unwrap_or_default()));
            ran.push((format!("{client}/{}", job.id), copies));
        }
        ran
    }

    #[test]
    fn a_repeated_id_gets_the_stored_answer_and_never_runs_twice() {
        let mut t = Table::new(small());
        assert_eq!(t.request("c", "1", "state", 0, None), Admit::Queued);
        assert_eq!(t.request("c", "1", "takeoff", 1, None), Admit::Copy);
        assert_eq!(t.request("c", "1", "takeoff", 1, None), Admit::Copy);
        assert_eq!(t.request("c", "1", "takeoff", 1, None), Admit::Ignored);
        assert_eq!(run_all(&mut t, 2), [("c/1".to_owned(), 2)], "two copies wait");
        assert_eq!(
            t.request("c", "1", "takeoff", 3, None),
            Admit::Repeat(Bytes::from("state"))
        );
        assert_eq!(
            t.request("d", "1", "land", 3, None),
            Admit::Queued,
            "ids are per client"
        );
    }

    #[test]
    fn ids_are_forgotten_after_the_window_and_not_before() {
        let mut t = Table::new(small());
        assert_eq!(t.request("c", "1", "state", 0, None), Admit::Queued);
        run_all(&mut t, 0);
        assert!(matches!(
            t.request("c", "1", "state", 999, None),
            Admit::Repeat(_)
        ));
        assert_eq!(t.request("c", "1", "state", 1000, None), Admit::Queued);
    }

    #[test]
    fn nothing_is_due_in_an_empty_table_and_the_earliest_expiry_otherwise() {
        let mut t = Table::new(small());
        assert_eq!(t.next_expiry(), None);
        assert_eq!(t.request("c", "1", "state", 100, None), Admit::Queued);
        // Queued: the session is not idle, the id's window is due.
        assert_eq!(t.next_expiry(), Some(1100));
        run_all(&mut t, 100);
        assert_eq!(t.next_expiry(), Some(600), "the idle session first");
        t.expire(600);
        assert_eq!(t.ended().len(), 1);
        assert_eq!(t.next_expiry(), Some(1100));
        t.expire(1100);
        assert_eq!(t.next_expiry(), None, "all forgotten");
    }

    #[test]
    fn a_full_id_store_refuses_new_requests_instead_of_forgetting() {
        let mut t = Table::new(small());
        for id in 0..5 {
            assert_eq!(t.request("c", &id.to_string(), "s", 0, None), Admit::Queued);
            run_all(&mut t, 0);
        }
        assert_eq!(
            t.request("c", "5", "s", 1, None),
            Admit::IdsFull,
            "the client's share"
        );
        for id in 0..3 {
            assert_eq!(t.request("d", &id.to_string(), "s", 1, None), Admit::Queued);
            run_all(&mut t, 1);
        }
        assert_eq!(t.request("d", "3", "s", 1, None), Admit::IdsFull, "the store");
        for id in 0..5 {
            assert!(
                !matches!(t.request("c", &id.to_string(), "s", 2, None), Admit::Queued),
                "{id} is remembered"
            );
        }
        assert_eq!(
            t.request("d", "3", "s", 1000, None),
            Admit::Queued,
            "after the window"
        );
    }

    #[test]
    fn beyond_the_in_flight_bound_requests_are_refused_and_not_remembered() {
        let mut t = Table::new(small());
        assert_eq!(t.request("c", "1", "a", 0, None), Admit::Queued);
        assert_eq!(t.request("c", "2", "b", 0, None), Admit::Queued);
        assert_eq!(t.request("c", "3", "c", 0, None), Admit::TooMany);
        assert_eq!(run_all(&mut t, 0).len(), 2);
        assert_eq!(t.request("c", "3", "c", 0, None), Admit::Queued);
    }

    #[test]
    fn answers_over_the_byte_bounds_are_dropped_but_their_ids_still_refuse_a_rerun() {
        let mut t = Table::new(small());
        for id in ["1", "2"] {
            t.request("c", id, "0123456789abcdef", 0, None);
            run_all(&mut t, 0);
        }
        assert_eq!(t.request("c", "1", "x", 1, None), Admit::Forgotten);
        assert!(matches!(t.request("c", "2", "x", 1, None), Admit::Repeat(_)));
        assert!(t.totals().3 <= 20);
        // The total: the oldest answer of anyone goes.
        for id in ["3", "4"] {
            t.request("d", id, "0123456789", 2, None);
            run_all(&mut t, 2);
        }
        assert_eq!(t.request("c", "2", "x", 3, None), Admit::Forgotten);
        assert!(matches!(t.request("d", "3", "x", 3, None), Admit::Repeat(_)));
        assert!(t.totals().3 <= 30);
    }

    #[test]
    fn a_client_that_gives_up_its_seat_keeps_its_ids() {
        let mut t = Table::new(small());
        t.request("a", "1", "s", 0, None);
        t.request("b", "1", "s", 1, None);
        assert_eq!(t.request("c", "1", "s", 2, None), Admit::Full, "both are queued");
        run_all(&mut t, 3);
        // a and b ended with nothing: their seats went; c and d take seats.
        assert_eq!(t.request("c", "1", "s", 4, None), Admit::Queued);
        assert_eq!(t.request("d", "1", "s", 4, None), Admit::Queued);
        assert_eq!(t.clients(), 2);
        assert!(matches!(t.request("a", "1", "s", 5, None), Admit::Repeat(_)));
    }

    #[test]
    fn a_full_table_never_takes_the_seat_of_a_logged_in_or_busy_client() {
        let mut t = Table::new(small());
        let mut auth = lluav_core::Auth::new(Some("pw-test")).expect("a valid password");
        t.request("a", "1", "s", 0, None);
        let (Some(Take { client, job, session }), _) = t.take(0) else {
            panic!("a request")
        };
        let mut session = session.unwrap_or_default();
        auth.login(&mut session, "pw-test", 0);
        t.answered(&job, Bytes::from("ok"));
        t.release(&client, &job, Some(session));
        t.request("b", "1", "s", 1, None);
        assert_eq!(t.request("c", "1", "s", 2, None), Admit::Full);
        run_all(&mut t, 2);
        assert_eq!(t.request("c", "2", "s", 3, None), Admit::Queued, "b's seat");
        assert_eq!(t.ended().len(), 1, "b's session is handed back to be closed");
    }

    #[test]
    fn clients_take_turns_and_each_client_runs_one_request_at_a_time_in_order() {
        let mut t = Table::new(Limits {
            in_flight: 10,
            ..small()
        });
        for id in ["1", "2", "3"] {
            t.request("a", id, "s", 0, None);
        }
        t.request("b", "1", "s", 0, None);
        let (Some(first), _) = t.take(0) else {
            panic!("a request")
        };
        assert_eq!(&*first.job.id, "1");
        let (Some(second), _) = t.take(0) else {
            panic!("b's request")
        };
        assert_eq!((&*second.client, &*second.job.id), ("b", "1"));
        assert!(t.take(0).0.is_none(), "a's next waits for its first");
        assert_eq!(t.answered(&first.job, Bytes::new()), 0);
        assert!(t.take(0).0.is_none(), "and for its answers to go out");
        t.release(&first.client, &first.job, None);
        let (Some(next), _) = t.take(0) else {
            panic!("a's second")
        };
        assert_eq!((&*next.client, &*next.job.id), ("a", "2"));
        assert_eq!(t.running(), 2);
    }

    #[test]
    fn a_request_whose_expiry_passed_is_dropped_unrun_and_its_id_forgotten() {
        let mut t = Table::new(small());
        t.request("a", "1", "s", 0, Some(5));
        t.request("a", "2", "s", 0, Some(50));
        let (take, expired) = t.take(10);
        assert_eq!(
            (take.map(|t| t.job.id.to_string()), expired),
            (Some("2".into()), 1)
        );
        assert_eq!(t.request("a", "1", "s", 11, None), Admit::Queued, "never ran");
    }

    #[test]
    fn restored_requests_answer_their_repeats_for_the_rest_of_their_window() {
        let mut t = Table::new(small());
        t.restore("a", "1", 400, 10_000, Restored::Answer(Bytes::from("done")));
        t.restore("a", "2", 400, 10_000, Restored::Answered);
        t.restore("a", "3", 1000, 10_000, Restored::Answered);
        assert_eq!(
            t.request("a", "1", "s", 10_000, None),
            Admit::Repeat(Bytes::from("done"))
        );
        assert_eq!(t.request("a", "2", "s", 10_000, None), Admit::Forgotten);
        assert_eq!(
            t.request("a", "3", "s", 10_000, None),
            Admit::Queued,
            "too old to matter"
        );
        assert_eq!(
            t.request("a", "1", "s", 10_600, None),
            Admit::Queued,
            "its window ended"
        );
    }

    #[test]
    fn idle_sessions_end_and_the_totals_return_to_zero() {
        let mut t = Table::new(small());
        t.request("a", "1", "s", 0, None);
        run_all(&mut t, 0);
        t.expire(499);
        assert!(t.ended().is_empty());
        t.expire(500);
        assert_eq!(t.ended().len(), 1);
        assert_eq!(t.clients(), 0);
        assert_eq!(t.totals().2, 1, "its id is still remembered");
        t.expire(1000);
        assert_eq!(t.totals(), (0, 0, 0, 0));
    }
}
