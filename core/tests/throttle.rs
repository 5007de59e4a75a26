//! Password guessing limited per client, with a table that cannot be
//! flushed and a budget across all clients (DESIGN.md, "Sessions and
//! gates").

mod common;

use std::cell::Cell;
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
use std::rc::Rc;

use common::*;
use lluav_core::throttle::{DEFAULT_RATE, MAX_WRONG_PASSWORDS, Slot, THROTTLE_CAPACITY, Throttle};
use lluav_core::{Auth, Message, Outcome, Peer, Server, Session};
use proptest::prelude::*;

const THROTTLED: &str = "Too many wrong passwords, retry later";
const WRONG: &str = "Wrong password!";
const BASE_MS: u32 = 30_000;
const MAX_MS: u32 = 15 * 60_000;
/// A budget too large to matter, for the tests of the per-client rules.
const UNLIMITED: u16 = 1000;

/// A server with a clock the test moves and a table of any size.
type Rigged = Server<MockVehicle, Box<dyn Fn() -> i64>, Box<[Slot]>>;

/// A server whose clock the test moves.
struct Rig {
    now: Rc<Cell<i64>>,
    server: Rigged,
}

impl Rig {
    /// The default table, without a budget that matters.
    fn new() -> Rig {
        Rig::with(THROTTLE_CAPACITY, UNLIMITED)
    }

    /// A table of `capacity` records and a budget of `rate` per second.
    fn with(capacity: usize, rate: u16) -> Rig {
        let now = Rc::new(Cell::new(TS));
        let clock = Rc::clone(&now);
        let throttle = Throttle::new(BASE_MS, MAX_MS)
            .with_table(vec![Slot::EMPTY; capacity].into_boxed_slice())
            .with_rate(rate);
        let auth = Auth::new(Some("pw")).unwrap().with_throttle(throttle);
        Rig {
            now,
            server: Server::new(MockVehicle::default(), Box::new(move || clock.get()), auth),
        }
    }

    fn open(&mut self, peer: impl Into<Who>) -> Session {
        self.server.open(Some(peer.into().0))
    }

    fn advance(&mut self, ms: u32) {
        self.now.set(self.now.get() + i64::from(ms));
    }

    /// Ret and message of one login, on a connection of its own.
    fn login(&mut self, peer: impl Into<Who>, password: &str) -> (i64, String) {
        let mut session = self.open(peer);
        self.login_on(&mut session, password)
    }

    fn login_on(&mut self, session: &mut Session, password: &str) -> (i64, String) {
        let v = self.login_answer(session, password);
        (
            v["ret"].as_i64().unwrap(),
            v["msg"].as_str().unwrap_or("").to_owned(),
        )
    }

    /// The whole answer to one login.
    fn login_answer(&mut self, session: &mut Session, password: &str) -> serde_json::Value {
        let frame = format!("login {password}");
        let mut out = vec![0u8; 4096];
        let outcome = self
            .server
            .handle(session, Message::Text(frame.as_bytes()), &mut out);
        checked_json(outcome.reply().expect("login is always answered"))
    }

    /// `retry_after_s` of a login from `peer` on a connection of its own
    /// (`None` when the answer has none).
    fn retry_after(&mut self, peer: impl Into<Who>, password: &str) -> Option<u64> {
        let mut session = self.open(peer);
        self.login_answer(&mut session, password)["retry_after_s"].as_u64()
    }

    /// Five wrong passwords from `peer`, each on a new connection.
    fn guess_five_times(&mut self, peer: impl Into<Who> + Copy) {
        for i in 0..MAX_WRONG_PASSWORDS {
            assert_eq!(self.login(peer, "guess"), (-1, WRONG.into()), "guess {i}");
        }
    }
}

/// Whoever a test connects as: an address or a client key.
struct Who(Peer);

impl From<Ipv4Addr> for Who {
    fn from(a: Ipv4Addr) -> Who {
        Who(IpAddr::from(a).into())
    }
}

impl From<Ipv6Addr> for Who {
    fn from(a: Ipv6Addr) -> Who {
        Who(IpAddr::from(a).into())
    }
}

impl From<Peer> for Who {
    fn from(p: Peer) -> Who {
        Who(p)
    }
}

const ATTACKER: Ipv4Addr = Ipv4Addr::new(192, 168, 1, 66);
const OPERATOR: Ipv4Addr = Ipv4Addr::new(192, 168, 1, 10);

#[test]
fn five_wrong_passwords_across_connections_lock_the_address_out() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    assert_eq!(rig.login(ATTACKER, "guess"), (-1, THROTTLED.into()));
}

#[test]
fn a_locked_out_address_is_refused_without_checking_the_password() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    for right in ["pw", "1025", "0315"] {
        assert_eq!(rig.login(ATTACKER, right), (-1, THROTTLED.into()), "{right}");
    }
    let mut session = rig.open(ATTACKER);
    let mut out = vec![0u8; 4096];
    let outcome = rig.server.handle(&mut session, Message::Text(b"state"), &mut out);
    assert_eq!(checked_json(outcome.reply().unwrap())["msg"], "Login first!");
}

#[test]
fn a_login_refused_by_the_lockout_says_when_to_retry() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    let mut session = rig.open(ATTACKER);
    let v = rig.login_answer(&mut session, "pw");
    assert_eq!(
        (v["ret"].as_i64(), v["msg"].as_str()),
        (Some(-1), Some(THROTTLED))
    );
    assert_eq!(v["retry_after_s"], 30, "{v}");
    // Whole in the smallest buffer every error fits.
    let mut small = vec![0u8; lluav_core::MIN_RESPONSE_CAPACITY];
    let outcome = rig
        .server
        .handle(&mut session, Message::Text(b"login pw"), &mut small);
    assert_eq!(
        checked_json(outcome.reply().expect("answered"))["retry_after_s"],
        30
    );
    rig.advance(10_000);
    assert_eq!(rig.retry_after(ATTACKER, "pw"), Some(20));
    rig.advance(19_500);
    assert_eq!(
        rig.retry_after(ATTACKER, "pw"),
        Some(1),
        "whole seconds, rounded up"
    );
    rig.advance(500);
    assert_eq!(
        rig.login(ATTACKER, "guess"),
        (-1, WRONG.into()),
        "checked again, as promised"
    );
    assert_eq!(
        rig.retry_after(OPERATOR, "guess"),
        None,
        "no retry_after_s unless throttled"
    );
    for _ in 1..MAX_WRONG_PASSWORDS {
        rig.login(ATTACKER, "guess");
    }
    assert_eq!(
        rig.retry_after(ATTACKER, "pw"),
        Some(60),
        "the second lockout doubles"
    );
}

#[test]
fn a_login_refused_for_a_full_table_or_a_spent_budget_says_when_to_retry() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    for i in 1..THROTTLE_CAPACITY {
        rig.advance(1);
        rig.login(Ipv4Addr::new(10, 0, 0, u8::try_from(i).unwrap()), "guess");
    }
    // Full: the first record that stops mattering is the attacker's, at
    // the end of its lockout, 30 s after the first guess.
    let elapsed = u32::try_from(THROTTLE_CAPACITY - 1).unwrap();
    assert_eq!(rig.retry_after(OPERATOR, "pw"), Some(30));
    rig.advance(BASE_MS - elapsed);
    assert_eq!(rig.login(OPERATOR, "pw").0, 0, "room at the time it said");

    const RATE: u16 = 4;
    let mut rig = Rig::with(1024, RATE);
    for i in 0..u32::from(RATE) {
        rig.login(Ipv4Addr::new(10, 2, 0, i as u8), "guess");
    }
    // One check per 250 ms: a second at most, in whole seconds.
    assert_eq!(rig.retry_after(OPERATOR, "pw"), Some(1));
    rig.advance(250);
    assert_eq!(rig.login(OPERATOR, "pw").0, 0);
}

#[test]
fn other_addresses_are_not_locked_out() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    assert_eq!(rig.login(OPERATOR, "pw").0, 0);
}

#[test]
fn the_lockout_ends_after_its_time_and_doubles_each_time_up_to_the_maximum() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    for round in 0..8u32 {
        let lockout = (BASE_MS << round).min(MAX_MS);
        rig.advance(lockout - 1);
        assert_eq!(rig.login(ATTACKER, "pw"), (-1, THROTTLED.into()), "round {round}");
        rig.advance(1);
        // Over: the password is checked again, and counted.
        assert_eq!(
            rig.login(ATTACKER, "guess"),
            (-1, "Wrong password!".into()),
            "round {round}"
        );
        for _ in 1..MAX_WRONG_PASSWORDS {
            rig.login(ATTACKER, "guess");
        }
    }
    rig.advance(MAX_MS);
    assert_eq!(rig.login(ATTACKER, "pw").0, 0);
}

#[test]
fn a_login_that_grants_access_after_the_lockout_clears_the_record() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    rig.advance(BASE_MS);
    assert_eq!(rig.login(ATTACKER, "pw").0, 0);
    // A fresh record: four wrong passwords do not lock out, and the next
    // lockout is the first one again.
    for _ in 1..MAX_WRONG_PASSWORDS {
        rig.login(ATTACKER, "guess");
    }
    assert_eq!(rig.login(ATTACKER, "pw").0, 0);
    rig.guess_five_times(ATTACKER);
    rig.advance(BASE_MS);
    assert_eq!(rig.login(ATTACKER, "pw").0, 0);
}

#[test]
fn the_logout_value_does_not_reset_the_counts() {
    let mut rig = Rig::new();
    let mut session = rig.open(ATTACKER);
    for _ in 1..MAX_WRONG_PASSWORDS {
        assert_eq!(rig.login_on(&mut session, "guess").0, -1);
        assert_eq!(rig.login_on(&mut session, "0315").0, 0);
    }
    let mut out = vec![0u8; 4096];
    let outcome = rig
        .server
        .handle(&mut session, Message::Text(b"login guess"), &mut out);
    assert!(
        matches!(outcome, Outcome::ReplyThenClose(_, code) if code.code() == 1008),
        "the fifth wrong password in the session closes it: {outcome:?}"
    );
    assert_eq!(rig.login(ATTACKER, "pw"), (-1, THROTTLED.into()));
}

#[test]
fn ipv6_addresses_count_by_their_64_prefix_and_mapped_ipv4_as_ipv4() {
    let mut rig = Rig::new();
    for host in 0..u16::from(MAX_WRONG_PASSWORDS) {
        rig.login(Ipv6Addr::new(0x2001, 0xdb8, 0, 7, 0, 0, 0, host), "guess");
    }
    assert_eq!(
        rig.login(Ipv6Addr::new(0x2001, 0xdb8, 0, 7, 9, 9, 9, 9), "pw").1,
        THROTTLED
    );
    assert_eq!(
        rig.login(Ipv6Addr::new(0x2001, 0xdb8, 0, 8, 0, 0, 0, 1), "pw").0,
        0
    );
    rig.guess_five_times(ATTACKER);
    assert_eq!(rig.login(ATTACKER.to_ipv6_mapped(), "pw").1, THROTTLED);
}

#[test]
fn a_full_table_never_drops_a_locked_address_and_checks_no_password_from_a_new_one() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    for i in 1..THROTTLE_CAPACITY {
        rig.advance(1);
        let other = Ipv4Addr::new(10, 0, 0, u8::try_from(i).unwrap());
        assert_eq!(rig.login(other, "guess"), (-1, WRONG.into()));
    }
    // Full of records that still matter: a newcomer's password is not
    // checked, right or wrong, and the locked address stays locked.
    for password in ["pw", "guess"] {
        assert_eq!(rig.login(OPERATOR, password), (-1, THROTTLED.into()));
    }
    assert_eq!(rig.login(ATTACKER, "pw"), (-1, THROTTLED.into()));
    // A recorded address is still checked.
    assert_eq!(rig.login(Ipv4Addr::new(10, 0, 0, 1), "pw").0, 0);
}

#[test]
fn a_record_idle_for_a_first_lockout_makes_room_but_a_locked_one_never_does() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    for i in 1..THROTTLE_CAPACITY {
        rig.advance(1);
        rig.login(Ipv4Addr::new(10, 0, 0, u8::try_from(i).unwrap()), "guess");
    }
    rig.advance(BASE_MS);
    // The one-guess records are spent now, and so is the attacker's first
    // lockout; the newcomer takes the slot idle longest: the attacker's.
    assert_eq!(rig.login(OPERATOR, "guess"), (-1, WRONG.into()));
    assert_eq!(rig.login(OPERATOR, "pw").0, 0);
    // Locked twice, for 60 s: still locked when its last guess is one
    // first lockout old, so a flood of newcomers cannot push it out.
    rig.guess_five_times(ATTACKER);
    rig.advance(BASE_MS);
    rig.guess_five_times(ATTACKER);
    for i in 1..THROTTLE_CAPACITY {
        rig.advance(1);
        rig.login(Ipv4Addr::new(10, 0, 2, u8::try_from(i).unwrap()), "guess");
    }
    rig.advance(BASE_MS);
    for i in 1..THROTTLE_CAPACITY {
        rig.advance(1);
        let newcomer = Ipv4Addr::new(10, 0, 3, u8::try_from(i).unwrap());
        assert_eq!(rig.login(newcomer, "guess"), (-1, WRONG.into()));
    }
    assert_eq!(rig.login(ATTACKER, "pw"), (-1, THROTTLED.into()));
    rig.advance(2 * BASE_MS);
    assert_eq!(rig.login(ATTACKER, "pw").0, 0);
}

#[test]
fn a_host_sized_table_remembers_thousands_of_addresses() {
    let mut rig = Rig::with(4096, UNLIMITED);
    rig.guess_five_times(ATTACKER);
    for i in 0..4000u32 {
        rig.advance(1);
        let [_, _, a, b] = i.to_be_bytes();
        assert_eq!(rig.login(Ipv4Addr::new(10, 1, a, b), "guess"), (-1, WRONG.into()));
    }
    assert_eq!(rig.login(ATTACKER, "pw"), (-1, THROTTLED.into()));
    assert_eq!(rig.login(OPERATOR, "pw").0, 0);
}

#[test]
fn the_budget_limits_wrong_passwords_checked_across_all_addresses() {
    const RATE: u16 = 4;
    let mut rig = Rig::with(1024, RATE);
    let many = |i: u32| Ipv4Addr::new(10, 2, (i >> 8) as u8, i as u8);
    // A burst of RATE wrong passwords from as many addresses is checked;
    // then nothing is, not even the right password, from anyone.
    for i in 0..u32::from(RATE) {
        assert_eq!(rig.login(many(i), "guess"), (-1, WRONG.into()), "guess {i}");
    }
    assert_eq!(rig.login(many(99), "guess"), (-1, THROTTLED.into()));
    assert_eq!(rig.login(OPERATOR, "pw"), (-1, THROTTLED.into()));
    // It refills at RATE per second: one check per 250 ms, whoever sends.
    let mut checked = 0;
    for step in 0..4000u32 {
        rig.advance(1);
        if rig.login(many(100 + step), "guess").1 == WRONG {
            checked += 1;
        }
    }
    assert_eq!(checked, 4 * u32::from(RATE), "four seconds, {RATE} per second");
    rig.advance(250);
    assert_eq!(rig.login(OPERATOR, "pw").0, 0, "a right password spends nothing");
    assert_eq!(rig.login(OPERATOR, "pw").0, 0);
}

#[test]
fn the_default_budget_checks_one_sessions_five_guesses_at_once() {
    let mut rig = Rig::with(THROTTLE_CAPACITY, DEFAULT_RATE);
    let mut session = rig.open(ATTACKER);
    for _ in 1..MAX_WRONG_PASSWORDS {
        assert_eq!(rig.login_on(&mut session, "guess"), (-1, WRONG.into()));
    }
    let mut out = vec![0u8; 4096];
    let outcome = rig
        .server
        .handle(&mut session, Message::Text(b"login guess"), &mut out);
    assert!(matches!(outcome, Outcome::ReplyThenClose(_, code) if code.code() == 1008));
}

#[test]
fn client_keys_are_throttled_apart_from_each_other_and_from_addresses() {
    let mut rig = Rig::new();
    let mallory = Peer::Client([0xAA; 16]);
    rig.guess_five_times(mallory);
    assert_eq!(rig.login(mallory, "pw"), (-1, THROTTLED.into()));
    assert_eq!(rig.login(Peer::Client([0xAB; 16]), "pw").0, 0);
    assert_eq!(rig.login(Ipv4Addr::new(170, 170, 170, 170), "pw").0, 0);
}

#[test]
fn sessions_without_an_address_are_limited_per_connection_only() {
    let mut s = server(Some("pw"));
    for _ in 0..3 {
        let mut sess = Session::new();
        for _ in 1..MAX_WRONG_PASSWORDS {
            assert_eq!(send(&mut s, &mut sess, "login guess").msg(), WRONG);
        }
    }
    assert_eq!(send(&mut s, &mut Session::new(), "login pw").ret(), 0);
}

/// What one step of a guessing scenario sends.
#[derive(Clone, Debug)]
enum Attempt {
    Wrong,
    Right,
    Logout,
}

/// Table capacity and budget of the property below: small, so that a few
/// addresses fill the table and a few steps spend the budget.
const MODEL_SLOTS: usize = 4;
const MODEL_RATE: u16 = 3;

/// One address's history in the model.
struct Entry {
    wrong: u8,
    lockouts: u32,
    until: i64,
    last_wrong: i64,
}

/// The rules of DESIGN.md, written out plainly, for the property below.
struct Model {
    records: HashMap<u8, Entry>,
    /// The budget, as milliseconds of refill banked: a check needs one
    /// interval's worth, and at most `MODEL_RATE` intervals are banked.
    credit: i64,
    at: i64,
}

impl Model {
    // 1000 ms / MODEL_RATE, rounded up: never more than the rate.
    const INTERVAL: i64 = (1000 + MODEL_RATE as i64 - 1) / MODEL_RATE as i64;

    fn new(now: i64) -> Model {
        Model {
            records: HashMap::new(),
            credit: Model::INTERVAL * i64::from(MODEL_RATE),
            at: now,
        }
    }

    /// Whether a record may go to make room.
    fn spent(e: &Entry, now: i64) -> bool {
        now >= e.until && now - e.last_wrong >= i64::from(BASE_MS)
    }

    fn login(&mut self, addr: u8, attempt: &Attempt, now: i64) -> &'static str {
        let full = Model::INTERVAL * i64::from(MODEL_RATE);
        self.credit = (self.credit + (now - self.at)).min(full);
        self.at = now;
        match self.records.get(&addr) {
            Some(e) if now < e.until => return THROTTLED,
            Some(_) => {}
            None => {
                let room =
                    self.records.len() < MODEL_SLOTS || self.records.values().any(|e| Model::spent(e, now));
                if !room {
                    return THROTTLED;
                }
            }
        }
        if self.credit < Model::INTERVAL {
            return THROTTLED;
        }
        match attempt {
            Attempt::Right => {
                self.records.remove(&addr);
                ""
            }
            Attempt::Logout => "",
            Attempt::Wrong => {
                self.credit -= Model::INTERVAL;
                self.wrong(addr, now);
                WRONG
            }
        }
    }

    fn wrong(&mut self, addr: u8, now: i64) {
        if !self.records.contains_key(&addr) && self.records.len() == MODEL_SLOTS {
            let oldest = self
                .records
                .iter()
                .filter(|(_, e)| Model::spent(e, now))
                .min_by_key(|(_, e)| e.last_wrong)
                .map(|(a, _)| *a);
            self.records.remove(&oldest.expect("room was checked"));
        }
        let e = self.records.entry(addr).or_insert(Entry {
            wrong: 0,
            lockouts: 0,
            until: i64::MIN,
            last_wrong: now,
        });
        e.wrong += 1;
        e.last_wrong = now;
        if e.wrong == MAX_WRONG_PASSWORDS {
            let ms = (u64::from(BASE_MS) << e.lockouts).min(u64::from(MAX_MS));
            e.until = now + i64::try_from(ms).unwrap();
            e.lockouts += 1;
            e.wrong = 0;
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Whatever the interleaving of addresses, connections and waits, the
    /// server answers every login as the plainly written rules say: no
    /// address gets a sixth checked guess inside a lockout, a full table
    /// drops no record that still matters, and no more wrong passwords are
    /// checked than the budget allows. (Every step moves the clock, so that
    /// no two records were touched at the same millisecond and "idle
    /// longest" is one record.)
    #[test]
    fn logins_follow_the_per_address_rules_and_the_budget(
        steps in prop::collection::vec(
            (0u8..7, prop_oneof![3 => Just(Attempt::Wrong), 1 => Just(Attempt::Right), 1 => Just(Attempt::Logout)],
             prop_oneof![1u32..400, 400u32..2_000, 25_000u32..70_000]),
            1..160,
        ),
    ) {
        let mut rig = Rig::with(MODEL_SLOTS, MODEL_RATE);
        let mut model = Model::new(rig.now.get());
        for (addr, attempt, wait) in steps {
            rig.advance(wait);
            let ip = Ipv4Addr::new(172, 16, 0, addr);
            let password = match attempt {
                Attempt::Wrong => "guess",
                Attempt::Right => "pw",
                Attempt::Logout => "0315",
            };
            let expected = model.login(addr, &attempt, rig.now.get());
            let (ret, msg) = rig.login(ip, password);
            prop_assert_eq!(msg.as_str(), expected);
            prop_assert_eq!(ret, if expected.is_empty() { 0 } else { -1 });
        }
    }
}
