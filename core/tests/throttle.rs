//! Password guessing limited per session and per client address
//! (DESIGN.md, "Sessions and gates").

mod common;

use std::cell::Cell;
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
use std::rc::Rc;

use common::*;
use lluav_core::throttle::{MAX_WRONG_PASSWORDS, THROTTLE_CAPACITY};
use lluav_core::{Auth, Message, Outcome, Server, Session};
use proptest::prelude::*;

const THROTTLED: &str = "Too many wrong passwords, retry later";
const BASE_MS: u32 = 30_000;
const MAX_MS: u32 = 15 * 60_000;

/// A server whose clock the test moves.
struct Rig {
    now: Rc<Cell<i64>>,
    server: Server<MockVehicle, Box<dyn Fn() -> i64>>,
}

impl Rig {
    fn new() -> Rig {
        let now = Rc::new(Cell::new(TS));
        let clock = Rc::clone(&now);
        let auth = Auth::new(Some("pw")).unwrap().with_lockout(BASE_MS, MAX_MS);
        Rig {
            now,
            server: Server::new(MockVehicle::default(), Box::new(move || clock.get()), auth),
        }
    }

    fn open(&mut self, addr: impl Into<IpAddr>) -> Session {
        self.server.open(Some(addr.into()))
    }

    fn advance(&mut self, ms: u32) {
        self.now.set(self.now.get() + i64::from(ms));
    }

    /// Ret and message of one login, on a connection of its own.
    fn login(&mut self, addr: impl Into<IpAddr>, password: &str) -> (i64, String) {
        let mut session = self.open(addr);
        self.login_on(&mut session, password)
    }

    fn login_on(&mut self, session: &mut Session, password: &str) -> (i64, String) {
        let frame = format!("login {password}");
        let mut out = vec![0u8; 4096];
        let outcome = self
            .server
            .handle(session, Message::Text(frame.as_bytes()), &mut out);
        let reply = outcome.reply().expect("login is always answered");
        let v = checked_json(reply);
        (
            v["ret"].as_i64().unwrap(),
            v["msg"].as_str().unwrap_or("").to_owned(),
        )
    }

    /// Five wrong passwords from `addr`, each on a new connection.
    fn guess_five_times(&mut self, addr: impl Into<IpAddr> + Copy) {
        for i in 0..MAX_WRONG_PASSWORDS {
            assert_eq!(
                self.login(addr, "guess"),
                (-1, "Wrong password!".into()),
                "guess {i}"
            );
        }
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
fn a_full_table_drops_the_least_recently_touched_address() {
    let mut rig = Rig::new();
    rig.guess_five_times(ATTACKER);
    for i in 0..THROTTLE_CAPACITY {
        rig.advance(1);
        let other = Ipv4Addr::new(10, 0, 0, u8::try_from(i).unwrap());
        rig.login(other, "guess");
    }
    assert_eq!(
        rig.login(ATTACKER, "pw").0,
        0,
        "the attacker's record was the oldest"
    );
    assert_eq!(rig.login(Ipv4Addr::new(10, 0, 0, 1), "pw").0, 0);
}

#[test]
fn sessions_without_an_address_are_limited_per_connection_only() {
    let mut s = server(Some("pw"));
    for _ in 0..3 {
        let mut sess = Session::new();
        for _ in 1..MAX_WRONG_PASSWORDS {
            assert_eq!(send(&mut s, &mut sess, "login guess").msg(), "Wrong password!");
        }
    }
    assert_eq!(send(&mut s, &mut Session::new(), "login pw").ret(), 0);
}

/// One step of a guessing scenario: which of four addresses, what it sends,
/// and how far the clock moves first.
#[derive(Clone, Debug)]
enum Attempt {
    Wrong,
    Right,
    Logout,
}

/// The rules of DESIGN.md, written out plainly, for the property below.
#[derive(Default)]
struct Model {
    records: HashMap<u8, (u8, u32, i64)>,
}

impl Model {
    fn login(&mut self, addr: u8, attempt: &Attempt, now: i64) -> &'static str {
        let (wrong, lockouts, until) = self.records.entry(addr).or_insert((0, 0, i64::MIN));
        if now < *until {
            return THROTTLED;
        }
        match attempt {
            Attempt::Right => {
                self.records.remove(&addr);
                ""
            }
            Attempt::Logout => "",
            Attempt::Wrong => {
                *wrong += 1;
                if *wrong == MAX_WRONG_PASSWORDS {
                    let ms = (u64::from(BASE_MS) << *lockouts).min(u64::from(MAX_MS));
                    *until = now + i64::try_from(ms).unwrap();
                    *lockouts += 1;
                    *wrong = 0;
                }
                "Wrong password!"
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Whatever the interleaving of addresses, connections and waits, the
    /// server answers every login as the plainly written rules say, so no
    /// address ever gets a sixth checked guess inside a lockout.
    #[test]
    fn logins_follow_the_per_address_rules(
        steps in prop::collection::vec(
            (0u8..4, prop_oneof![3 => Just(Attempt::Wrong), 1 => Just(Attempt::Right), 1 => Just(Attempt::Logout)],
             prop_oneof![Just(0u32), 1u32..2_000, 25_000u32..70_000]),
            1..120,
        ),
    ) {
        let mut rig = Rig::new();
        let mut model = Model::default();
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
