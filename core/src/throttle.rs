//! Password guessing, limited per client and across all clients.
//!
//! DESIGN.md, "Sessions and gates": after [`MAX_WRONG_PASSWORDS`] wrong
//! passwords in a row from one client, every `login` from it is refused
//! without checking the password for a lockout that starts at
//! [`DEFAULT_LOCKOUT_MS`] and doubles with each further lockout, up to
//! [`DEFAULT_MAX_LOCKOUT_MS`]. A login that grants access once the lockout is
//! over clears the client's record.
//!
//! The records live in a table of fixed capacity that the adapter provides
//! ([`Slots`]: [`THROTTLE_CAPACITY`] in the default array; a host passes
//! thousands). A record that still matters (locked, or a wrong password
//! less than one first lockout ago) is never dropped to make room: when
//! none can go, a password from a client without a record is not checked,
//! so more addresses never buy more guesses. On top of that, wrong
//! passwords checked across all clients are limited per second (a token
//! bucket of [`Throttle::with_rate`]'s size, refilled at that rate): while
//! it is empty no password is checked at all.
//!
//! Clients are keyed by [`Peer`]: IPv6 addresses by their /64 prefix,
//! because a single host is usually given a whole /64 and could otherwise
//! walk through it to start fresh records; IPv4-mapped IPv6 addresses count
//! as their IPv4 address; [`Peer::Client`] keys as given.

use core::net::IpAddr;

/// Who a session is, as login throttling counts wrong passwords (each
/// [`Session`](crate::Session) holds its own).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Peer {
    /// The client's network address (IPv6 counts by its /64 prefix).
    Address(IpAddr),
    /// An opaque per-client key that an adapter derives from a name it
    /// trusts to be per-client (an uplink's client id, hashed with a key
    /// of its own so that no client can pick another's).
    Client([u8; 16]),
}

impl From<IpAddr> for Peer {
    fn from(addr: IpAddr) -> Self {
        Peer::Address(addr)
    }
}

/// Wrong passwords in a row after which a session is closed (1008) and a
/// client is locked out.
pub const MAX_WRONG_PASSWORDS: u8 = 5;
/// The first lockout of a client.
pub const DEFAULT_LOCKOUT_MS: u32 = 30_000;
/// The longest lockout of a client.
pub const DEFAULT_MAX_LOCKOUT_MS: u32 = 15 * 60_000;
/// Records in the default table (a microcontroller's).
pub const THROTTLE_CAPACITY: usize = 16;
/// Wrong passwords checked per second across all clients, by default (a
/// microcontroller's; lluavd configures its own).
pub const DEFAULT_RATE: u16 = 5;

/// What the throttle keys a client by: a kind (4: IPv4, 6: an IPv6 /64,
/// 1: a client key; 0 marks a free slot) and its bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Key {
    kind: u8,
    bytes: [u8; 16],
}

/// The key of `peer`.
fn key(peer: &Peer) -> Key {
    let (kind, bits) = match *peer {
        Peer::Client(bytes) => return Key { kind: 1, bytes },
        Peer::Address(IpAddr::V4(v4)) => (4, u128::from(v4.to_bits())),
        Peer::Address(IpAddr::V6(v6)) => match v6.to_ipv4_mapped() {
            Some(v4) => (4, u128::from(v4.to_bits())),
            None => (6, v6.to_bits() >> 64),
        },
    };
    Key {
        kind,
        bytes: bits.to_le_bytes(),
    }
}

/// One slot of the table: a client's history, or nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Slot {
    key: Key,
    /// Wrong passwords since the last lockout ended (or the first attempt).
    wrong: u8,
    /// Lockouts so far: the next one lasts `base << lockouts`.
    lockouts: u8,
    /// Logins are refused until this time (ms since the epoch).
    locked_until: i64,
    /// When the last wrong password came.
    touched: i64,
}

impl Slot {
    /// A free slot (all zeros, so that a table starts as zeroed memory).
    pub const EMPTY: Slot = Slot {
        key: Key {
            kind: 0,
            bytes: [0; 16],
        },
        wrong: 0,
        lockouts: 0,
        locked_until: 0,
        touched: 0,
    };

    /// Whether the record may go to make room: not locked, and no wrong
    /// password for one first lockout.
    fn spent(&self, now: i64, base_ms: u32) -> bool {
        now >= self.locked_until && now.saturating_sub(self.touched) >= i64::from(base_ms)
    }
}

/// Where a client's record is.
enum Place {
    /// In this slot.
    Own(usize),
    /// Nowhere yet; a wrong password would take this slot.
    New(usize),
    /// Nowhere, and every record still matters.
    Full,
}

/// Storage for the table: a fixed array on a microcontroller, a boxed
/// slice of any length on a host (`vec![Slot::EMPTY; n].into_boxed_slice()`).
pub trait Slots: AsRef<[Slot]> + AsMut<[Slot]> {}

impl<T: AsRef<[Slot]> + AsMut<[Slot]>> Slots for T {}

/// The default table.
pub type DefaultSlots = [Slot; THROTTLE_CAPACITY];

/// The table of wrong passwords per client, and the global budget.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Throttle<S = DefaultSlots> {
    slots: S,
    base_ms: u32,
    max_ms: u32,
    /// Milliseconds the budget takes to refill by one check.
    interval_ms: u32,
    /// How far ahead of now `full_at` may be for a check to pass: the
    /// budget's size less one, in intervals.
    burst_ms: u32,
    /// When the budget is full again, less `rate` intervals (a token
    /// bucket kept as one time, the generic cell rate algorithm's).
    full_at: i64,
}

/// The default budget's refill time per check.
const INTERVAL_MS: u32 = 1000u32.div_ceil(DEFAULT_RATE as u32);

impl Default for Throttle {
    fn default() -> Self {
        Throttle::new(DEFAULT_LOCKOUT_MS, DEFAULT_MAX_LOCKOUT_MS)
    }
}

impl Throttle {
    /// An empty default table whose first lockout lasts `base_ms`, doubling
    /// up to `max_ms` (at least `base_ms`), and a budget of
    /// [`DEFAULT_RATE`] wrong passwords per second.
    pub const fn new(base_ms: u32, max_ms: u32) -> Self {
        Throttle {
            slots: [Slot::EMPTY; THROTTLE_CAPACITY],
            base_ms,
            max_ms: if max_ms < base_ms { base_ms } else { max_ms },
            interval_ms: INTERVAL_MS,
            burst_ms: INTERVAL_MS * (DEFAULT_RATE as u32 - 1),
            full_at: i64::MIN,
        }
    }
}

impl<S: Slots> Throttle<S> {
    /// The same rules over another table, emptied.
    pub fn with_table<T: Slots>(self, mut slots: T) -> Throttle<T> {
        slots.as_mut().fill(Slot::EMPTY);
        Throttle {
            slots,
            base_ms: self.base_ms,
            max_ms: self.max_ms,
            interval_ms: self.interval_ms,
            burst_ms: self.burst_ms,
            full_at: self.full_at,
        }
    }

    /// At most `per_second` wrong passwords checked per second across all
    /// clients (at least 1, at most 1000), in bursts of at most as many.
    pub fn with_rate(mut self, per_second: u16) -> Self {
        let rate = u32::from(per_second.clamp(1, 1000));
        self.interval_ms = 1000u32.div_ceil(rate);
        self.burst_ms = self.interval_ms * (rate - 1);
        self
    }

    /// The same table with lockouts of `base_ms`, doubling up to `max_ms`.
    pub fn with_lockout(mut self, base_ms: u32, max_ms: u32) -> Self {
        self.base_ms = base_ms;
        self.max_ms = max_ms.max(base_ms);
        self
    }

    /// How many clients the table holds.
    pub fn capacity(&self) -> usize {
        self.slots.as_ref().len()
    }

    /// Where `key`'s record is or would go: its own slot, else a free one,
    /// else the spent record touched longest ago (one pass).
    fn place(&self, key: &Key, now: i64) -> Place {
        let mut free = None;
        let mut spent: Option<(i64, usize)> = None;
        for (i, slot) in self.slots.as_ref().iter().enumerate() {
            if slot.key == *key {
                return Place::Own(i);
            }
            if slot.key.kind == 0 {
                free = free.or(Some(i));
            } else if slot.spent(now, self.base_ms) && spent.is_none_or(|(t, _)| slot.touched < t) {
                spent = Some((slot.touched, i));
            }
        }
        match free.or(spent.map(|(_, i)| i)) {
            Some(i) => Place::New(i),
            None => Place::Full,
        }
    }

    fn slot(&self, i: usize) -> Slot {
        self.slots.as_ref().get(i).copied().unwrap_or(Slot::EMPTY)
    }

    /// Whether `peer` is locked out at `now`.
    pub fn locked(&self, peer: &Peer, now: i64) -> bool {
        match self.place(&key(peer), now) {
            Place::Own(i) => now < self.slot(i).locked_until,
            Place::New(_) | Place::Full => false,
        }
    }

    /// Whether a password from `peer` may be checked at `now`: it is not
    /// locked out, a wrong one would find a slot, and the budget is not
    /// spent.
    pub fn admits(&self, peer: &Peer, now: i64) -> bool {
        self.wait(peer, now).is_none()
    }

    /// How long, in milliseconds from `now`, until a password from `peer`
    /// may be checked (`None`: now): until its lockout ends, a slot for it
    /// frees, and the budget holds a check again, whichever is last. Other
    /// clients' wrong passwords meanwhile may make it longer.
    pub fn wait(&self, peer: &Peer, now: i64) -> Option<u32> {
        let place = match self.place(&key(peer), now) {
            Place::Own(i) => self.slot(i).locked_until,
            Place::New(_) => now,
            Place::Full => self.first_spent(),
        };
        let until = place.max(self.full_at.saturating_sub(i64::from(self.burst_ms)));
        let ms = until.wrapping_sub(now);
        (ms > 0).then(|| u32::try_from(ms).unwrap_or(u32::MAX))
    }

    /// When the first record becomes [`Slot::spent`], so that a new client
    /// finds a slot (the table is full of records that still matter, each
    /// of them touched in the past: no sum here overflows).
    fn first_spent(&self) -> i64 {
        let base = i64::from(self.base_ms);
        let mut first = i64::MAX;
        for s in self.slots.as_ref() {
            first = first.min(s.locked_until.max(s.touched.wrapping_add(base)));
        }
        first
    }

    /// Counts a checked wrong password from `peer`: it spends the budget,
    /// and the [`MAX_WRONG_PASSWORDS`]th in a row starts a lockout.
    pub fn wrong(&mut self, peer: &Peer, now: i64) {
        self.full_at = self.full_at.max(now).saturating_add(i64::from(self.interval_ms));
        let (base, max) = (self.base_ms, self.max_ms);
        let key = key(peer);
        let (i, fresh) = match self.place(&key, now) {
            Place::Own(i) => (i, false),
            Place::New(i) => (i, true),
            Place::Full => return,
        };
        let Some(record) = self.slots.as_mut().get_mut(i) else {
            return;
        };
        if fresh {
            *record = Slot { key, ..Slot::EMPTY };
        }
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

    /// Forgets `peer`: it logged in with a password that grants access.
    pub fn granted(&mut self, peer: &Peer) {
        let key = key(peer);
        for slot in self.slots.as_mut() {
            if slot.key == key {
                *slot = Slot::EMPTY;
            }
        }
    }
}
