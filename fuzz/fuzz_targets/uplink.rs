//! The uplink's request envelope, its session table and id store, and the
//! durable store's replay.
//!
//! Input: the first byte chooses. Even: the rest is a request envelope (a
//! broker message's payload): reading it never panics, accepts only ids of
//! 1-64 characters and JSON without a member named twice (checked against
//! serde_json, and by naming `frame` twice in every envelope it accepts),
//! and every answer written for it is JSON that carries the id it read.
//! Odd: the rest is a script of operations, one per byte pair (op,
//! argument), on a table with small bounds: a request (client, id, frame
//! length, an expiry), a worker taking a client's next request (writing
//! its start to the durable log when it changes the vehicle), a worker
//! answering it (the answer written to the log first), time moving on,
//! and a restart: a new table from what the log replays. Checked after
//! every step: an id is admitted again only after its window, or after a
//! restart when it had not started or did not change the vehicle; a
//! repeat gets exactly the answer stored for that id, also across a
//! restart (or the -3 of one interrupted by it); copies are counted; one
//! request of a client runs at a time; the totals stay within the bounds.
#![no_main]

use std::collections::{HashMap, HashSet};

use bytes::Bytes;
use libfuzzer_sys::fuzz_target;
use lluav_core::Auth;
use lluav_host::json;
use lluav_host::uplink::durable::{self, Entry, Outcome};
use lluav_host::uplink::envelope;
use lluav_host::uplink::table::{Admit, Job, Limits, Restored, Table, Take};
use serde_json::Value;

const CLIENTS: [&str; 5] = ["a", "b", "c", "d", "e"];
const WINDOW: u64 = 1_000;

fn envelope_case(payload: &[u8]) {
    let max = 64;
    match (json::read(payload), serde_json::from_slice::<Value>(payload)) {
        (Ok((value, None)), Ok(theirs)) => assert_eq!(value, theirs, "read as serde_json reads it"),
        (Ok((_, Some(_))), Ok(_)) => {}
        (Err(_), Err(_)) => {}
        (ours, theirs) => panic!("JSON or not: {:?} vs {:?}", ours.is_ok(), theirs.is_ok()),
    }
    match envelope::read(payload, max) {
        Ok(request) => {
            assert!(envelope::valid_id(&request.id));
            assert!(payload.len() <= max);
            let answer = envelope::response(Some(&request.id), r#"{"ret":0}"#);
            let v: Value = serde_json::from_str(&answer).expect("an answer is JSON");
            assert_eq!(v["id"], request.id.as_str());
            // The same envelope naming "frame" once more is refused.
            let at = payload.iter().position(|b| *b == b'{').expect("an object");
            let mut twice = payload[..=at].to_vec();
            twice.extend_from_slice(br#""frame":"login 1025","#);
            twice.extend_from_slice(&payload[at + 1..]);
            let refused = envelope::read(&twice, twice.len()).expect_err("a member named twice");
            assert_eq!(
                refused.why.to_string(),
                r#"duplicate member "frame""#,
                "{:?}",
                String::from_utf8_lossy(&twice)
            );
            assert_eq!(refused.id.as_deref(), Some(request.id.as_str()));
        }
        Err(refused) => {
            if let Some(id) = &refused.id {
                assert!(envelope::valid_id(id));
            }
            let answer = envelope::refused(&refused, 7);
            let v: Value = serde_json::from_str(&answer).expect("a refusal is JSON");
            assert_eq!(v["id"].as_str(), refused.id.as_deref());
            assert_eq!(v["response"]["ret"], -2);
        }
    }
}

/// What the model knows of one (client, id).
#[derive(Clone, Debug)]
struct Known {
    /// When it was admitted.
    at: u64,
    /// Its command changes the vehicle: its answer is in the log.
    durable: bool,
    /// The restart count when it was admitted.
    epoch: u32,
    /// A worker took it.
    started: bool,
    /// When its Message Expiry passes, if it has one.
    expires: Option<u64>,
    /// Dropped unrun (its expiry passed), or lost unrun with a restart.
    dropped: bool,
    /// Its answer, once given (or restored).
    answer: Option<Bytes>,
    /// Copies counted while it ran.
    copies: u16,
}

struct Model {
    table: Table,
    auth: Auth,
    now: u64,
    epoch: u32,
    known: HashMap<(usize, u8), Known>,
    /// Requests taken and not answered, per client.
    running: HashMap<usize, (Job, Option<lluav_core::Session>)>,
    /// The durable log: one line per record.
    log: Vec<String>,
}

fn key_of(client: &str, id: &str) -> (usize, u8) {
    let c = CLIENTS.iter().position(|n| *n == client).expect("a known client");
    (c, id.parse().expect("an id the script made"))
}

fn interrupted(id: &str) -> Bytes {
    let response = envelope::error(
        lluav_core::Ret::SystemCall,
        9,
        0,
        "Interrupted by a restart; check state",
    );
    Bytes::from(envelope::response(Some(id), &response))
}

impl Model {
    fn new(limits: Limits) -> Model {
        Model {
            table: Table::new(limits),
            auth: Auth::new(Some("pw-fuzz")).expect("a valid password"),
            now: WINDOW,
            epoch: 0,
            known: HashMap::new(),
            running: HashMap::new(),
            log: Vec::new(),
        }
    }

    fn request(&mut self, client: usize, id: u8, len: usize, expiry: Option<u64>) {
        let frame = "x".repeat(len);
        let expires = expiry.map(|e| self.now + e);
        let admit = self
            .table
            .request(CLIENTS[client], &id.to_string(), &frame, self.now, expires);
        let key = (client, id);
        match admit {
            Admit::Queued => {
                if let Some(k) = self.known.get(&key) {
                    let window_over = self.now - k.at >= WINDOW;
                    let lost = k.epoch < self.epoch && (!k.durable || !k.started);
                    assert!(window_over || lost || k.dropped, "admitted again: {key:?} {k:?}");
                }
                self.known.insert(
                    key,
                    Known {
                        at: self.now,
                        durable: len % 2 == 1,
                        epoch: self.epoch,
                        started: false,
                        expires,
                        dropped: false,
                        answer: None,
                        copies: 0,
                    },
                );
            }
            Admit::Copy => {
                let k = self.known.get_mut(&key).expect("a copy of a known request");
                assert!(k.answer.is_none() && k.epoch == self.epoch, "{k:?}");
                k.copies += 1;
            }
            Admit::Ignored => {
                let k = &self.known[&key];
                assert!(k.answer.is_none() && k.copies >= self.table.limits().copies);
            }
            Admit::Repeat(answer) => {
                let k = &self.known[&key];
                assert_eq!(k.answer.as_ref(), Some(&answer), "a wrong repeat of {key:?}");
            }
            Admit::Forgotten => {
                assert!(self.known[&key].answer.is_some(), "forgotten, never answered")
            }
            Admit::TooMany | Admit::IdsFull | Admit::Full => {}
        }
    }

    fn start(&mut self) {
        let (take, expired) = self.table.take(self.now);
        // What expired by now may have been dropped unrun (the table drops
        // those it meets on its way to the next request).
        if expired > 0 {
            let now = self.now;
            let mut could = 0;
            for k in self.known.values_mut() {
                if k.epoch == self.epoch && !k.started && k.expires.is_some_and(|e| e <= now) {
                    k.dropped = true;
                    could += 1;
                }
            }
            assert!(expired <= could, "{expired} dropped, {could} expired");
        }
        let Some(Take { client, job, session }) = take else {
            return;
        };
        let key = key_of(&client, &job.id);
        let c = key.0;
        assert!(
            !self.running.contains_key(&c),
            "two requests of one client at once"
        );
        let k = self.known.get_mut(&key).expect("a known request");
        assert!(!k.started, "taken twice: {key:?}");
        k.started = true;
        if k.durable {
            self.log.push(durable::line(Entry::Started {
                client: client.to_string(),
                id: job.id.to_string(),
                at: k.at as i64,
                cmd: 9,
            }));
        }
        self.running.insert(c, (job, session));
    }

    fn answer(&mut self, client: usize, logged_in: bool) {
        let Some((job, session)) = self.running.remove(&client) else {
            return;
        };
        let key = key_of(CLIENTS[client], &job.id);
        let answer = Bytes::from(format!("{client}/{}/{}/{}", job.id, job.frame.len(), self.epoch));
        let k = self.known.get_mut(&key).expect("a known request");
        if k.durable {
            self.log.push(durable::line(Entry::Answered {
                client: CLIENTS[client].to_owned(),
                id: job.id.to_string(),
                at: k.at as i64,
                answer: Some(String::from_utf8_lossy(&answer).into_owned()),
            }));
        }
        let copies = self.table.answered(&job, answer.clone());
        assert_eq!(copies, k.copies, "copies of {key:?}");
        k.answer = Some(answer);
        let mut session = session.unwrap_or_default();
        if logged_in {
            self.auth.login(&mut session, "pw-fuzz", 0);
        }
        self.table.release(CLIENTS[client], &job, Some(session));
    }

    /// lluavd stops (whatever it was doing) and starts again from the log.
    fn restart(&mut self) {
        let limits = *self.table.limits();
        self.table = Table::new(limits);
        self.running.clear();
        self.epoch += 1;
        let found = durable::replay(&self.log, self.now as i64, WINDOW as i64);
        let restored: HashSet<(usize, u8)> = found.iter().map(|f| key_of(&f.client, &f.id)).collect();
        for f in found {
            let key = key_of(&f.client, &f.id);
            let age = self.now.saturating_sub(f.at as u64);
            let (restored, answer) = match f.outcome {
                Outcome::Answered(a) => {
                    let a = Bytes::from(a);
                    (Restored::Answer(a.clone()), Some(a))
                }
                Outcome::AnsweredNotKept => (Restored::Answered, None),
                Outcome::Interrupted(_) => {
                    let a = interrupted(&f.id);
                    (Restored::Answer(a.clone()), Some(a))
                }
            };
            self.table.restore(&f.client, &f.id, age, self.now, restored);
            let k = self.known.get_mut(&key).expect("a known request");
            assert!(k.durable && k.started, "restored what was not recorded: {key:?}");
            k.answer = answer;
        }
        // What was not restored is forgotten: it may come again.
        for (key, k) in &mut self.known {
            if !restored.contains(key) && k.answer.is_none() {
                k.dropped = true;
            }
        }
    }

    fn tick(&mut self, ms: u64) {
        self.now += ms;
        self.table.expire(self.now);
        let _ = self.table.ended();
    }

    fn check(&mut self) {
        let limits = *self.table.limits();
        let (in_flight, bytes, ids, kept) = self.table.totals();
        assert!(in_flight <= limits.in_flight_total);
        assert!(bytes <= limits.in_flight_bytes);
        assert!(ids <= limits.ids_total);
        assert!(kept <= limits.bytes_total);
        assert!(self.table.clients() <= limits.clients);
        let _ = self.table.ended();
    }
}

fn table_case(script: &[u8]) {
    let limits = Limits {
        clients: 3,
        in_flight: 3,
        in_flight_total: 8,
        in_flight_bytes: 40,
        window_ms: WINDOW,
        ids: 6,
        ids_total: 10,
        bytes: 24,
        bytes_total: 40,
        copies: 2,
        idle_ms: 300,
    };
    let mut m = Model::new(limits);
    for step in script.chunks(2) {
        let (op, arg) = (step[0], step.get(1).copied().unwrap_or(0));
        let client = usize::from(op >> 4) % CLIENTS.len();
        match op % 8 {
            0..=2 => {
                let expiry = (op & 8 != 0).then(|| u64::from(arg & 7) * 50);
                m.request(client, arg % 16, usize::from(arg >> 4), expiry)
            }
            3 => m.start(),
            4 | 5 => m.answer(client, arg & 1 == 1),
            6 => m.tick(u64::from(arg) * 8),
            _ if arg < 64 => m.restart(),
            _ => m.tick(1),
        }
        m.check();
    }
}

fuzz_target!(|data: &[u8]| {
    let Some((&first, rest)) = data.split_first() else {
        return;
    };
    if first % 2 == 0 {
        envelope_case(rest);
    } else {
        table_case(rest);
    }
});
