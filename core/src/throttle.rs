//! Password guessing, limited per client address across connections.
//!
//! DESIGN.md, "Sessions and gates": after [`MAX_WRONG_PASSWORDS`] wrong
//! passwords in a row from one address, every `login` from it is refused
//! without checking the password for a lockout that starts at
//! [`DEFAULT_LOCKOUT_MS`] and doubles with each further lockout, up to
//! [`DEFAULT_MAX_LOCKOUT_MS`]. A login that grants access once the lockout is
//! over clears the address's record.
//!
//! The table has a fixed capacity ([`THROTTLE_CAPACITY`] records, no
//! allocation); when it is full, the least recently touched record is
//! dropped. IPv6 addresses are keyed by their /64 prefix, because a single
//! host is usually given a whole /64 and could otherwise walk through it to
//! start fresh records; IPv4-mapped IPv6 addresses count as their IPv4
//! address.

use core::net::IpAddr;

/// Wrong passwords in a row after which a session is closed (1008) and an
/// address is locked out.
pub const MAX_WRONG_PASSWORDS: u8 = 5;
/// The first lockout of an address.
pub const DEFAULT_LOCKOUT_MS: u32 = 30_000;
/// The longest lockout of an address.
pub const DEFAULT_MAX_LOCKOUT_MS: u32 = 15 * 60_000;
/// Addresses remembered at once.
pub const THROTTLE_CAPACITY: usize = 16;

/// What the throttle keys an address by: the IPv4 address, or the /64
/// prefix of an IPv6 address.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Key {
    V4([u8; 4]),
    V6([u8; 8]),
}

impl Key {
    fn of(addr: IpAddr) -> Key {
        match addr {
            IpAddr::V4(v4) => Key::V4(v4.octets()),
            IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
                Some(v4) => Key::V4(v4.octets()),
                None => {
                    let mut prefix = [0u8; 8];
                    for (dst, src) in prefix.iter_mut().zip(v6.octets()) {
                        *dst = src;
                    }
                    Key::V6(prefix)
                }
            },
        }
    }
}

/// One address's history.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Record {
    key: Key,
    /// Wrong passwords since the last lockout ended (or the first attempt).
    wrong: u8,
    /// Lockouts so far: the next one lasts `base << lockouts`.
    lockouts: u8,
    /// Logins are refused until this time (ms since the epoch).
    locked_until: i64,
    /// When the record was last touched, for eviction.
    touched: i64,
}

/// The per-address table of wrong passwords.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Throttle {
    records: [Option<Record>; THROTTLE_CAPACITY],
    base_ms: u32,
    max_ms: u32,
}

impl Default for Throttle {
    fn default() -> Self {
        Throttle::new(DEFAULT_LOCKOUT_MS, DEFAULT_MAX_LOCKOUT_MS)
    }
}

impl Throttle {
    /// An empty table whose first lockout lasts `base_ms`, doubling up to
    /// `max_ms` (at least `base_ms`).
    pub const fn new(base_ms: u32, max_ms: u32) -> Self {
        let max_ms = if max_ms < base_ms { base_ms } else { max_ms };
        Throttle {
            records: [None; THROTTLE_CAPACITY],
            base_ms,
            max_ms,
        }
    }

    /// Whether `addr` is locked out at `now`.
    pub fn locked(&self, addr: IpAddr, now: i64) -> bool {
        let key = Key::of(addr);
        self.records
            .iter()
            .flatten()
            .any(|r| r.key == key && now < r.locked_until)
    }

    /// Counts a wrong password from `addr`; the
    /// [`MAX_WRONG_PASSWORDS`]th in a row starts a lockout.
    pub fn wrong(&mut self, addr: IpAddr, now: i64) {
        let (base, max) = (self.base_ms, self.max_ms);
        let Some(record) = self.record(Key::of(addr), now) else {
            return;
        };
        record.wrong = record.wrong.saturating_add(1);
        record.touched = now;
        if record.wrong >= MAX_WRONG_PASSWORDS {
            let lockout = u64::from(base)
                .checked_shl(u32::from(record.lockouts))
                .map_or(u64::from(max), |ms| ms.min(u64::from(max)));
            record.locked_until = now.saturating_add(i64::try_from(lockout).unwrap_or(i64::MAX));
            record.lockouts = record.lockouts.saturating_add(1);
            record.wrong = 0;
        }
    }

    /// Forgets `addr`: it logged in with a password that grants access.
    pub fn granted(&mut self, addr: IpAddr) {
        let key = Key::of(addr);
        for slot in &mut self.records {
            if slot.is_some_and(|r| r.key == key) {
                *slot = None;
            }
        }
    }

    /// The record of `key`, made in a free slot or in place of the least
    /// recently touched one. (Always `Some`: the table is never empty.)
    fn record(&mut self, key: Key, now: i64) -> Option<&mut Record> {
        let fresh = Record {
            key,
            wrong: 0,
            lockouts: 0,
            locked_until: i64::MIN,
            touched: now,
        };
        let index = self
            .records
            .iter()
            .position(|r| r.is_some_and(|r| r.key == key))
            .or_else(|| self.records.iter().position(Option::is_none))
            .or_else(|| {
                let oldest = self.records.iter().flatten().map(|r| r.touched).min();
                self.records.iter().position(|r| r.map(|r| r.touched) == oldest)
            })
            .unwrap_or(0);
        let slot = self.records.get_mut(index)?;
        if slot.is_none_or(|r| r.key != key) {
            *slot = Some(fresh);
        }
        slot.as_mut()
    }
}
