//! Which autopilot lluavd follows on a lossy, shared, spoofable link
//! (DESIGN.md "Backends"): one autopilot, chosen by its heartbeat, and
//! from then on only its packets, from its address, count.
//!
//! - Acquiring: a `HEARTBEAT` from component 1 of the wanted system (or of
//!   any system with [`Wanted::Any`]) whose `autopilot` is not
//!   `MAV_AUTOPILOT_INVALID` and whose type is not a ground station, gimbal
//!   or companion computer. Its address is where lluavd sends.
//! - Following: a message counts only when it comes from that address and
//!   that system and component; everything else is foreign and dropped
//!   before any cache, whatever it claims.
//! - Losing: 3 s without the followed autopilot's heartbeat. Then the next
//!   heartbeat that satisfies the acquiring rule is followed, from
//!   wherever it comes.
//! - Same or new vehicle: the same system id from the same address is the
//!   same vehicle, unless its boot time (`time_boot_ms` of `SYSTEM_TIME`
//!   and `ATTITUDE`) went back, which means it rebooted. Anything else is
//!   a new vehicle, and what lluavd knew of the old one must be forgotten.
//!
//! Sans-IO: the caller says where a packet came from and when.

use std::collections::BTreeMap;
use std::net::SocketAddr;

use ::mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavAutopilot, MavMessage, MavType};
use ::mavlink::{MavHeader, Message as _};

use super::protocol::Target;

/// Without a heartbeat for this long the link is lost (DESIGN.md).
pub const LINK_TIMEOUT_MS: i64 = 3000;
/// The autopilot's component: `MAV_COMP_ID_AUTOPILOT1`.
pub const AUTOPILOT_COMPONENT: u8 = 1;
/// How far a boot time may go back before it means a reboot: packets a
/// radio link reorders arrive a little out of order, never by a second.
const REBOOT_MARGIN_MS: u32 = 1000;

/// Which system lluavd follows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wanted {
    /// This system id (PX4 and ArduPilot ship with 1).
    System(u8),
    /// The first autopilot that heartbeats.
    Any,
}

impl Default for Wanted {
    /// System 1, the id PX4 and ArduPilot ship with.
    fn default() -> Self {
        Wanted::System(1)
    }
}

impl std::str::FromStr for Wanted {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "any" => Ok(Wanted::Any),
            _ => match s.parse::<u8>() {
                Ok(n) if n > 0 => Ok(Wanted::System(n)),
                _ => Err(format!("a system id 1-255 or `any`, not `{s}`")),
            },
        }
    }
}

/// What a packet is to the link.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Admit {
    /// Not from the followed autopilot: dropped.
    Foreign,
    /// The followed autopilot's.
    Accept,
    /// This heartbeat acquired the autopilot: the link is up (again).
    /// `new_vehicle` when it is not the vehicle followed before (another
    /// system or address, or the first ever).
    Acquired {
        /// Whether it is another vehicle than the one followed before.
        new_vehicle: bool,
    },
    /// The followed autopilot's message, whose boot time says it rebooted:
    /// a new vehicle behind the same address.
    Rebooted,
}

/// The autopilot followed, and since when it is silent.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Follow {
    wanted: Wanted,
    target: Option<Target>,
    /// Where its packets come from (`None` on a serial or TCP link).
    from: Option<SocketAddr>,
    /// When its last heartbeat arrived, on the daemon's clock.
    heartbeat_ms: Option<i64>,
    /// The latest boot time seen, by message id.
    boot_ms: BTreeMap<u32, u32>,
}

impl Default for Follow {
    fn default() -> Self {
        Follow::new(Wanted::default())
    }
}

impl Follow {
    /// Following nothing yet.
    pub fn new(wanted: Wanted) -> Self {
        Follow {
            wanted,
            target: None,
            from: None,
            heartbeat_ms: None,
            boot_ms: BTreeMap::new(),
        }
    }

    /// The autopilot followed (or last followed).
    pub fn target(&self) -> Option<Target> {
        self.target
    }

    /// Where its packets come from, so where lluavd sends.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.from
    }

    /// How many boot times are kept.
    #[cfg(feature = "fuzzing")]
    pub fn boot_times(&self) -> usize {
        self.boot_ms.len()
    }

    /// Whether its heartbeat arrived within [`LINK_TIMEOUT_MS`] of `now_ms`.
    pub fn link_up(&self, now_ms: i64) -> bool {
        self.heartbeat_ms
            .is_some_and(|t| now_ms.saturating_sub(t) <= LINK_TIMEOUT_MS)
    }

    /// Milliseconds since its last heartbeat.
    pub fn heartbeat_age_ms(&self, now_ms: i64) -> Option<i64> {
        self.heartbeat_ms.map(|t| now_ms.saturating_sub(t).max(0))
    }

    /// What the packet `msg` from `from` with `header`, received at
    /// `now_ms`, is to the link.
    pub fn admit(
        &mut self,
        from: Option<SocketAddr>,
        header: &MavHeader,
        msg: &MavMessage,
        now_ms: i64,
    ) -> Admit {
        let ours = self.target.is_some_and(|t| t.sent(header)) && self.from == from;
        let up = self.link_up(now_ms);
        if ours && up {
            return self.followed(msg, now_ms);
        }
        match msg {
            MavMessage::HEARTBEAT(hb) if !up && self.acquires(header, hb) => {
                let same = ours;
                self.acquire(from, header, now_ms);
                if same {
                    Admit::Acquired { new_vehicle: false }
                } else {
                    self.boot_ms.clear();
                    Admit::Acquired { new_vehicle: true }
                }
            }
            _ if ours => self.followed(msg, now_ms),
            _ => Admit::Foreign,
        }
    }

    /// Whether this heartbeat may be followed now.
    fn acquires(&self, header: &MavHeader, hb: &HEARTBEAT_DATA) -> bool {
        let wanted = match self.wanted {
            Wanted::System(n) => header.system_id == u32::from(n),
            Wanted::Any => u8::try_from(header.system_id).is_ok_and(|s| s > 0),
        };
        wanted && header.component_id == AUTOPILOT_COMPONENT && is_autopilot(hb)
    }

    fn acquire(&mut self, from: Option<SocketAddr>, header: &MavHeader, now_ms: i64) {
        let target = Target {
            system: u8::try_from(header.system_id).unwrap_or(u8::MAX),
            component: header.component_id,
        };
        tracing::info!(system = target.system, from = ?from, "autopilot followed");
        self.target = Some(target);
        self.from = from;
        self.heartbeat_ms = Some(now_ms);
    }

    /// A message of the followed autopilot.
    fn followed(&mut self, msg: &MavMessage, now_ms: i64) -> Admit {
        let boot = match msg {
            MavMessage::HEARTBEAT(_) => {
                self.heartbeat_ms = Some(now_ms);
                return Admit::Accept;
            }
            MavMessage::SYSTEM_TIME(m) => m.time_boot_ms,
            MavMessage::ATTITUDE(m) => m.time_boot_ms,
            _ => return Admit::Accept,
        };
        let id = msg.message_id();
        let before = self.boot_ms.insert(id, boot);
        if before.is_some_and(|b| boot.saturating_add(REBOOT_MARGIN_MS) < b) {
            tracing::warn!(
                before,
                now = boot,
                "the autopilot's boot time went back: it rebooted"
            );
            self.boot_ms.clear();
            self.boot_ms.insert(id, boot);
            Admit::Rebooted
        } else {
            Admit::Accept
        }
    }
}

/// Whether a heartbeat is an autopilot's (not a ground station's, a
/// gimbal's or another companion computer's).
fn is_autopilot(hb: &HEARTBEAT_DATA) -> bool {
    hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID
        && !matches!(
            hb.mavtype,
            MavType::MAV_TYPE_GCS | MavType::MAV_TYPE_ONBOARD_CONTROLLER | MavType::MAV_TYPE_GIMBAL
        )
}

#[cfg(test)]
mod tests;
