//! The cache of the followed autopilot's latest telemetry (only its own
//! messages reach it, see `follow`), and what `state`, `mavlink_msgs` and
//! the armed gate read from it.

use std::collections::BTreeMap;

use ::mavlink::Message as _;
use ::mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, BATTERY_STATUS_DATA, EXTENDED_SYS_STATE_DATA, GLOBAL_POSITION_INT_DATA, HEARTBEAT_DATA,
    HOME_POSITION_DATA, LOCAL_POSITION_NED_DATA, MavLandedState, MavMessage, MavModeFlag,
    MavProtocolCapability, MavState, SYS_STATUS_DATA,
};
use lluav_core::Fields;

use super::autopilot::{Encoding, Flavour, ParamValue, Phase};
use super::geo::Global;
use crate::vehicle::Ned;

/// How `state` reads beside the cache: the flight state as lluavd knows
/// it and the link's health.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    /// `fsm`.
    pub fsm: &'static str,
    /// `airborne`.
    pub airborne: bool,
    /// Whether the link is up.
    pub link_up: bool,
    /// Milliseconds since the autopilot's last heartbeat.
    pub heartbeat_age_ms: Option<i64>,
}

/// The latest of each message lluavd reads, from the autopilot.
#[derive(Debug, Default)]
pub struct Telemetry {
    /// Which autopilot.
    flavour: Option<Flavour>,
    heartbeat: Option<HEARTBEAT_DATA>,
    sys_status: Option<SYS_STATUS_DATA>,
    local: Option<LOCAL_POSITION_NED_DATA>,
    global: Option<GLOBAL_POSITION_INT_DATA>,
    home: Option<HOME_POSITION_DATA>,
    attitude: Option<ATTITUDE_DATA>,
    extended: Option<EXTENDED_SYS_STATE_DATA>,
    battery: Option<BATTERY_STATUS_DATA>,
    /// The parameter encoding `AUTOPILOT_VERSION` announced.
    encoding: Option<Encoding>,
    /// The altitude its return climbs to (if lower), m, from its
    /// parameter's latest `PARAM_VALUE`.
    rtl_alt: Option<f32>,
    /// Messages received from the autopilot, by type.
    counts: BTreeMap<&'static str, u64>,
    /// Distance flown while armed, metres.
    distance_m: f64,
}

impl Telemetry {
    /// Another vehicle: nothing of the old one is true of it. The message
    /// counts and the distance flown are the link's and lluavd's, kept.
    pub fn new_vehicle(&mut self) {
        *self = Telemetry {
            counts: std::mem::take(&mut self.counts),
            distance_m: self.distance_m,
            ..Telemetry::default()
        };
    }

    /// Takes in one message of the followed autopilot.
    pub fn observe(&mut self, msg: &MavMessage) {
        *self.counts.entry(msg.message_name()).or_insert(0) += 1;
        match msg {
            MavMessage::HEARTBEAT(hb) => {
                self.flavour = Some(Flavour::from_autopilot(hb.autopilot));
                self.heartbeat = Some(hb.clone());
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
            MavMessage::PARAM_VALUE(v) => {
                // Whoever asked (lluavd at link-up, a client's get_param or
                // set_param, another ground station), the value is the
                // autopilot's.
                if let Some(flavour) = self.flavour {
                    let (name, per_metre) = flavour.rtl_alt_param();
                    if v.param_id.to_str().is_ok_and(|n| n == name) {
                        let alt = match self.encoding().decode(v.param_type, v.param_value) {
                            ParamValue::Int(i) => i as f32,
                            ParamValue::Float(f) => f,
                        } / per_metre;
                        self.rtl_alt = alt.is_finite().then_some(alt);
                    }
                }
            }
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
    }

    /// Which autopilot, once a heartbeat named it.
    pub fn flavour(&self) -> Option<Flavour> {
        self.flavour
    }

    /// Distance flown while armed, metres.
    pub fn distance_m(&self) -> f64 {
        self.distance_m
    }

    /// The heartbeat's armed flag (the last one seen, even if the link is
    /// lost: an armed vehicle out of reach stays armed for the gate).
    pub fn armed(&self) -> bool {
        self.heartbeat
            .as_ref()
            .is_some_and(|hb| hb.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED))
    }

    /// The heartbeat's `system_status`.
    pub fn system_status(&self) -> Option<MavState> {
        self.heartbeat.as_ref().map(|hb| hb.system_status)
    }

    /// The altitude above home the autopilot's return climbs to (if
    /// lower), m, once its parameter was read.
    pub fn rtl_alt(&self) -> Option<f32> {
        self.rtl_alt
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

    /// Altitude above home, m: `GLOBAL_POSITION_INT.relative_alt`, or the
    /// local position's height.
    pub fn altitude(&self) -> Option<f32> {
        match (&self.global, &self.local) {
            (Some(g), _) => Some(g.relative_alt as f32 / 1000.0),
            (None, Some(l)) => Some(-l.z),
            _ => None,
        }
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
    pub fn battery_percent(&self) -> Option<i8> {
        let from_status = self.battery.as_ref().map(|b| b.battery_remaining);
        let from_sys = self.sys_status.as_ref().map(|s| s.battery_remaining);
        from_status.into_iter().chain(from_sys).find(|p| *p >= 0)
    }

    /// Writes the telemetry members of `state` (see the module doc of
    /// [`super`]).
    pub fn write_state(&self, status: Status, s: &mut Fields<'_>) {
        s.bool("armed", self.armed())
            .str("fsm", status.fsm)
            .bool("airborne", status.airborne);
        opt_ned(s, "position", self.position());
        opt_ned(
            s,
            "velocity",
            self.local
                .as_ref()
                .map(|l| Ned::new(l.vx.into(), l.vy.into(), l.vz.into())),
        );
        opt_f32(s, "yaw", self.yaw());
        opt_f32(s, "altitude", self.altitude());
        match self.battery_percent() {
            Some(p) => s.i64("battery", p.into()),
            None => s.null("battery"),
        };
        opt_ned(s, "home", self.home_local());
        s.str("link", if status.link_up { "up" } else { "lost" });
        match status.heartbeat_age_ms {
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

    /// How many message kinds were counted.
    #[cfg(feature = "fuzzing")]
    pub fn kinds(&self) -> usize {
        self.counts.len()
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

#[cfg(test)]
mod tests {
    use super::*;
    use ::mavlink::dialects::ardupilotmega::{
        MavAutopilot, MavParamType, MavState, MavType, MavVtolState, PARAM_VALUE_DATA,
    };

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
    fn the_heartbeat_names_the_autopilot_and_every_message_is_counted() {
        let mut t = Telemetry::default();
        assert_eq!(t.flavour(), None);
        t.observe(&heartbeat(MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, true, 4));
        t.observe(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR));
        assert_eq!(t.flavour(), Some(Flavour::ArduPilot));
        assert!(t.armed());
        assert_eq!(t.total_messages(), 2);
    }

    fn param(name: &str, value: f32, ty: MavParamType) -> MavMessage {
        MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: value,
            param_count: 1,
            param_index: 0,
            param_id: name.into(),
            param_type: ty,
        })
    }

    #[test]
    fn the_return_altitude_is_the_autopilots_own_parameter_in_metres() {
        let mut t = Telemetry::default();
        // Before the heartbeat, nobody knows whose parameter it is.
        t.observe(&param(
            "RTL_RETURN_ALT",
            30.0,
            MavParamType::MAV_PARAM_TYPE_REAL32,
        ));
        assert_eq!(t.rtl_alt(), None);
        t.observe(&heartbeat(MavAutopilot::MAV_AUTOPILOT_PX4, false, 0));
        t.observe(&param(
            "RTL_RETURN_ALT",
            30.0,
            MavParamType::MAV_PARAM_TYPE_REAL32,
        ));
        t.observe(&param(
            "RTL_DESCEND_ALT",
            10.0,
            MavParamType::MAV_PARAM_TYPE_REAL32,
        ));
        assert_eq!(t.rtl_alt(), Some(30.0));
        let mut t = Telemetry::default();
        t.observe(&heartbeat(MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA, false, 0));
        t.observe(&param("RTL_ALT", 1500.0, MavParamType::MAV_PARAM_TYPE_INT16));
        assert_eq!(t.rtl_alt(), Some(15.0), "centimetres");
        t.observe(&param(
            "RTL_RETURN_ALT",
            30.0,
            MavParamType::MAV_PARAM_TYPE_REAL32,
        ));
        assert_eq!(t.rtl_alt(), Some(15.0), "not ArduPilot's parameter");
    }

    #[test]
    fn fsm_follows_the_armed_flag_the_landed_state_and_the_mode() {
        let mut t = Telemetry::default();
        let px4 = MavAutopilot::MAV_AUTOPILOT_PX4;
        t.observe(&heartbeat(px4, false, 0));
        assert_eq!(t.fsm(), "disarmed");
        t.observe(&heartbeat(px4, true, 0));
        t.observe(&landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND));
        assert_eq!((t.fsm(), t.airborne()), ("armed", false));
        t.observe(&landed(MavLandedState::MAV_LANDED_STATE_TAKEOFF));
        assert_eq!(t.fsm(), "takeoff");
        t.observe(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR));
        assert_eq!((t.fsm(), t.airborne()), ("hover", true));
        t.observe(&heartbeat(px4, true, (4 << 16) | (4 << 24)));
        assert_eq!(t.fsm(), "mission");
        t.observe(&heartbeat(px4, true, (4 << 16) | (5 << 24)));
        assert_eq!(t.fsm(), "rtl");
        t.observe(&heartbeat(px4, true, (4 << 16) | (6 << 24)));
        assert_eq!(t.fsm(), "landing");
    }
}
