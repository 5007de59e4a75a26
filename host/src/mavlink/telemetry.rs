//! The cache of the autopilot's latest telemetry, fed by the link task,
//! and what `state`, `mavlink_msgs` and the armed gate read from it.

use std::collections::BTreeMap;

use ::mavlink::MavHeader;
use ::mavlink::Message as _;
use ::mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, BATTERY_STATUS_DATA, EXTENDED_SYS_STATE_DATA, GLOBAL_POSITION_INT_DATA, HEARTBEAT_DATA,
    HOME_POSITION_DATA, LOCAL_POSITION_NED_DATA, MavAutopilot, MavLandedState, MavMessage, MavModeFlag,
    MavProtocolCapability, MavType, SYS_STATUS_DATA,
};
use lluav_core::Fields;

use super::autopilot::{Encoding, Flavour, Phase};
use super::geo::Global;
use super::protocol::Target;
use crate::vehicle::Ned;

/// Without a heartbeat for this long the link is lost (DESIGN.md).
pub const LINK_TIMEOUT_MS: i64 = 3000;

/// The latest of each message lluavd reads, from the autopilot.
#[derive(Debug, Default)]
pub struct Telemetry {
    /// The autopilot's address: the first heartbeat from an autopilot.
    target: Option<Target>,
    /// Which autopilot.
    flavour: Option<Flavour>,
    heartbeat: Option<HEARTBEAT_DATA>,
    /// When the last heartbeat arrived, ms since the Unix epoch.
    heartbeat_ms: Option<i64>,
    sys_status: Option<SYS_STATUS_DATA>,
    local: Option<LOCAL_POSITION_NED_DATA>,
    global: Option<GLOBAL_POSITION_INT_DATA>,
    home: Option<HOME_POSITION_DATA>,
    attitude: Option<ATTITUDE_DATA>,
    extended: Option<EXTENDED_SYS_STATE_DATA>,
    battery: Option<BATTERY_STATUS_DATA>,
    /// The parameter encoding `AUTOPILOT_VERSION` announced.
    encoding: Option<Encoding>,
    /// Messages received, by type, from anyone on the link.
    counts: BTreeMap<&'static str, u64>,
    /// Distance flown while armed, metres.
    distance_m: f64,
}

impl Telemetry {
    /// Takes in one message received at `now_ms`; true when it is a
    /// heartbeat that brings the link up (first, or after it was lost).
    pub fn observe(&mut self, header: &MavHeader, msg: &MavMessage, now_ms: i64) -> bool {
        *self.counts.entry(msg.message_name()).or_insert(0) += 1;
        if let (None, MavMessage::HEARTBEAT(hb)) = (self.target, msg)
            && is_autopilot(hb)
        {
            self.target = Some(Target {
                system: u8::try_from(header.system_id).unwrap_or(u8::MAX),
                component: header.component_id,
            });
            self.flavour = Some(Flavour::from_autopilot(hb.autopilot));
            tracing::info!(
                system = header.system_id,
                component = header.component_id,
                autopilot = ?hb.autopilot,
                "autopilot found"
            );
        }
        let Some(target) = self.target else {
            return false;
        };
        if header.system_id != u32::from(target.system) || header.component_id != target.component {
            return false;
        }
        match msg {
            MavMessage::HEARTBEAT(hb) => {
                let came_up = !self.link_up(now_ms);
                self.heartbeat = Some(hb.clone());
                self.heartbeat_ms = Some(now_ms);
                return came_up;
            }
            MavMessage::SYS_STATUS(m) => self.sys_status = Some(m.clone()),
            MavMessage::LOCAL_POSITION_NED(m) => {
                if let (Some(old), true) = (&self.local, self.armed()) {
                    let d = ((m.x - old.x).powi(2) + (m.y - old.y).powi(2) + (m.z - old.z).powi(2)).sqrt();
                    self.distance_m += f64::from(d);
                }
                self.local = Some(m.clone());
            }
            MavMessage::GLOBAL_POSITION_INT(m) => self.global = Some(m.clone()),
            MavMessage::HOME_POSITION(m) => self.home = Some(m.clone()),
            MavMessage::ATTITUDE(m) => self.attitude = Some(m.clone()),
            MavMessage::EXTENDED_SYS_STATE(m) => self.extended = Some(m.clone()),
            MavMessage::BATTERY_STATUS(m) => self.battery = Some(m.clone()),
            MavMessage::AUTOPILOT_VERSION(m) => {
                let caps = m.capabilities;
                self.encoding = if caps
                    .contains(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
                {
                    Some(Encoding::CCast)
                } else if caps.contains(MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
                {
                    Some(Encoding::Bytewise)
                } else {
                    None
                };
            }
            _ => {}
        }
        false
    }

    /// The autopilot's address, once a heartbeat named it.
    pub fn target(&self) -> Option<Target> {
        self.target
    }

    /// Which autopilot, once a heartbeat named it.
    pub fn flavour(&self) -> Option<Flavour> {
        self.flavour
    }

    /// Distance flown while armed, metres.
    pub fn distance_m(&self) -> f64 {
        self.distance_m
    }

    /// Whether a heartbeat arrived within [`LINK_TIMEOUT_MS`] of `now_ms`.
    pub fn link_up(&self, now_ms: i64) -> bool {
        self.heartbeat_ms.is_some_and(|t| now_ms - t <= LINK_TIMEOUT_MS)
    }

    /// Milliseconds since the last heartbeat.
    pub fn heartbeat_age_ms(&self, now_ms: i64) -> Option<i64> {
        self.heartbeat_ms.map(|t| (now_ms - t).max(0))
    }

    /// The heartbeat's armed flag (the last one seen, even if the link is
    /// lost: an armed vehicle out of reach stays armed for the gate).
    pub fn armed(&self) -> bool {
        self.heartbeat
            .as_ref()
            .is_some_and(|hb| hb.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED))
    }

    /// The heartbeat's `custom_mode`.
    pub fn custom_mode(&self) -> Option<u32> {
        self.heartbeat.as_ref().map(|hb| hb.custom_mode)
    }

    /// How integer parameters travel.
    pub fn encoding(&self) -> Encoding {
        self.encoding
            .unwrap_or_else(|| self.flavour.unwrap_or(Flavour::Generic).default_encoding())
    }

    /// Home, globally, once `HOME_POSITION` arrived.
    pub fn home_global(&self) -> Option<Global> {
        self.home
            .as_ref()
            .map(|h| Global::from_e7(h.latitude, h.longitude, h.altitude))
    }

    /// Home in the local NED frame.
    pub fn home_local(&self) -> Option<Ned> {
        self.home
            .as_ref()
            .map(|h| Ned::new(h.x.into(), h.y.into(), h.z.into()))
    }

    /// Position in the local NED frame.
    pub fn position(&self) -> Option<Ned> {
        self.local
            .as_ref()
            .map(|l| Ned::new(l.x.into(), l.y.into(), l.z.into()))
    }

    /// Heading, radians.
    pub fn yaw(&self) -> Option<f32> {
        self.attitude.as_ref().map(|a| a.yaw)
    }

    /// The autopilot's boot clock, seconds.
    pub fn boot_s(&self) -> f64 {
        let ms = [
            self.local.as_ref().map(|m| m.time_boot_ms),
            self.attitude.as_ref().map(|m| m.time_boot_ms),
            self.global.as_ref().map(|m| m.time_boot_ms),
        ]
        .into_iter()
        .flatten()
        .max()
        .unwrap_or(0);
        f64::from(ms) / 1000.0
    }

    fn landed(&self) -> MavLandedState {
        self.extended
            .as_ref()
            .map_or(MavLandedState::MAV_LANDED_STATE_UNDEFINED, |e| e.landed_state)
    }

    /// `state.fsm` in the simulator's words, from the armed flag, the
    /// landed state and the flight mode.
    pub fn fsm(&self) -> &'static str {
        use MavLandedState as L;
        if !self.armed() {
            return "disarmed";
        }
        let phase = match (self.flavour, self.custom_mode()) {
            (Some(f), Some(m)) => f.phase(m),
            _ => Phase::Other,
        };
        match (self.landed(), phase) {
            (L::MAV_LANDED_STATE_TAKEOFF, _) | (_, Phase::Takeoff) => "takeoff",
            (L::MAV_LANDED_STATE_LANDING, _) | (_, Phase::Landing) => "landing",
            (L::MAV_LANDED_STATE_ON_GROUND, _) => "armed",
            (_, Phase::Mission) => "mission",
            (_, Phase::Rtl) => "rtl",
            (L::MAV_LANDED_STATE_IN_AIR, Phase::Other) => "hover",
            _ => "armed",
        }
    }

    /// Whether the vehicle is in the air (armed and not on the ground).
    pub fn airborne(&self) -> bool {
        matches!(self.fsm(), "takeoff" | "hover" | "mission" | "landing" | "rtl")
    }

    /// Battery charge, percent, if the autopilot reports one.
    fn battery_percent(&self) -> Option<i8> {
        let from_status = self.battery.as_ref().map(|b| b.battery_remaining);
        let from_sys = self.sys_status.as_ref().map(|s| s.battery_remaining);
        from_status.into_iter().chain(from_sys).find(|p| *p >= 0)
    }

    /// Writes the telemetry members of `state` (see the module doc of
    /// [`super`]).
    pub fn write_state(&self, now_ms: i64, s: &mut Fields<'_>) {
        s.bool("armed", self.armed())
            .str("fsm", self.fsm())
            .bool("airborne", self.airborne());
        opt_ned(s, "position", self.position());
        opt_ned(
            s,
            "velocity",
            self.local
                .as_ref()
                .map(|l| Ned::new(l.vx.into(), l.vy.into(), l.vz.into())),
        );
        opt_f32(s, "yaw", self.yaw());
        let altitude = match (&self.global, &self.local) {
            (Some(g), _) => Some(g.relative_alt as f32 / 1000.0),
            (None, Some(l)) => Some(-l.z),
            _ => None,
        };
        opt_f32(s, "altitude", altitude);
        match self.battery_percent() {
            Some(p) => s.i64("battery", p.into()),
            None => s.null("battery"),
        };
        opt_ned(s, "home", self.home_local());
        s.str("link", if self.link_up(now_ms) { "up" } else { "lost" });
        match self.heartbeat_age_ms(now_ms) {
            Some(age) => s.i64("heartbeat_age_ms", age),
            None => s.null("heartbeat_age_ms"),
        };
        self.write_autopilot(s);
    }

    fn write_autopilot(&self, s: &mut Fields<'_>) {
        match self.flavour {
            Some(f) => s.str("autopilot", f.name()),
            None => s.null("autopilot"),
        };
        match (self.flavour, self.custom_mode()) {
            (Some(f), Some(m)) => s.str("mode", f.mode_name(m)),
            _ => s.null("mode"),
        };
        s.str("landed", landed_name(self.landed()));
        opt_global(
            s,
            "global",
            self.global.as_ref().map(|g| Global::from_e7(g.lat, g.lon, g.alt)),
        );
        opt_global(s, "home_global", self.home_global());
    }

    /// Writes `mav_msgs`: how many of each message type arrived.
    pub fn write_counts(&self, out: &mut Fields<'_>) {
        out.object("mav_msgs", |o| {
            for (name, n) in &self.counts {
                o.u64(name, *n);
            }
        });
    }

    /// All messages received.
    pub fn total_messages(&self) -> u64 {
        self.counts.values().sum()
    }
}

fn opt_ned(s: &mut Fields<'_>, key: &str, p: Option<Ned>) {
    match p {
        Some(p) => s.object(key, |o| p.write(o)),
        None => s.null(key),
    };
}

fn opt_global(s: &mut Fields<'_>, key: &str, g: Option<Global>) {
    match g {
        Some(g) => s.object(key, |o| {
            o.f64("lat", g.lat).f64("lon", g.lon).f64("alt", g.alt);
        }),
        None => s.null(key),
    };
}

fn opt_f32(s: &mut Fields<'_>, key: &str, v: Option<f32>) {
    match v {
        Some(v) => s.f32(key, v),
        None => s.null(key),
    };
}

fn landed_name(l: MavLandedState) -> &'static str {
    match l {
        MavLandedState::MAV_LANDED_STATE_ON_GROUND => "on_ground",
        MavLandedState::MAV_LANDED_STATE_IN_AIR => "in_air",
        MavLandedState::MAV_LANDED_STATE_TAKEOFF => "takeoff",
        MavLandedState::MAV_LANDED_STATE_LANDING => "landing",
        MavLandedState::MAV_LANDED_STATE_UNDEFINED => "undefined",
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
mod tests {
    use super::*;
    use ::mavlink::dialects::ardupilotmega::{MavState, MavVtolState};

    fn header(system: u32, component: u8) -> MavHeader {
        MavHeader {
            system_id: system,
            component_id: component,
            sequence: 0,
        }
    }

    fn heartbeat(autopilot: MavAutopilot, armed: bool, custom_mode: u32) -> MavMessage {
        let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if armed {
            base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
        }
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode,
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot,
            base_mode,
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    fn landed(state: MavLandedState) -> MavMessage {
        MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
            vtol_state: MavVtolState::MAV_VTOL_STATE_MC,
            landed_state: state,
        })
    }

    #[test]
    fn the_link_is_up_for_three_seconds_after_each_heartbeat() {
        let mut t = Telemetry::default();
        assert!(!t.link_up(0));
        assert!(t.observe(
            &header(1, 1),
            &heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, false, 0),
            1000
        ));
        assert!(!t.observe(
            &header(1, 1),
            &heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, false, 0),
            2000
        ));
        assert!(t.link_up(5000) && !t.link_up(5001));
        assert_eq!(t.heartbeat_age_ms(5001), Some(3001));
        // A heartbeat after the loss brings the link up again.
        assert!(t.observe(
            &header(1, 1),
            &heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, false, 0),
            9000
        ));
    }

    #[test]
    fn only_the_first_autopilot_is_followed() {
        let mut t = Telemetry::default();
        let gcs = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_GCS,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            ..HEARTBEAT_DATA::DEFAULT
        });
        t.observe(&header(255, 190), &gcs, 0);
        assert_eq!(t.target, None);
        t.observe(
            &header(3, 1),
            &heartbeat(MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, true, 4),
            0,
        );
        t.observe(
            &header(4, 1),
            &heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, false, 0),
            0,
        );
        assert_eq!(
            t.target,
            Some(Target {
                system: 3,
                component: 1
            })
        );
        assert_eq!(t.flavour, Some(Flavour::ArduPilot));
        assert!(t.armed(), "system 4's disarmed heartbeat must not count");
        assert_eq!(t.total_messages(), 3);
    }

    #[test]
    fn fsm_follows_the_armed_flag_the_landed_state_and_the_mode() {
        let mut t = Telemetry::default();
        let px4 = MavAutopilot::MAV_AUTOPILOT_PX4;
        let h = header(1, 1);
        t.observe(&h, &heartbeat(px4, false, 0), 0);
        assert_eq!(t.fsm(), "disarmed");
        t.observe(&h, &heartbeat(px4, true, 0), 0);
        t.observe(&h, &landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND), 0);
        assert_eq!((t.fsm(), t.airborne()), ("armed", false));
        t.observe(&h, &landed(MavLandedState::MAV_LANDED_STATE_TAKEOFF), 0);
        assert_eq!(t.fsm(), "takeoff");
        t.observe(&h, &landed(MavLandedState::MAV_LANDED_STATE_IN_AIR), 0);
        assert_eq!((t.fsm(), t.airborne()), ("hover", true));
        t.observe(&h, &heartbeat(px4, true, (4 << 16) | (4 << 24)), 0);
        assert_eq!(t.fsm(), "mission");
        t.observe(&h, &heartbeat(px4, true, (4 << 16) | (5 << 24)), 0);
        assert_eq!(t.fsm(), "rtl");
        t.observe(&h, &heartbeat(px4, true, (4 << 16) | (6 << 24)), 0);
        assert_eq!(t.fsm(), "landing");
    }
}
