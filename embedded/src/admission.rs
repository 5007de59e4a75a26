//! Who gets one of the few session slots, with fixed tables: DESIGN.md's
//! availability rules on a board.
//!
//! # Noticing a newcomer when every slot is busy
//!
//! A slot listens with its own socket whenever it has no connection, and
//! smoltcp answers a SYN that finds no listening socket with a reset: a
//! board whose slots are all held cannot even see that someone else wants
//! in. So the slots keep a spare: when a connection arrives on the last
//! listening slot, the oldest slot held by a connection that may be
//! reclaimed (a handshake still in progress, a session that has not
//! logged in while a password is required, or a connection that is over
//! and only waits for its peer's side of the close) is evicted at once (its TCP
//! connection is reset), and that slot listens again. The newcomer keeps
//! the slot it arrived on. Sessions that logged in are never evicted; when
//! only they hold slots, the last slot serves its connection and nothing
//! listens until one of them ends (the operator's own sessions are the
//! capacity, not an attack).
//!
//! A connection younger than [`Config::reclaim_after`] is not evicted: a
//! legitimate newcomer needs a few round trips to send its request and log
//! in, and a swarm reconnecting faster than that would otherwise evict it
//! before it could (oldest first only delays that by as many connections as
//! there are slots). When every reclaimable slot is that young, the
//! newcomer on the last listening slot is refused (reset) instead, so that
//! the slot keeps listening; it may retry, and the swarm's connections age.
//! And while the last slot is contested that way, a newcomer from an
//! address that already holds a slot it has not logged in with is refused
//! too: a swarm then holds one reclaimable slot per address, and each
//! eviction makes room for an address that held none, such as the
//! operator's. So under a swarm each slot changes hands at most once per
//! `reclaim_after`, a newcomer that gets a slot keeps it for at least that
//! long, and one slot always listens.
//!
//! # Per-address limits
//!
//! A connection from an address that already has
//! [`Config::max_handshakes_per_address`] handshakes in progress is reset
//! as it arrives (it evicts no one), and an upgrade from an address that
//! already holds [`Config::max_sessions_per_address`] sessions is answered
//! `429 Too Many Requests`. Loopback is not exempt.
//!
//! # Deadlines
//!
//! A handshake has [`Config::handshake_timeout`] from the moment the
//! connection is accepted to complete its whole request, however slowly
//! its bytes come. With a password required, a session that has not logged
//! in within [`Config::login_timeout`] of its upgrade is closed with 1008;
//! neither pings nor other messages move that deadline.
//!
//! # Logging
//!
//! Evictions, refusals, rejected requests and missed deadlines are logged
//! at most once per offending address per minute (a fixed table of the
//! last [`OFFENDERS`] addresses), with the number of events left unlogged
//! since.

use core::cell::Cell;
use core::net::IpAddr;

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant};

use crate::Config;

/// How many offending addresses the log remembers.
pub const OFFENDERS: usize = 8;

/// How often one address's offenses are logged.
const LOG_INTERVAL: Duration = Duration::from_secs(60);

/// What a slot holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Nothing: tearing down or between sockets.
    Idle,
    /// Waiting for a connection.
    Listening,
    /// A connection whose upgrade is in progress.
    Handshake,
    /// A WebSocket session; `admitted` once it may run commands.
    Session { admitted: bool },
    /// Its connection is over (a refused upgrade or an ended session) and
    /// only waits for the peer's side of the close: reclaimable, and no
    /// longer a handshake or a session of its address.
    Closing,
}

#[derive(Clone, Copy, Debug)]
struct Entry {
    phase: Phase,
    peer: Option<IpAddr>,
    since: Instant,
}

impl Entry {
    const IDLE: Entry = Entry {
        phase: Phase::Idle,
        peer: None,
        since: Instant::from_ticks(0),
    };

    fn reclaimable(&self) -> bool {
        matches!(
            self.phase,
            Phase::Handshake | Phase::Session { admitted: false } | Phase::Closing
        )
    }
}

/// Why an arriving connection was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Refusal {
    /// Its address already has as many handshakes in progress as allowed.
    TooManyHandshakes,
    /// It arrived on the last listening slot while its address already
    /// holds a slot that could be reclaimed, or while every such slot is
    /// younger than [`Config::reclaim_after`].
    Busy,
}

/// What an address did that gets logged (once a minute at most).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Offense {
    /// Its connection was refused on arrival.
    Refused(Refusal),
    /// Its connection was evicted to keep a slot listening.
    Evicted,
    /// Its upgrade request did not complete in time.
    SlowHandshake,
    /// Its upgrade request was rejected.
    Rejected(crate::error::Rejection),
    /// Its session did not log in before the deadline.
    NoLogin,
}

/// The state of every slot of one `serve`, shared by their loops (which
/// run on one executor, in one task or one task each: hence plain cells).
pub struct Table<const N: usize> {
    slots: [Cell<Entry>; N],
    evict: [Signal<CriticalSectionRawMutex, ()>; N],
    offenders: [Cell<Option<Offender>>; OFFENDERS],
}

/// One address's logging state.
#[derive(Clone, Copy, Debug)]
struct Offender {
    peer: IpAddr,
    logged: Instant,
    unlogged: u32,
}

impl<const N: usize> Table<N> {
    /// Every slot idle; `const`, so that a firmware can keep the table in a
    /// static shared by its slots' tasks.
    pub const fn new() -> Self {
        Table {
            slots: [const { Cell::new(Entry::IDLE) }; N],
            evict: [const { Signal::new() }; N],
            offenders: [const { Cell::new(None) }; OFFENDERS],
        }
    }

    fn set(&self, slot: usize, entry: Entry) {
        if let Some(cell) = self.slots.get(slot) {
            cell.set(entry);
        }
    }

    fn others(&self, slot: usize) -> impl Iterator<Item = (usize, Entry)> + '_ {
        self.slots
            .iter()
            .map(Cell::get)
            .enumerate()
            .filter(move |(i, _)| *i != slot)
    }

    fn count(&self, slot: usize, peer: Option<IpAddr>, phase: impl Fn(Phase) -> bool) -> usize {
        match peer {
            Some(peer) => self
                .others(slot)
                .filter(|(_, e)| e.peer == Some(peer) && phase(e.phase))
                .count(),
            None => 0,
        }
    }

    /// `slot` is waiting for a connection.
    pub fn listening(&self, slot: usize) {
        self.set(
            slot,
            Entry {
                phase: Phase::Listening,
                ..Entry::IDLE
            },
        );
        if let Some(signal) = self.evict.get(slot) {
            signal.reset();
        }
    }

    /// A connection from `peer` arrived on `slot` at `now`: refused, or
    /// admitted to its handshake, with the slot to evict so that one slot
    /// keeps listening.
    pub fn arrive(
        &self,
        slot: usize,
        peer: Option<IpAddr>,
        config: &Config,
        now: Instant,
    ) -> Result<Option<usize>, Refusal> {
        if self.count(slot, peer, |p| p == Phase::Handshake) >= config.max_handshakes_per_address {
            self.set(slot, Entry::IDLE);
            return Err(Refusal::TooManyHandshakes);
        }
        self.set(
            slot,
            Entry {
                phase: Phase::Handshake,
                peer,
                since: now,
            },
        );
        if self.others(slot).any(|(_, e)| e.phase == Phase::Listening) {
            return Ok(None);
        }
        let mut reclaimable = self.others(slot).filter(|(_, e)| e.reclaimable()).peekable();
        if reclaimable.peek().is_none() {
            // Only admitted sessions besides: they are the capacity.
            return Ok(None);
        }
        if self.count(slot, peer, |p| {
            matches!(p, Phase::Handshake | Phase::Session { admitted: false })
        }) > 0
        {
            // The last slot is contested: an address that already holds a
            // slot it has not logged in with gets no second one.
            self.set(slot, Entry::IDLE);
            return Err(Refusal::Busy);
        }
        let victim = reclaimable
            .filter(|(_, e)| e.since + config.reclaim_after <= now)
            .min_by_key(|(_, e)| e.since)
            .map(|(i, _)| i);
        let Some(victim) = victim else {
            // Everything reclaimable is too young to evict: the newcomer is
            // refused instead, so that a slot keeps listening.
            self.set(slot, Entry::IDLE);
            return Err(Refusal::Busy);
        };
        // Evicted now, so that the next newcomer does not pick it again.
        self.set(victim, Entry::IDLE);
        if let Some(signal) = self.evict.get(victim) {
            signal.signal(());
        }
        Ok(Some(victim))
    }

    /// Whether `peer` may open one more session (checked when its upgrade
    /// request on `slot` is complete).
    pub fn may_open(&self, slot: usize, peer: Option<IpAddr>, config: &Config) -> bool {
        self.count(slot, peer, |p| matches!(p, Phase::Session { .. })) < config.max_sessions_per_address
    }

    /// The upgrade on `slot` completed; `admitted` as [`Table::admit`].
    pub fn opened(&self, slot: usize, admitted: bool) {
        if let Some(cell) = self.slots.get(slot) {
            let entry = cell.get();
            cell.set(Entry {
                phase: Phase::Session { admitted },
                ..entry
            });
        }
    }

    /// Whether the session on `slot` may run commands (if not, it may be
    /// evicted).
    pub fn admit(&self, slot: usize, admitted: bool) {
        if let Some(cell) = self.slots.get(slot) {
            let entry = cell.get();
            if let Phase::Session { .. } = entry.phase {
                cell.set(Entry {
                    phase: Phase::Session { admitted },
                    ..entry
                });
            }
        }
    }

    /// The connection on `slot` is over and closing: a client that retries
    /// at once (all of a port forwarder's clients share one address) is not
    /// refused for it, and the slot may be reclaimed for a newcomer.
    pub fn closing(&self, slot: usize) {
        if let Some(cell) = self.slots.get(slot) {
            let entry = cell.get();
            if entry.phase != Phase::Idle {
                cell.set(Entry {
                    phase: Phase::Closing,
                    ..entry
                });
            }
        }
    }

    /// The connection on `slot` ended.
    pub fn ended(&self, slot: usize) {
        self.set(slot, Entry::IDLE);
    }

    /// Waits until `slot` is evicted.
    pub async fn evicted(&self, slot: usize) {
        match self.evict.get(slot) {
            Some(signal) => signal.wait().await,
            None => core::future::pending().await,
        }
    }

    /// Counts an offense by `peer` at `now`: `Some(unlogged)` (the offenses
    /// since the last logged one) when it should be logged, `None` when the
    /// address was logged less than a minute ago.
    pub fn offense(&self, peer: Option<IpAddr>, now: Instant) -> Option<u32> {
        let Some(peer) = peer else {
            return Some(0);
        };
        let known = self
            .offenders
            .iter()
            .find(|c| c.get().is_some_and(|o| o.peer == peer));
        if let Some(cell) = known {
            let Some(mut o) = cell.get() else {
                return Some(0);
            };
            if now < o.logged + LOG_INTERVAL {
                o.unlogged = o.unlogged.saturating_add(1);
                cell.set(Some(o));
                return None;
            }
            cell.set(Some(Offender {
                peer,
                logged: now,
                unlogged: 0,
            }));
            return Some(o.unlogged);
        }
        // A free entry, or the one logged longest ago.
        let oldest = self.offenders.iter().min_by_key(|c| c.get().map(|o| o.logged));
        if let Some(cell) = oldest {
            cell.set(Some(Offender {
                peer,
                logged: now,
                unlogged: 0,
            }));
        }
        Some(0)
    }
}

impl<const N: usize> Default for Table<N> {
    fn default() -> Self {
        Table::new()
    }
}

#[cfg(test)]
mod tests {
    use core::net::Ipv4Addr;

    use super::*;

    fn ip(last: u8) -> Option<IpAddr> {
        Some(IpAddr::V4(Ipv4Addr::new(10, 0, 0, last)))
    }

    fn at(secs: u64) -> Instant {
        Instant::from_secs(100 + secs)
    }

    fn config() -> Config {
        Config {
            max_handshakes_per_address: 2,
            max_sessions_per_address: 2,
            reclaim_after: Duration::from_secs(1),
            ..Config::new()
        }
    }

    #[test]
    fn a_closing_connection_is_no_handshake_or_session_of_its_address_and_may_be_reclaimed() {
        let t = Table::<3>::new();
        let c = config();
        (0..3).for_each(|i| t.listening(i));
        assert_eq!(t.arrive(0, ip(1), &c, at(1)), Ok(None));
        assert_eq!(t.arrive(1, ip(1), &c, at(1)), Ok(None));
        // Both upgrades refused; their connections wait for the peer's FIN.
        t.closing(0);
        t.closing(1);
        // The address retries at once: no handshake of its is in progress,
        // and on the last listening slot the oldest closing slot makes room.
        assert_eq!(t.arrive(2, ip(1), &c, at(3)), Ok(Some(0)));
        t.opened(2, true);
        t.closing(2);
        assert!(
            t.may_open(0, ip(1), &c),
            "a closing session is not one of the address's"
        );
    }

    #[test]
    fn the_last_listener_evicts_the_oldest_reclaimable_slot() {
        let t = Table::<3>::new();
        let c = Config {
            max_handshakes_per_address: 9,
            ..config()
        };
        (0..3).for_each(|i| t.listening(i));
        assert_eq!(t.arrive(0, ip(1), &c, at(1)), Ok(None));
        assert_eq!(t.arrive(1, ip(2), &c, at(2)), Ok(None));
        t.opened(1, true);
        // Slot 2 was the last listener: slot 0's handshake is the oldest
        // reclaimable one; slot 1's admitted session is never evicted.
        assert_eq!(t.arrive(2, ip(3), &c, at(3)), Ok(Some(0)));
        t.listening(0);
        assert_eq!(t.arrive(0, ip(4), &c, at(4)), Ok(Some(2)));
    }

    #[test]
    fn sessions_not_logged_in_are_reclaimable_oldest_first() {
        let t = Table::<3>::new();
        let c = config();
        (0..3).for_each(|i| t.listening(i));
        t.arrive(0, ip(1), &c, at(1)).unwrap();
        t.opened(0, false);
        t.arrive(1, ip(2), &c, at(2)).unwrap();
        t.opened(1, false);
        assert_eq!(t.arrive(2, ip(3), &c, at(3)), Ok(Some(0)));
        t.admit(1, true);
        t.listening(0);
        assert_eq!(t.arrive(0, ip(4), &c, at(4)), Ok(Some(2)));
    }

    #[test]
    fn connections_younger_than_the_grace_are_not_evicted() {
        let t = Table::<2>::new();
        let c = config();
        (0..2).for_each(|i| t.listening(i));
        assert_eq!(t.arrive(0, ip(1), &c, at(10)), Ok(None));
        // Slot 0 is half a second old: the newcomer on the last slot is
        // refused, so that slot 1 listens again...
        assert_eq!(
            t.arrive(1, ip(2), &c, Instant::from_millis(110_500)),
            Err(Refusal::Busy)
        );
        // ...and a second later slot 0 is evicted for it.
        t.listening(1);
        assert_eq!(t.arrive(1, ip(2), &c, at(11)), Ok(Some(0)));
    }

    #[test]
    fn nothing_is_evicted_while_another_slot_listens_or_when_all_logged_in() {
        let t = Table::<2>::new();
        let c = config();
        (0..2).for_each(|i| t.listening(i));
        assert_eq!(t.arrive(0, ip(1), &c, at(1)), Ok(None));
        t.opened(0, true);
        assert_eq!(t.arrive(1, ip(2), &c, at(2)), Ok(None));
    }

    #[test]
    fn handshakes_per_address_are_limited_at_arrival() {
        let t = Table::<5>::new();
        let c = config();
        (0..5).for_each(|i| t.listening(i));
        assert_eq!(t.arrive(0, ip(1), &c, at(1)), Ok(None));
        assert_eq!(t.arrive(1, ip(1), &c, at(1)), Ok(None));
        assert_eq!(t.arrive(2, ip(1), &c, at(1)), Err(Refusal::TooManyHandshakes));
        t.listening(2);
        assert_eq!(t.arrive(2, ip(2), &c, at(1)), Ok(None));
        // A handshake that became a session no longer counts.
        t.opened(0, true);
        assert_eq!(t.arrive(3, ip(1), &c, at(2)), Ok(None));
    }

    #[test]
    fn the_contested_last_slot_goes_only_to_an_address_without_one() {
        let t = Table::<3>::new();
        let c = config();
        (0..3).for_each(|i| t.listening(i));
        t.arrive(0, ip(1), &c, at(1)).unwrap();
        t.arrive(1, ip(2), &c, at(1)).unwrap();
        // Address 1 already holds a reclaimable slot: no second one...
        assert_eq!(t.arrive(2, ip(1), &c, at(5)), Err(Refusal::Busy));
        // ...while address 3, which holds none, evicts the oldest.
        t.listening(2);
        assert_eq!(t.arrive(2, ip(3), &c, at(5)), Ok(Some(0)));
    }

    #[test]
    fn sessions_per_address_are_limited_at_upgrade() {
        let t = Table::<4>::new();
        let c = config();
        (0..4).for_each(|i| t.listening(i));
        for i in 0..3 {
            let many = Config {
                max_handshakes_per_address: 9,
                ..c
            };
            assert_eq!(t.arrive(i, ip(1), &many, at(1)), Ok(None));
        }
        assert!(t.may_open(0, ip(1), &c));
        t.opened(0, true);
        assert!(t.may_open(1, ip(1), &c));
        t.opened(1, false);
        assert!(!t.may_open(2, ip(1), &c));
        assert!(t.may_open(2, ip(2), &c));
    }

    #[test]
    fn an_address_is_logged_once_a_minute_with_what_was_left_out() {
        let t = Table::<1>::new();
        assert_eq!(t.offense(ip(1), at(0)), Some(0));
        assert_eq!(t.offense(ip(1), at(10)), None);
        assert_eq!(t.offense(ip(1), at(59)), None);
        assert_eq!(t.offense(ip(2), at(59)), Some(0));
        assert_eq!(t.offense(ip(1), at(60)), Some(2));
        assert_eq!(t.offense(ip(1), at(61)), None);
    }

    #[test]
    fn the_log_table_forgets_the_address_logged_longest_ago() {
        let t = Table::<1>::new();
        for i in 0..OFFENDERS as u8 {
            assert_eq!(t.offense(ip(i), at(u64::from(i))), Some(0));
        }
        // A ninth address takes the place of the first...
        assert_eq!(t.offense(ip(100), at(20)), Some(0));
        // ...which is therefore logged again at once.
        assert_eq!(t.offense(ip(0), at(21)), Some(0));
        assert_eq!(t.offense(ip(100), at(22)), None);
    }
}
