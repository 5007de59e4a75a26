//! The uplink's request envelope and its per-client session table.
//!
//! Input: the first byte chooses. Even: the rest is a request envelope (a
//! broker message's payload): reading it never panics, accepts only ids of
//! 1-64 characters, and every answer written for it is JSON that carries
//! the id it read. Odd: the rest is a script of table operations, one per
//! byte pair (op, argument), on a table with small bounds: a request
//! (client, id, frame length from the argument), a worker taking and
//! finishing a client's next request (its session logged in or not), time
//! moving on. Checked after every step: a repeat gets exactly the answer
//! stored for that id, a request still running is never started again, a
//! worker is started only for a client that has none, and the totals stay
//! within the bounds.
#![no_main]

use std::collections::{HashMap, HashSet};

use bytes::Bytes;
use libfuzzer_sys::fuzz_target;
use lluav_core::Auth;
use lluav_host::uplink::envelope;
use lluav_host::uplink::table::{Admit, Limits, Table, Take};
use serde_json::Value;

const CLIENTS: [&str; 5] = ["a", "b", "c", "d", "e"];

fn envelope_case(payload: &[u8]) {
    let max = 64;
    match envelope::read(payload, max) {
        Ok(request) => {
            assert!(envelope::valid_id(&request.id));
            assert!(payload.len() <= max);
            let answer = envelope::response(Some(&request.id), r#"{"ret":0}"#);
            let v: Value = serde_json::from_str(&answer).expect("an answer is JSON");
            assert_eq!(v["id"], request.id.as_str());
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

struct Model {
    table: Table,
    auth: Auth,
    now: u64,
    /// What was stored as the answer to each (client, id).
    answers: HashMap<(usize, u8), Bytes>,
    /// Requests queued or running.
    running: HashSet<(usize, u8)>,
    /// Clients whose worker runs.
    workers: HashSet<usize>,
}

impl Model {
    fn request(&mut self, client: usize, id: u8, len: usize) {
        let frame = "x".repeat(len);
        let admit = self
            .table
            .request(CLIENTS[client], &id.to_string(), &frame, self.now);
        let key = (client, id);
        match admit {
            Admit::Start => {
                assert!(self.workers.insert(client), "a second worker for one client");
                assert!(self.running.insert(key), "started again while running");
            }
            Admit::Queued => {
                assert!(self.workers.contains(&client), "queued with no worker");
                assert!(self.running.insert(key), "queued again while running");
            }
            Admit::Running => assert!(self.running.contains(&key), "running, but it is not"),
            Admit::Repeat(answer) => assert_eq!(self.answers.get(&key), Some(&answer), "a wrong repeat"),
            Admit::Forgotten => assert!(self.answers.contains_key(&key), "forgotten, never answered"),
            Admit::TooMany | Admit::Full => {}
        }
    }

    fn work(&mut self, client: usize, logged_in: bool) {
        match self.table.take(CLIENTS[client]) {
            None => {
                self.workers.remove(&client);
            }
            Some(Take { job, session }) => {
                let id: u8 = job.id.parse().expect("an id the script made");
                assert!(self.running.remove(&(client, id)), "took a request not queued");
                let mut session = session.unwrap_or_default();
                if logged_in {
                    self.auth.login(&mut session, "pw-fuzz", 0);
                }
                let answer = Bytes::from(format!("{client}/{id}/{}", job.frame.len()));
                self.table
                    .finish(CLIENTS[client], &job, Some(session), answer.clone(), self.now);
                self.answers.insert((client, id), answer);
            }
        }
    }

    fn check(&mut self) {
        let limits = *self.table.limits();
        let (in_flight, ids, bytes) = self.table.totals();
        assert!(in_flight <= limits.in_flight_bytes);
        assert!(ids <= limits.ids_total + limits.in_flight * CLIENTS.len());
        assert!(bytes <= limits.bytes_total);
        assert!(self.table.clients() <= limits.clients);
        let _ = self.table.ended();
    }
}

fn table_case(script: &[u8]) {
    let limits = Limits {
        clients: 3,
        in_flight: 3,
        in_flight_bytes: 40,
        window_ms: 1_000,
        ids: 6,
        bytes: 24,
        ids_total: 10,
        bytes_total: 40,
        idle_ms: 300,
    };
    let mut m = Model {
        table: Table::new(limits),
        auth: Auth::new(Some("pw-fuzz")).expect("a valid password"),
        now: 0,
        answers: HashMap::new(),
        running: HashSet::new(),
        workers: HashSet::new(),
    };
    for step in script.chunks(2) {
        let (op, arg) = (step[0], step.get(1).copied().unwrap_or(0));
        let client = usize::from(op >> 4) % CLIENTS.len();
        match op % 4 {
            0 | 1 => m.request(client, arg % 16, usize::from(arg >> 4)),
            2 => m.work(client, arg & 1 == 1),
            _ => {
                m.now += u64::from(arg) * 8;
                m.table.expire(m.now);
            }
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
