//! Who holds what: pending handshakes and sessions, in all and per client
//! address, so that no client can take the capacity the operator needs.
//!
//! Handshakes in progress live in their own bounded pool, never in a
//! session slot. When that pool (or one address's share of it) is full,
//! an OLD pending handshake is dropped, not the newcomer: the oldest one of
//! the address that holds the most. A swarm of half-open connections that
//! reopens whatever is dropped then churns through its own handshakes,
//! not through those of an address with fewer pending (the operator's
//! single one). A session slot held by a client that has not logged in
//! (when a password is configured) is reclaimed the same way when a
//! newcomer needs it; logged-in sessions are never displaced.
//!
//! An address is an IPv4 address, or an IPv6 /64 (one host usually has a
//! whole /64 to pick from).
//!
//! Every slot is a guard: dropping a [`Pending`] or [`Held`] frees it, so
//! no path out of a connection task can leak one. A dropped or reclaimed
//! holder is told through its `cancel` notification and frees nothing
//! twice.

use std::collections::{BTreeMap, HashMap};
use std::net::IpAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use tokio::sync::Notify;

/// The capacities, in all and per address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capacity {
    /// Pending handshakes in all.
    pub handshakes: usize,
    /// Pending handshakes from one address.
    pub handshakes_per_ip: usize,
    /// Sessions in all.
    pub sessions: usize,
    /// Sessions from one address.
    pub sessions_per_ip: usize,
}

/// Why a finished handshake gets no session.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Full {
    /// This address holds its share of sessions, all logged in.
    Address,
    /// Every session slot is held by a logged-in session.
    Server,
}

struct Waiting {
    ip: IpAddr,
    cancel: Arc<Notify>,
}

struct Live {
    ip: IpAddr,
    cancel: Arc<Notify>,
    admitted: Arc<AtomicBool>,
}

#[derive(Default)]
struct Counts {
    handshakes: usize,
    sessions: usize,
}

#[derive(Default)]
struct Inner {
    next: u64,
    // Keys are handed out in increasing order, so the first entry is the
    // oldest.
    handshakes: BTreeMap<u64, Waiting>,
    sessions: BTreeMap<u64, Live>,
    per_ip: HashMap<IpAddr, Counts>,
}

impl Inner {
    fn counts(&mut self, ip: IpAddr) -> &mut Counts {
        self.per_ip.entry(ip).or_default()
    }

    fn forget_if_idle(&mut self, ip: IpAddr) {
        if self
            .per_ip
            .get(&ip)
            .is_some_and(|c| c.handshakes == 0 && c.sessions == 0)
        {
            self.per_ip.remove(&ip);
        }
    }

    fn drop_handshake(&mut self, id: u64) -> Option<IpAddr> {
        let waiting = self.handshakes.remove(&id)?;
        self.counts(waiting.ip).handshakes -= 1;
        self.forget_if_idle(waiting.ip);
        waiting.cancel.notify_one();
        Some(waiting.ip)
    }

    fn drop_session(&mut self, id: u64) -> Option<IpAddr> {
        let live = self.sessions.remove(&id)?;
        self.counts(live.ip).sessions -= 1;
        self.forget_if_idle(live.ip);
        live.cancel.notify_one();
        Some(live.ip)
    }

    /// The oldest pending handshake of the address holding the most.
    fn handshake_to_drop(&self) -> Option<u64> {
        let most = self.per_ip.values().map(|c| c.handshakes).max()?;
        self.handshakes
            .iter()
            .find(|(_, w)| self.per_ip.get(&w.ip).is_some_and(|c| c.handshakes == most))
            .map(|(id, _)| *id)
    }

    /// The session not logged in to reclaim: from `ip` if given, else from
    /// the address holding the most such sessions; its oldest.
    fn session_to_reclaim(&self, ip: Option<IpAddr>) -> Option<u64> {
        let unadmitted = || {
            self.sessions
                .iter()
                .filter(|(_, s)| !s.admitted.load(Ordering::Relaxed))
        };
        let from = match ip {
            Some(ip) => ip,
            None => {
                let mut counts: HashMap<IpAddr, usize> = HashMap::new();
                for (_, s) in unadmitted() {
                    *counts.entry(s.ip).or_default() += 1;
                }
                let most = counts.values().copied().max()?;
                return unadmitted()
                    .find(|(_, s)| counts.get(&s.ip) == Some(&most))
                    .map(|(id, _)| *id);
            }
        };
        unadmitted().find(|(_, s)| s.ip == from).map(|(id, _)| *id)
    }
}

/// The address limits apply to: IPv4 addresses as they are, IPv6 by /64.
fn address(ip: IpAddr) -> IpAddr {
    match ip.to_canonical() {
        IpAddr::V6(v6) => {
            let bits = u128::from(v6) & !((1u128 << 64) - 1);
            IpAddr::V6(std::net::Ipv6Addr::from(bits))
        }
        v4 => v4,
    }
}

/// The registry of pending handshakes and sessions.
pub struct Slots {
    capacity: Capacity,
    inner: Mutex<Inner>,
}

/// A pending handshake's place in the pool; dropping it frees the place.
pub struct Pending {
    slots: Arc<Slots>,
    id: u64,
    /// Notified when this handshake is dropped for a newer one.
    pub cancel: Arc<Notify>,
}

/// A session's slot; dropping it frees the slot.
pub struct Held {
    slots: Arc<Slots>,
    id: u64,
    /// Notified when this session, not logged in, is reclaimed.
    pub cancel: Arc<Notify>,
    admitted: Arc<AtomicBool>,
}

impl Held {
    /// Marks the session as logged in (or not needing to): it is no longer
    /// reclaimable.
    pub fn admit(&self) {
        self.admitted.store(true, Ordering::Relaxed);
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        self.slots.lock().drop_handshake(self.id);
    }
}

impl Drop for Held {
    fn drop(&mut self) {
        self.slots.lock().drop_session(self.id);
    }
}

impl Slots {
    /// An empty registry.
    pub fn new(capacity: Capacity) -> Arc<Slots> {
        Arc::new(Slots {
            capacity,
            inner: Mutex::default(),
        })
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // Nothing panics while holding it; if something did, the counts
        // are still the best there are.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A place in the handshake pool for a connection from `ip`, and the
    /// addresses of the handshakes dropped to make room.
    pub fn begin(self: &Arc<Self>, ip: IpAddr) -> (Pending, Vec<IpAddr>) {
        let ip = address(ip);
        let mut inner = self.lock();
        let mut dropped = Vec::new();
        if inner.counts(ip).handshakes >= self.capacity.handshakes_per_ip {
            let oldest = inner
                .handshakes
                .iter()
                .find(|(_, w)| w.ip == ip)
                .map(|(id, _)| *id);
            dropped.extend(oldest.and_then(|id| inner.drop_handshake(id)));
        }
        while inner.handshakes.len() >= self.capacity.handshakes {
            let Some(victim) = inner.handshake_to_drop() else {
                break;
            };
            dropped.extend(inner.drop_handshake(victim));
        }
        let id = inner.next;
        inner.next += 1;
        let cancel = Arc::new(Notify::new());
        inner.handshakes.insert(
            id,
            Waiting {
                ip,
                cancel: Arc::clone(&cancel),
            },
        );
        inner.counts(ip).handshakes += 1;
        let pending = Pending {
            slots: Arc::clone(self),
            id,
            cancel,
        };
        (pending, dropped)
    }

    /// Turns a finished handshake from `ip` into a session, reclaiming the
    /// oldest session not logged in if the address's share or the whole
    /// pool is full; returns the reclaimed session's address.
    pub fn admit(self: &Arc<Self>, pending: Pending, ip: IpAddr) -> Result<(Held, Option<IpAddr>), Full> {
        let ip = address(ip);
        let mut inner = self.lock();
        inner.drop_handshake(pending.id);
        let mut reclaimed = None;
        if inner.counts(ip).sessions >= self.capacity.sessions_per_ip {
            let id = inner.session_to_reclaim(Some(ip)).ok_or(Full::Address)?;
            reclaimed = inner.drop_session(id);
        }
        if inner.sessions.len() >= self.capacity.sessions {
            let id = inner.session_to_reclaim(None).ok_or(Full::Server)?;
            reclaimed = inner.drop_session(id);
        }
        let id = inner.next;
        inner.next += 1;
        let held = Held {
            slots: Arc::clone(self),
            id,
            cancel: Arc::new(Notify::new()),
            admitted: Arc::new(AtomicBool::new(false)),
        };
        inner.sessions.insert(
            id,
            Live {
                ip,
                cancel: Arc::clone(&held.cancel),
                admitted: Arc::clone(&held.admitted),
            },
        );
        inner.counts(ip).sessions += 1;
        Ok((held, reclaimed))
    }

    /// Sessions open now.
    pub fn sessions(&self) -> usize {
        self.lock().sessions.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(last: u8) -> IpAddr {
        IpAddr::V4(std::net::Ipv4Addr::new(127, 0, 0, last))
    }

    fn slots() -> Arc<Slots> {
        Slots::new(Capacity {
            handshakes: 3,
            handshakes_per_ip: 2,
            sessions: 3,
            sessions_per_ip: 2,
        })
    }

    #[tokio::test]
    async fn a_full_handshake_pool_drops_its_oldest_not_the_newcomer() {
        let s = slots();
        let (first, _) = s.begin(ip(1));
        let (_second, _) = s.begin(ip(2));
        let (_third, _) = s.begin(ip(3));
        let (_fourth, dropped) = s.begin(ip(4));
        assert_eq!(dropped, vec![ip(1)]);
        // The dropped handshake is told, even though it was not waiting yet.
        first.cancel.notified().await;
    }

    #[test]
    fn a_full_handshake_pool_drops_from_the_address_holding_the_most() {
        let s = slots();
        let (_operator, _) = s.begin(ip(1));
        let (_a, _) = s.begin(ip(2));
        let (_b, _) = s.begin(ip(2));
        let (_c, dropped) = s.begin(ip(3));
        assert_eq!(dropped, vec![ip(2)], "not the operator's older one");
    }

    #[test]
    fn ipv6_clients_are_counted_by_their_64_bit_prefix() {
        let s = slots();
        let v6 = |last: u16| IpAddr::V6(std::net::Ipv6Addr::new(0x2001, 0xdb8, 0, 1, 0, 0, 0, last));
        let (_a, _) = s.begin(v6(1));
        let (_b, _) = s.begin(v6(2));
        let (_c, dropped) = s.begin(v6(3));
        assert_eq!(dropped.len(), 1, "one /64 holds at most its share: {dropped:?}");
    }

    #[test]
    fn one_address_holds_at_most_its_share_of_the_handshake_pool() {
        let s = slots();
        let (_a, _) = s.begin(ip(1));
        let (_b, _) = s.begin(ip(1));
        let (_c, dropped) = s.begin(ip(1));
        assert_eq!(dropped, vec![ip(1)], "the address's own oldest goes");
        let (_d, dropped) = s.begin(ip(2));
        assert!(dropped.is_empty(), "another address still has room: {dropped:?}");
    }

    #[test]
    fn sessions_not_logged_in_are_reclaimed_oldest_first_and_logged_in_ones_never() {
        let s = slots();
        let session = |from: u8| {
            let (p, _) = s.begin(ip(from));
            s.admit(p, ip(from))
        };
        let (a, _) = session(1).expect("room");
        a.admit();
        let (_b, _) = session(2).expect("room");
        let (_c, _) = session(3).expect("room");
        let (d, reclaimed) = session(4).expect("reclaims the oldest not logged in");
        assert_eq!(reclaimed, Some(address(ip(2))));
        d.admit();
        let (e, reclaimed) = session(5).expect("reclaims the next");
        assert_eq!(reclaimed, Some(ip(3)));
        e.admit();
        assert_eq!(session(6).err(), Some(Full::Server), "every session is logged in");
        drop(a);
        let f = session(6);
        assert!(f.is_ok(), "a freed slot is reused");
        assert_eq!(s.sessions(), 3);
    }

    #[test]
    fn one_address_holds_at_most_its_share_of_sessions() {
        let s = slots();
        let session = |from: u8| {
            let (p, _) = s.begin(ip(from));
            s.admit(p, ip(from))
        };
        let (a, _) = session(1).expect("room");
        let (b, _) = session(1).expect("room");
        a.admit();
        b.admit();
        assert_eq!(session(1).err(), Some(Full::Address));
        assert!(session(2).is_ok(), "other addresses are not affected");
    }
}
