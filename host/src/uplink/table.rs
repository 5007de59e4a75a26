//! The uplink's sessions, one per client id, and what each client asked
//! within the last 10 minutes (DESIGN.md, "Uplink").
//!
//! Sans-IO: the caller passes the time (milliseconds on any monotonic
//! clock) and runs the requests; the table decides what happens to each
//! message and keeps everything bounded:
//! - per client: requests in flight ([`Limits::in_flight`]; beyond it
//!   [`Admit::TooMany`]), remembered request ids ([`Limits::ids`]) and the
//!   bytes of stored answers ([`Limits::bytes`]);
//! - in all: clients ([`Limits::clients`]; a client that holds nothing that
//!   matters makes room, never one logged in or running a request), bytes
//!   of requests in flight, remembered ids and stored answers (the client
//!   holding the most gives way first).
//!
//! A repeated id within [`Limits::window_ms`] is never run again: it gets
//! the stored answer ([`Admit::Repeat`]), nothing while the first copy
//! still runs ([`Admit::Running`]: its answer is coming), or, once the
//! answer was dropped to stay within bounds, [`Admit::Forgotten`]. Ids are
//! kept as keyed 64-bit hashes, so a client cannot make another client's
//! ids collide with its own.

use std::collections::{HashMap, VecDeque};
use std::hash::{BuildHasher, RandomState};

use bytes::Bytes;
use lluav_core::Session;

/// The table's bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Clients remembered at once (sessions, and ids of ended sessions).
    pub clients: usize,
    /// Requests one client may have queued or running.
    pub in_flight: usize,
    /// Bytes of frames queued or running, all clients together.
    pub in_flight_bytes: usize,
    /// How long a request id is remembered, from its request.
    pub window_ms: u64,
    /// Request ids remembered per client.
    pub ids: usize,
    /// Bytes of stored answers per client.
    pub bytes: usize,
    /// Request ids remembered in all.
    pub ids_total: usize,
    /// Bytes of stored answers in all.
    pub bytes_total: usize,
    /// A session without requests for this long ends.
    pub idle_ms: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            clients: 1024,
            in_flight: 32,
            in_flight_bytes: 8 << 20,
            window_ms: 10 * 60 * 1000,
            ids: 1024,
            bytes: 256 << 10,
            ids_total: 64 << 10,
            bytes_total: 16 << 20,
            idle_ms: 300 * 1000,
        }
    }
}

/// What becomes of a request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Admit {
    /// Queued, and the client had nothing running: start its worker,
    /// which [`Table::take`]s requests until there are none.
    Start,
    /// Queued behind the client's running request.
    Queued,
    /// A repeat of an answered request: send this stored answer again.
    Repeat(Bytes),
    /// A repeat of a request still queued or running: its answer is coming.
    Running,
    /// A repeat of a request whose answer was dropped to stay in bounds:
    /// not run again, and nothing to send but that.
    Forgotten,
    /// The client (or all clients together) has too much in flight.
    TooMany,
    /// Every client slot is held by a session that is logged in or busy.
    Full,
}

/// A request to run.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Job {
    /// The client's request id.
    pub id: Box<str>,
    /// The frame.
    pub frame: Box<str>,
    key: u64,
}

/// The next request of a client, and its session (`None`: open one).
#[derive(Debug)]
pub struct Take {
    /// The request.
    pub job: Job,
    /// The client's session, if it has one.
    pub session: Option<Session>,
}

/// A remembered request.
#[derive(Clone, Debug, PartialEq, Eq)]
enum Stored {
    /// Queued or running.
    InFlight,
    /// Answered: the answer as sent.
    Kept(Bytes),
    /// Answered; the answer was dropped to stay within bounds.
    Dropped,
}

/// One client's remembered requests, oldest first.
#[derive(Debug, Default)]
struct Dedup {
    stored: HashMap<u64, (u64, Stored)>,
    order: VecDeque<u64>,
    bytes: usize,
}

/// Where a client's session is.
#[derive(Debug)]
enum Slot {
    /// None yet, or it ended.
    Empty,
    /// Between requests.
    Idle(Session),
    /// Out with the worker, running a request.
    Busy,
}

#[derive(Debug)]
struct Entry {
    slot: Slot,
    queue: VecDeque<Job>,
    /// A worker is taking this client's requests.
    worker: bool,
    last_request: u64,
    dedup: Dedup,
}

impl Entry {
    fn new(now: u64) -> Entry {
        Entry {
            slot: Slot::Empty,
            queue: VecDeque::new(),
            worker: false,
            last_request: now,
            dedup: Dedup::default(),
        }
    }

    /// Whether the entry may be let go to make room: nothing running or
    /// queued, and no session that is logged in.
    fn reclaimable(&self) -> bool {
        !self.worker && !matches!(&self.slot, Slot::Idle(s) if s.logged_in())
    }

    fn is_empty(&self) -> bool {
        matches!(self.slot, Slot::Empty) && !self.worker && self.dedup.order.is_empty()
    }

    fn in_flight(&self) -> usize {
        self.queue.len() + usize::from(matches!(self.slot, Slot::Busy))
    }
}

/// The sessions and remembered requests of every client.
#[derive(Debug)]
pub struct Table {
    limits: Limits,
    clients: HashMap<Box<str>, Entry>,
    keys: RandomState,
    queued_bytes: usize,
    ids: usize,
    bytes: usize,
    /// Sessions that ended in the table (idle, or let go to make room),
    /// for the caller to close.
    ended: Vec<Session>,
}

impl Table {
    /// An empty table.
    pub fn new(limits: Limits) -> Table {
        Table {
            limits,
            clients: HashMap::new(),
            keys: RandomState::new(),
            queued_bytes: 0,
            ids: 0,
            bytes: 0,
            ended: Vec::new(),
        }
    }

    /// The bounds.
    pub fn limits(&self) -> &Limits {
        &self.limits
    }

    /// Decides what becomes of request `id` from `client` at `now`.
    pub fn request(&mut self, client: &str, id: &str, frame: &str, now: u64) -> Admit {
        let key = self.keys.hash_one(id);
        if let Some(entry) = self.clients.get_mut(client) {
            let (ids, bytes) = expire(&mut entry.dedup, now, self.limits.window_ms);
            self.ids -= ids;
            self.bytes -= bytes;
            match entry.dedup.stored.get(&key) {
                Some((_, Stored::Kept(answer))) => return Admit::Repeat(answer.clone()),
                Some((_, Stored::InFlight)) => return Admit::Running,
                Some((_, Stored::Dropped)) => return Admit::Forgotten,
                None => {}
            }
        } else if !self.make_room() {
            return Admit::Full;
        }
        let limits = self.limits;
        let in_flight = self.clients.get(client).map_or(0, Entry::in_flight);
        if in_flight >= limits.in_flight || self.queued_bytes + frame.len() > limits.in_flight_bytes {
            return Admit::TooMany;
        }
        let entry = self
            .clients
            .entry(client.into())
            .or_insert_with(|| Entry::new(now));
        entry.queue.push_back(Job {
            id: id.into(),
            frame: frame.into(),
            key,
        });
        entry.last_request = now;
        entry.dedup.stored.insert(key, (now, Stored::InFlight));
        entry.dedup.order.push_back(key);
        let started = !std::mem::replace(&mut entry.worker, true);
        self.queued_bytes += frame.len();
        self.ids += 1;
        self.trim_ids(client);
        if started { Admit::Start } else { Admit::Queued }
    }

    /// The next request of `client` and its session, or `None` when it
    /// has no more (its worker then stops; the next request starts one).
    pub fn take(&mut self, client: &str) -> Option<Take> {
        let entry = self.clients.get_mut(client)?;
        let Some(job) = entry.queue.pop_front() else {
            entry.worker = false;
            return None;
        };
        // Its bytes count as in flight until `finish`.
        let session = match std::mem::replace(&mut entry.slot, Slot::Busy) {
            Slot::Idle(s) => Some(s),
            Slot::Empty | Slot::Busy => None,
        };
        Some(Take { job, session })
    }

    /// Records the answer to `job` (as sent) and gives back the session
    /// (`None` when it ended with this request).
    pub fn finish(&mut self, client: &str, job: &Job, session: Option<Session>, answer: Bytes, now: u64) {
        self.queued_bytes -= job.frame.len();
        let Some(entry) = self.clients.get_mut(client) else {
            return;
        };
        entry.slot = session.map_or(Slot::Empty, Slot::Idle);
        entry.last_request = entry.last_request.max(now);
        if let Some((_, stored)) = entry.dedup.stored.get_mut(&job.key) {
            entry.dedup.bytes += answer.len();
            self.bytes += answer.len();
            *stored = Stored::Kept(answer);
        }
        self.trim_bytes(client);
    }

    /// Ends the sessions idle for [`Limits::idle_ms`] and forgets request
    /// ids older than [`Limits::window_ms`]. The ended sessions are in
    /// [`Table::ended`].
    pub fn expire(&mut self, now: u64) {
        let limits = self.limits;
        for entry in self.clients.values_mut() {
            let (ids, bytes) = expire(&mut entry.dedup, now, limits.window_ms);
            self.ids -= ids;
            self.bytes -= bytes;
            let idle = now.saturating_sub(entry.last_request) >= limits.idle_ms;
            if idle
                && !entry.worker
                && matches!(entry.slot, Slot::Idle(_))
                && let Slot::Idle(s) = std::mem::replace(&mut entry.slot, Slot::Empty)
            {
                self.ended.push(s);
            }
        }
        self.clients.retain(|_, e| !e.is_empty());
    }

    /// Sessions that ended in the table since the last call, to close.
    pub fn ended(&mut self) -> Vec<Session> {
        std::mem::take(&mut self.ended)
    }

    /// Clients whose worker is running.
    pub fn workers(&self) -> usize {
        self.clients.values().filter(|e| e.worker).count()
    }

    /// Clients remembered.
    pub fn clients(&self) -> usize {
        self.clients.len()
    }

    /// Totals: bytes in flight, request ids remembered, bytes of stored
    /// answers.
    pub fn totals(&self) -> (usize, usize, usize) {
        (self.queued_bytes, self.ids, self.bytes)
    }

    /// Makes room for one more client; false when nothing can go.
    fn make_room(&mut self) -> bool {
        if self.clients.len() < self.limits.clients {
            return true;
        }
        let victim = self
            .clients
            .iter()
            .filter(|(_, e)| e.reclaimable())
            .min_by_key(|(_, e)| e.last_request)
            .map(|(name, _)| name.clone());
        let Some(entry) = victim.and_then(|name| self.clients.remove(&name)) else {
            return false;
        };
        self.ids -= entry.dedup.order.len();
        self.bytes -= entry.dedup.bytes;
        if let Slot::Idle(s) = entry.slot {
            self.ended.push(s);
        }
        true
    }

    /// Keeps the request ids within bounds: `client`'s own first, then the
    /// client holding the most.
    fn trim_ids(&mut self, client: &str) {
        let limits = self.limits;
        while let Some(entry) = self.clients.get_mut(client)
            && entry.dedup.order.len() > limits.ids
            && let Some(bytes) = forget_oldest(&mut entry.dedup)
        {
            self.ids -= 1;
            self.bytes -= bytes;
        }
        while self.ids > limits.ids_total
            && let Some(entry) = self.clients.values_mut().max_by_key(|e| e.dedup.order.len())
            && let Some(bytes) = forget_oldest(&mut entry.dedup)
        {
            self.ids -= 1;
            self.bytes -= bytes;
        }
    }

    /// Keeps the stored answers within bounds: `client`'s own first, then
    /// the client holding the most.
    fn trim_bytes(&mut self, client: &str) {
        let limits = self.limits;
        while let Some(entry) = self.clients.get_mut(client)
            && entry.dedup.bytes > limits.bytes
            && let Some(freed) = drop_oldest_answer(&mut entry.dedup)
        {
            self.bytes -= freed;
        }
        while self.bytes > limits.bytes_total
            && let Some(entry) = self.clients.values_mut().max_by_key(|e| e.dedup.bytes)
            && let Some(freed) = drop_oldest_answer(&mut entry.dedup)
        {
            self.bytes -= freed;
        }
    }
}

/// Forgets ids older than `window` (those in flight stay: their answer is
/// still to be stored); returns the ids and bytes freed.
fn expire(dedup: &mut Dedup, now: u64, window: u64) -> (usize, usize) {
    let (mut ids, mut bytes) = (0, 0);
    while let Some(key) = dedup.order.front().copied() {
        match dedup.stored.get(&key) {
            Some((at, stored)) if now.saturating_sub(*at) >= window && *stored != Stored::InFlight => {
                bytes += stored_len(stored);
                dedup.stored.remove(&key);
                dedup.order.pop_front();
                ids += 1;
            }
            _ => break,
        }
    }
    dedup.bytes -= bytes;
    (ids, bytes)
}

/// Forgets the oldest id that is not in flight; the bytes it held, or
/// `None` if every id is in flight.
fn forget_oldest(dedup: &mut Dedup) -> Option<usize> {
    let at = dedup
        .order
        .iter()
        .position(|key| dedup.stored.get(key).is_some_and(|(_, s)| *s != Stored::InFlight))?;
    let key = dedup.order.remove(at)?;
    let bytes = dedup.stored.remove(&key).map_or(0, |(_, s)| stored_len(&s));
    dedup.bytes -= bytes;
    Some(bytes)
}

/// Drops the oldest stored answer (its id stays); the bytes freed, or
/// `None` if no answer is stored.
fn drop_oldest_answer(dedup: &mut Dedup) -> Option<usize> {
    let stored = &mut dedup.stored;
    let key = dedup
        .order
        .iter()
        .find(|key| matches!(stored.get(*key), Some((_, Stored::Kept(_)))))?;
    let (_, slot) = stored.get_mut(key)?;
    let freed = stored_len(slot);
    *slot = Stored::Dropped;
    dedup.bytes -= freed;
    Some(freed)
}

fn stored_len(stored: &Stored) -> usize {
    match stored {
        Stored::Kept(b) => b.len(),
        Stored::InFlight | Stored::Dropped => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small() -> Limits {
        Limits {
            clients: 2,
            in_flight: 2,
            in_flight_bytes: 1000,
            window_ms: 1000,
            ids: 3,
            bytes: 20,
            ids_total: 100,
            bytes_total: 1000,
            idle_ms: 500,
        }
    }

    /// Runs `client`'s queue to the end, answering each request with its
    /// frame, and gives the session back logged in or not.
    fn run_all(t: &mut Table, client: &str, now: u64) -> usize {
        let mut ran = 0;
        while let Some(Take { job, session }) = t.take(client) {
            let answer = Bytes::from(job.frame.to_string());
            t.finish(client, &job, Some(session.unwrap_or_default()), answer, now);
            ran += 1;
        }
        ran
    }

    #[test]
    fn a_repeated_id_gets_the_stored_answer_and_never_runs_twice() {
        let mut t = Table::new(small());
        assert_eq!(t.request("c", "1", "state", 0), Admit::Start);
        assert_eq!(t.request("c", "1", "takeoff", 1), Admit::Running);
        assert_eq!(run_all(&mut t, "c", 2), 1);
        assert_eq!(
            t.request("c", "1", "takeoff", 3),
            Admit::Repeat(Bytes::from("state"))
        );
        assert_eq!(t.request("d", "1", "land", 3), Admit::Start, "ids are per client");
    }

    #[test]
    fn ids_are_forgotten_after_the_window() {
        let mut t = Table::new(small());
        assert_eq!(t.request("c", "1", "state", 0), Admit::Start);
        run_all(&mut t, "c", 0);
        assert!(matches!(t.request("c", "1", "state", 999), Admit::Repeat(_)));
        assert_eq!(t.request("c", "1", "state", 1000), Admit::Start);
    }

    #[test]
    fn beyond_the_in_flight_bound_requests_are_refused() {
        let mut t = Table::new(small());
        assert_eq!(t.request("c", "1", "a", 0), Admit::Start);
        assert_eq!(t.request("c", "2", "b", 0), Admit::Queued);
        assert_eq!(t.request("c", "3", "c", 0), Admit::TooMany);
        assert_eq!(run_all(&mut t, "c", 0), 2);
        assert_eq!(
            t.request("c", "3", "c", 0),
            Admit::Start,
            "a refused request was not remembered"
        );
    }

    #[test]
    fn answers_over_the_byte_bound_are_dropped_but_their_ids_still_refuse_a_rerun() {
        let mut t = Table::new(small());
        for id in ["1", "2"] {
            t.request("c", id, "0123456789abcdef", 0);
            run_all(&mut t, "c", 0);
        }
        assert_eq!(t.request("c", "1", "x", 1), Admit::Forgotten);
        assert!(matches!(t.request("c", "2", "x", 1), Admit::Repeat(_)));
        assert!(t.totals().2 <= 20);
    }

    #[test]
    fn the_oldest_ids_go_beyond_the_per_client_bound() {
        let mut t = Table::new(small());
        for id in ["1", "2", "3", "4"] {
            t.request("c", id, "s", 0);
            run_all(&mut t, "c", 0);
        }
        assert_eq!(t.totals().1, 3);
        assert_eq!(t.request("c", "1", "s", 0), Admit::Start);
    }

    #[test]
    fn a_full_table_lets_go_of_a_client_not_logged_in_but_never_of_a_busy_one() {
        let mut t = Table::new(small());
        t.request("a", "1", "s", 0);
        t.request("b", "1", "s", 1);
        assert_eq!(t.request("c", "1", "s", 2), Admit::Full, "both are running");
        run_all(&mut t, "a", 3);
        assert_eq!(t.request("c", "1", "s", 4), Admit::Start);
        assert_eq!(t.ended().len(), 1, "a's session is handed back to be closed");
        assert_eq!(t.clients(), 2);
    }

    #[test]
    fn idle_sessions_end_and_empty_clients_are_forgotten() {
        let mut t = Table::new(small());
        t.request("a", "1", "s", 0);
        run_all(&mut t, "a", 0);
        t.expire(499);
        assert!(t.ended().is_empty());
        t.expire(500);
        assert_eq!(t.ended().len(), 1);
        assert_eq!(t.clients(), 1, "its ids are still remembered");
        t.expire(1000);
        assert_eq!(t.clients(), 0);
        assert_eq!(t.totals(), (0, 0, 0));
    }
}
