//! Log lines about misbehaving clients, at most one per address and kind
//! of offence per minute: an attacker opening thousands of connections
//! must not also flood the log (and `showmsg`'s buffer) with one line each.

use std::collections::HashMap;
use std::fmt;
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use tracing::warn;

/// How often one address is reported for one kind of offence.
pub const REPORT_EVERY: Duration = Duration::from_secs(60);

/// Records kept before the stale ones are swept.
const SWEEP_AT: usize = 4096;

/// What a client did.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Offence {
    /// Did not finish its HTTP upgrade (and TLS handshake) in time.
    HandshakeTimeout,
    /// Its pending handshake was dropped for a newer one.
    HandshakeDropped,
    /// Its request was malformed or broke RFC 6455 (4xx).
    BadRequest,
    /// Its Origin or Host was refused (403).
    Forbidden,
    /// Wanted more sessions than one address may have.
    TooManySessions,
    /// Arrived while every session slot was held by logged-in sessions (503).
    ServerFull,
    /// Did not log in within the login deadline.
    LoginTimeout,
    /// Its session, not logged in, was closed to make room for a newcomer.
    SessionReclaimed,
    /// Sent wrong passwords until its session was closed (1008).
    WrongPasswords,
}

impl fmt::Display for Offence {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Offence::HandshakeTimeout => "handshake not completed in time; connection dropped",
            Offence::HandshakeDropped => "pending handshake dropped for a newer connection",
            Offence::BadRequest => "malformed request refused",
            Offence::Forbidden => "upgrade refused by the Origin/Host policy (403)",
            Offence::TooManySessions => "too many sessions from this address; refused (503)",
            Offence::ServerFull => "every session slot is taken; refused (503)",
            Offence::LoginTimeout => "no login within the deadline; closed (1008)",
            Offence::SessionReclaimed => "session not logged in; closed to make room (1008)",
            Offence::WrongPasswords => "wrong passwords; session closed (1008)",
        })
    }
}

struct Record {
    reported: Instant,
    since: u64,
}

/// The reports made in the last [`REPORT_EVERY`], per address and offence.
#[derive(Default)]
pub struct Reports {
    records: Mutex<HashMap<(IpAddr, Offence), Record>>,
}

impl Reports {
    /// Notes one offence by `ip`: logged now if this address was not
    /// reported for it within the last minute, else counted for the next
    /// line.
    pub fn note(&self, ip: IpAddr, offence: Offence) {
        let now = Instant::now();
        let mut records = self.records.lock().unwrap_or_else(|p| p.into_inner());
        if records.len() >= SWEEP_AT {
            records.retain(|_, r| now.duration_since(r.reported) < REPORT_EVERY);
        }
        match records.get_mut(&(ip, offence)) {
            Some(r) if now.duration_since(r.reported) < REPORT_EVERY => r.since += 1,
            Some(r) => {
                let more = r.since;
                *r = Record {
                    reported: now,
                    since: 0,
                };
                drop(records);
                if more == 0 {
                    warn!(%ip, "{offence}");
                } else {
                    warn!(%ip, "{offence} ({more} more times since the last report)");
                }
            }
            None => {
                records.insert(
                    (ip, offence),
                    Record {
                        reported: now,
                        since: 0,
                    },
                );
                drop(records);
                warn!(%ip, "{offence}");
            }
        }
    }
}
