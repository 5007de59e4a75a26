//! What a command does that the autopilot's telemetry shows: how lluavd
//! tells whether a command whose `COMMAND_ACK` was lost happened anyway
//! (DESIGN.md "Backends": a lost acknowledgement is not a failure until
//! telemetry says so). Each effect is read from one message of the
//! autopilot: the heartbeat's armed flag and mode, the extended state's
//! landed state.

use ::mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavLandedState, MavMessage, MavModeFlag};

use super::autopilot::{Flavour, Mode, Phase};

/// What a command changes, as telemetry shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// The heartbeat's armed flag is this.
    Armed(bool),
    /// The heartbeat's mode is this one.
    Mode(Flavour, Mode),
    /// The mode means this phase of flight (`NAV_RETURN_TO_LAUNCH`,
    /// `MISSION_START`).
    Phase(Flavour, Phase),
    /// Landing or landed (`NAV_LAND`): the landed state, the landing mode,
    /// or a vehicle that landed and disarmed.
    Landing(Flavour),
    /// Taking off or in the air: the landed state, or PX4's takeoff mode.
    Airborne(Flavour),
}

impl Effect {
    /// Whether `msg`, from the autopilot, shows the effect. One message
    /// that shows it after the command was sent is enough: the command
    /// happened, even if what it started is over by now (a return that
    /// already landed, an arming the autopilot undid).
    pub fn seen(self, msg: &MavMessage) -> bool {
        let armed = |hb: &HEARTBEAT_DATA| hb.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
        match (self, msg) {
            (Effect::Armed(want), MavMessage::HEARTBEAT(hb)) => armed(hb) == want,
            (Effect::Mode(flavour, mode), MavMessage::HEARTBEAT(hb)) => flavour.is_mode(hb.custom_mode, mode),
            (Effect::Phase(flavour, phase), MavMessage::HEARTBEAT(hb)) => {
                flavour.phase(hb.custom_mode) == phase
            }
            (Effect::Landing(flavour), MavMessage::HEARTBEAT(hb)) => {
                armed(hb) && flavour.phase(hb.custom_mode) == Phase::Landing
            }
            (Effect::Landing(_), MavMessage::EXTENDED_SYS_STATE(e)) => {
                e.landed_state == MavLandedState::MAV_LANDED_STATE_LANDING
            }
            (Effect::Airborne(flavour), MavMessage::HEARTBEAT(hb)) => {
                armed(hb) && flavour.phase(hb.custom_mode) == Phase::Takeoff
            }
            (Effect::Airborne(_), MavMessage::EXTENDED_SYS_STATE(e)) => matches!(
                e.landed_state,
                MavLandedState::MAV_LANDED_STATE_TAKEOFF | MavLandedState::MAV_LANDED_STATE_IN_AIR
            ),
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use ::mavlink::dialects::ardupilotmega::{
        EXTENDED_SYS_STATE_DATA, HEARTBEAT_DATA, MavAutopilot, MavState, MavType, MavVtolState,
    };

    use super::*;

    fn heartbeat(armed: bool, custom_mode: u32) -> MavMessage {
        let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if armed {
            base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
        }
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode,
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
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

    const PX4_TAKEOFF: u32 = (4 << 16) | (2 << 24);
    const PX4_LAND: u32 = (4 << 16) | (6 << 24);
    const PX4_OFFBOARD: u32 = 6 << 16;

    #[test]
    fn arming_shows_in_the_heartbeat() {
        assert!(Effect::Armed(true).seen(&heartbeat(true, 0)));
        assert!(!Effect::Armed(true).seen(&heartbeat(false, 0)));
        assert!(Effect::Armed(false).seen(&heartbeat(false, 0)));
        assert!(!Effect::Armed(true).seen(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR)));
    }

    #[test]
    fn a_takeoff_shows_in_the_landed_state_or_the_takeoff_mode() {
        let px4 = Effect::Airborne(Flavour::Px4);
        assert!(px4.seen(&landed(MavLandedState::MAV_LANDED_STATE_TAKEOFF)));
        assert!(px4.seen(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR)));
        assert!(!px4.seen(&landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND)));
        assert!(px4.seen(&heartbeat(true, PX4_TAKEOFF)));
        assert!(
            !px4.seen(&heartbeat(false, PX4_TAKEOFF)),
            "disarmed is on the ground"
        );
        assert!(!px4.seen(&heartbeat(true, PX4_OFFBOARD)));
    }

    #[test]
    fn modes_and_phases_show_in_the_heartbeat() {
        assert!(Effect::Mode(Flavour::Px4, Mode::Guided).seen(&heartbeat(true, PX4_OFFBOARD)));
        assert!(!Effect::Mode(Flavour::Px4, Mode::Guided).seen(&heartbeat(true, PX4_LAND)));
        assert!(Effect::Mode(Flavour::ArduPilot, Mode::Guided).seen(&heartbeat(true, 4)));
        let landing = Effect::Landing(Flavour::Px4);
        assert!(landing.seen(&heartbeat(true, PX4_LAND)));
        assert!(!landing.seen(&heartbeat(true, PX4_OFFBOARD)));
        assert!(landing.seen(&landed(MavLandedState::MAV_LANDED_STATE_LANDING)));
        assert!(!landing.seen(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR)));
        assert!(!Effect::Phase(Flavour::ArduPilot, Phase::Rtl).seen(&heartbeat(true, 9)));
        assert!(Effect::Phase(Flavour::ArduPilot, Phase::Rtl).seen(&heartbeat(true, 6)));
    }
}
